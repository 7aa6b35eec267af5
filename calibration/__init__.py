"""Camera-to-robot calibration (the paper's referencing method), pure numpy/OpenCV."""
from __future__ import annotations

from importlib import import_module
from typing import Any

__version__ = "0.1.0"

#: the package's public names -> the module that defines them; imported on first use, so
#: importing one submodule (or this face) never loads the rest
_FACE = {
    "reference": "referencing",
    "ReferencingResult": "referencing",
    "robot_pose": "referencing",
    "measure_mark": "measure",
    "measure_image": "measure",
    "MarkMeasurement": "measure",
    "mark_to_abs": "measure",
    "experiment_metrics": "metrics",
    "ExperimentMetrics": "metrics",
    "fit_bias": "metrics",
    "min_enclosing_circle": "metrics",
    "combine": "reversal",
    "ReversalResult": "reversal",
    "calibrate_intrinsics": "intrinsics",
    "run_survey": "plate_survey",
    "SurveyResult": "plate_survey",
    "compensate": "compensation",
    "Compensation": "compensation",
    "CameraModel": "camera_model",
    "Plate": "plate",
    "make_H": "frames",
    "inv_H": "frames",
    "apply_H": "frames",
    "check_H": "frames",
    "assert_rotation": "frames",
}
__all__ = sorted(_FACE)


def __getattr__(name: str) -> Any:
    if name not in _FACE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(f"{__name__}.{_FACE[name]}"), name)
