"""Scoring against the simulated world's truth: the only place the demo and the tests compare with it.

Truth never feeds the product's loop; it only grades a result here, after the fact.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from calibration.referencing import rob_H_cam_error

#: the scale the principal point goal (1.5 px) is stated at (WorldParams.full_size width)
FULL_WIDTH_PX = 4024


def score_rob_H_cam(estimate: Any, truth: Any) -> dict[str, float]:
    """rob_H_cam error against truth: ``t_xy_mm``, ``t_z_mm``, ``rot_deg`` (and what rob_H_cam_error adds)."""
    return rob_H_cam_error(np.asarray(estimate, float), np.asarray(truth, float))


def score_camera_model(model: dict[str, Any], truth: dict[str, Any]) -> dict[str, float]:
    """Focal length error (relative) and principal point error (px at full size) of a camera_model.json."""
    K, Kt = np.asarray(model["K"], float), np.asarray(truth["camera_model"]["K"], float)
    scale = FULL_WIDTH_PX / float(model["size"][0])
    return {"df_rel": float(max(abs(K[0, 0] / Kt[0, 0] - 1), abs(K[1, 1] / Kt[1, 1] - 1))),
            "pp_full_px": float(np.hypot(*(K[:2, 2] - Kt[:2, 2])) * scale)}


def true_seats(truth: dict[str, Any]) -> dict[str, np.ndarray]:
    """Nest seats in PCS from the truth: SMR centres (ACS) → PCS, + δ along PCS z (plate.json's
    convention)."""
    ref_H_abs = np.linalg.inv(np.asarray(truth["abs_H_ref"], float))
    delta = truth["plate"]["smr_offset_mm"]
    return {n: ref_H_abs[:3, :3] @ np.asarray(P, float) + ref_H_abs[:3, 3] + [0, 0, delta]
            for n, P in truth["nests_abs"].items()}


def score_nests(plate: dict[str, Any], truth: dict[str, Any]) -> dict[str, float]:
    """Per nest: distance of the plate file's seat from the true seat (mm)."""
    seats = true_seats(truth)
    return {n: float(np.linalg.norm(np.asarray(plate["nests_ref_nst"][n], float) - seats[n])) for n in seats}


def score_experiment(result: dict[str, Any], mark: dict[str, Any]) -> dict[str, float]:
    """An experiment result's paper metrics and its marks' ACS error against the true mark (mm)."""
    xy = np.array([m["abs_xyz"][:2] for m in result["marks"]])
    d = xy - [mark["x_mm"], mark["y_mm"]]
    m = result["metrics"]
    return {"enclosing": m["enclosing_diameter_mm"], "pairwise": m["pairwise_mean_mm"],
            "abs_rms": float(np.sqrt(np.mean(np.sum(d ** 2, axis=1)))),
            "grand_mean": float(np.hypot(*d.mean(axis=0)))}


__all__ = ["FULL_WIDTH_PX", "score_camera_model", "score_experiment", "score_nests", "score_rob_H_cam",
           "true_seats"]
