"""The procedures' computation from stored observations: one library under both programs.

The calibration worker computes each job's result with it after measuring; ``ritactl
recompute`` and ``ritactl plate survey`` run the same code on the operator's laptop. It
sits beside the bus library, not in it (it needs numpy and OpenCV, which the thin client's
bus must not) and not in ``calibration/`` (it reads dataset folders through the bus
library's contract and writes result files, where ``calibration/`` is a pure leaf).
"""
from __future__ import annotations

from daemon.face import lazy_face

#: the package's public names -> the module that defines them; imported on first use, so
#: importing one submodule (or this face) never loads the rest
_FACE = {
    "recompute": "recompute",
    "compare": "recompute",
    "ComputationFailed": "recompute",
    "compute_referencing": "procedures",
    "compute_measure_mark": "procedures",
    "compute_experiment": "procedures",
    "compute_intrinsics": "procedures",
    "survey_plate": "survey",
    "read_image": "images",
}
__all__, __getattr__ = lazy_face(__name__, _FACE)
