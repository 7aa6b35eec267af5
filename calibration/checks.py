"""Self-checks: what a result's own data can show about the model it was computed with.

On the real robot nobody has ground truth, so every compensation is checked against the
data it uses before it is applied, and a result whose data contradict its model says
``warn`` with the reason. Each check returns None when it passes (or cannot be made) and
the operator's sentence when it fails.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

#: how many stream points at each end stand for the standstill there (the stream starts before the move)
END_POINTS = 3
#: a check fails beyond this many standard deviations
CHECK_Z = 4.0
#: the least tilt disagreement (deg) a check reports: the inclinometer's own noise class
TILT_FLOOR_DEG = 0.005


def stream_ends_check(stream: np.ndarray, abs_P_prev: np.ndarray, abs_P_at: np.ndarray,
                      sigma_mm: float) -> str | None:
    """The stream's ends against the chord between the standstill points: a path leaves and joins it.

    Sideways only (the stream may start or end a little inside the move when it was thinned):
    a bend is zero at both anchors, so an end that lies off the chord means the stream is in
    another frame or shifted in time against the standstill measurements.
    """
    P = np.asarray(stream, float)[:, :2]
    if len(P) < 2 * END_POINTS:
        return None
    a, b = np.asarray(abs_P_prev, float)[:2], np.asarray(abs_P_at, float)[:2]
    L = float(np.linalg.norm(b - a))
    if L <= 0:
        return None
    n = np.array([-(b - a)[1], (b - a)[0]]) / L
    k = min(END_POINTS, len(P) // 2)
    gaps = [abs(float(np.median((P[:k] - a) @ n))), abs(float(np.median((P[-k:] - b) @ n)))]
    limit = CHECK_Z * max(sigma_mm, 0.001) + 0.010  # 10 µm for the bend near the ends
    if max(gaps) <= limit:
        return None
    return (f"the tracker's stream does not run between the standstill points (its ends lie "
            f"{gaps[0]:.3f} and {gaps[1]:.3f} mm beside the chord, allowed {limit:.3f} mm): its timing "
            f"or frame is off; the chord is used")


def stream_tilt_check(stream_tilt: np.ndarray, tilt_prev: Sequence[float], tilt_at: Sequence[float],
                      sigma_deg: float) -> str | None:
    """The inclinometer's readings along the stream at its ends against the standstill means."""
    t = np.asarray(stream_tilt, float)
    if len(t) < 2 * END_POINTS:
        return None
    k = min(END_POINTS, len(t) // 2)
    gaps = [float(np.max(np.abs(np.median(t[:k], axis=0) - np.asarray(tilt_prev, float)))),
            float(np.max(np.abs(np.median(t[-k:], axis=0) - np.asarray(tilt_at, float))))]
    limit = CHECK_Z * max(sigma_deg, TILT_FLOOR_DEG)
    if max(gaps) <= limit:
        return None
    return (f"the inclinometer along the stream disagrees with the standstill readings at its ends by "
            f"{max(gaps):.4f}° (allowed {limit:.4f}°): the tilt along the move is not used")


def bias_model_check(xy: np.ndarray, labels: Sequence[Any], fit_rms_mm: float | None,
                     stated_sigma_mm: Sequence[float]) -> dict[str, Any]:
    """Do the cluster means follow ``M + R(ψ)·b``? Their fit residual against the expected scatter.

    The expected RMS of a cluster mean (per coordinate) comes from the within-direction scatter
    when each direction was repeated, else from the marks' stated σ. A residual well beyond it
    is a heading-dependent error that is no robot-frame bias: storing b would not remove it.
    """
    xy = np.asarray(xy, float)
    names = list(dict.fromkeys(str(g) for g in labels))
    idx = [np.array([i for i, g in enumerate(labels) if str(g) == n]) for n in names]
    k = len(names)
    out: dict[str, Any] = {"residual_rms_mm": fit_rms_mm, "expected_rms_mm": None,
                           "ok": True, "message": None}
    if fit_rms_mm is None or k < 4:  # 4 unknowns: with 3 directions the fit is exact
        return out
    within = [xy[i] - xy[i].mean(axis=0) for i in idx if len(i) >= 2]
    dof = sum(len(w) - 1 for w in within)
    if dof >= 2:
        var = float(sum((w ** 2).sum() for w in within)) / (2 * dof)  # per coordinate
        source = "the within-direction scatter"
    else:
        var = float(np.mean(np.square(stated_sigma_mm)))
        source = "the marks' stated σ"
    per_mean = var / np.mean([len(i) for i in idx])
    expected = float(np.sqrt(2 * per_mean * (2 * k - 4) / (2 * k)))  # 2D, as fit_bias's rms; 4 of 2k taken
    out["expected_rms_mm"] = expected
    if fit_rms_mm > CHECK_Z * expected + 0.002:
        out["ok"] = False
        out["message"] = (f"the cluster means do not follow M + R(ψ)·b: the fit leaves {fit_rms_mm:.4f} mm "
                          f"RMS where {source} expects {expected:.4f} mm; an error that depends on the "
                          f"heading other than a robot-frame bias (floor, tracker line of sight, reflector "
                          f"mount) is present, and a stored bias would not remove it")
    return out
