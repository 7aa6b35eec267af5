"""Camera-to-robot calibration (the paper's referencing method), pure numpy/OpenCV.

Its public names are imported here at once: every user of this package needs numpy and OpenCV
anyway (the laptop client never imports it), and a leaf that imports nothing of ours cannot share
the lazy face of daemon/face.py.
"""
from __future__ import annotations

from calibration.referencing import ReferencingResult, reference, robot_pose
from calibration.measure import MarkMeasurement, mark_to_abs, measure_image, measure_mark
from calibration.metrics import ExperimentMetrics, experiment_metrics, fit_bias, min_enclosing_circle
from calibration.reversal import ReversalResult, combine
from calibration.intrinsics import calibrate_intrinsics
from calibration.plate_survey import SurveyResult, run_survey
from calibration.compensation import Compensation, compensate
from calibration.camera_model import CameraModel
from calibration.plate import Plate
from calibration.frames import apply_H, assert_rotation, check_H, inv_H, make_H

__version__ = "0.1.0"

__all__ = ["CameraModel", "Compensation", "ExperimentMetrics", "MarkMeasurement", "Plate", "ReferencingResult",
           "ReversalResult", "SurveyResult", "apply_H", "assert_rotation", "calibrate_intrinsics", "check_H",
           "combine", "compensate", "experiment_metrics", "fit_bias", "inv_H", "make_H", "mark_to_abs",
           "measure_image", "measure_mark", "min_enclosing_circle", "reference", "robot_pose", "run_survey"]
