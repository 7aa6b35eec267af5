"""Scoring against the simulated world's truth: the only place the demo and the tests compare with it.

Truth never feeds the product's loop; it only grades a result here, after the fact.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from calibration.referencing import rob_H_cam_error


def score_rob_H_cam(estimate: Any, truth: Any) -> dict[str, float]:
    """rob_H_cam error against truth: ``t_xy_mm``, ``t_z_mm``, ``rot_deg`` (and what rob_H_cam_error adds)."""
    return rob_H_cam_error(np.asarray(estimate, float), np.asarray(truth, float))


__all__ = ["score_rob_H_cam"]
