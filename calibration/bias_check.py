"""The stored robot-frame bias: how well it is known, and whether it still holds where it is used.

An experiment that stores b (``store_bias``) corrects every later mark by it. A correction is a measured
value: what it is not known to goes into every mark it corrects (JCGM 100:2008 (GUM) §3.2.4 and §F.2.4.5:
the uncertainty of a correction is a component of the result's), and in the same direction at every stop
of one heading: ACS covariance R(ψ)·C_b·R(ψ)ᵀ, the mark's part ``bias`` (calibration/measure.py). An
experiment's own check (calibration/coverage.py) cannot see it: its fit of M + R(ψ)·b takes it up.

C_b is estimated as the weight's σ is (calibration/heading_weight.py): the sandwich over stops (each stop's
two rows share one error) or the jackknife over directions (a direction's stops share its floor and path,
so their errors do not average within it), whichever has the larger trace.

An experiment that applied the stored b fits what is left of the bias, b_left, with its own covariance.
If b still holds, b_left ~ N(0, C_b + C_left) and

    χ² = b_leftᵀ · (C_b + C_left)⁻¹ · b_left   follows χ² with 2 degrees of freedom: P(χ² ≥ x) = e^(−x/2).

P < :data:`ALPHA` (the σ check's level) is a stored bias the data contradict: the verdict is ``warn``,
naming both. The learned quantity is re-checked where it is used, as heading_fit's weight is
(calibration/weight_check.py).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Callable

import numpy as np

from calibration.coverage import ALPHA
from calibration.metrics import bias_design, mean_heading_deg

#: the columns of b in :func:`calibration.metrics.bias_design` (and weight_cv.py ``design``)
B_COLUMNS = slice(2, 4)
#: the fewest directions the jackknife over directions is made with
MIN_DIRECTIONS = 5


def sandwich_lstsq(A: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least squares and its covariance, robust to each stop's two rows sharing one error (a heading error
    moves the mark along one direction): the sandwich over stops, with the small-sample factor."""
    theta, *_ = np.linalg.lstsq(A, y, rcond=None)
    r = y - A @ theta
    bread = np.linalg.inv(A.T @ A)
    g = np.einsum("kij,ki->kj", A.reshape(-1, 2, A.shape[1]), r.reshape(-1, 2))  # per stop A_kᵀ r_k
    n, p = len(g), A.shape[1]
    return theta, bread @ (g.T @ g) @ bread * n / max(n - p, 1)


def jackknife_cov(estimate: Callable[[np.ndarray], np.ndarray | None], groups: np.ndarray
                  ) -> np.ndarray | None:
    """The covariance of ``estimate(keep)`` (keep: a boolean mask over stops) from leaving one direction
    out at a time, (G − 1)/G · Σ (θ_g − θ̄)(θ_g − θ̄)ᵀ; None with fewer than :data:`MIN_DIRECTIONS`
    directions or a fold the estimate cannot be made on."""
    names = list(dict.fromkeys(np.asarray(groups).reshape(-1).tolist()))
    if len(names) < MIN_DIRECTIONS:
        return None
    folds = [estimate(np.asarray(groups).reshape(-1) != g) for g in names]
    if any(f is None for f in folds):
        return None
    T = np.array(folds, dtype=float)
    D = T - T.mean(axis=0)
    return (len(T) - 1) / len(T) * D.T @ D


def larger(*covs: np.ndarray | None) -> np.ndarray:
    """The covariance with the larger trace of those given (not None)."""
    return max((c for c in covs if c is not None), key=lambda c: float(np.trace(c)))


def chord_bias(xy: Any, headings_deg: Any, groups: Any) -> tuple[np.ndarray, np.ndarray] | None:
    """(b, C_b): the robot-frame bias of the marks ``xy`` (N, 2) about M + R(ψ)·b, the b that
    calibration/metrics.py ``fit_bias`` fits to the directions' means (``metrics.fit.b``, what ``store_bias``
    stores without a weight), and its covariance (module docstring); None when the headings do not separate
    M from b. The same b as a fit over the stops, each at its direction's mean heading and weighed 1/n_k:
    Σ_k Σ_i |P_ki − M − R(ψ̄_k)·b|² / n_k is Σ_k |P̄_k − M − R(ψ̄_k)·b|² plus a constant, so that the
    sandwich sees each stop and the jackknife's fold is fit_bias on the other directions' means."""
    P = np.asarray(xy, dtype=float).reshape(-1, 2)
    psi = np.asarray(headings_deg, dtype=float).reshape(-1)
    g = np.asarray(groups).reshape(-1)
    names, k, n = np.unique(g, return_inverse=True, return_counts=True)
    mean_h = np.array([mean_heading_deg(psi[k == i]) for i in range(len(names))])
    if len(names) < 3 or np.linalg.cond(bias_design(mean_h)) > 1e6:  # as fit_bias refuses
        return None
    root_w = np.repeat(1.0 / np.sqrt(n[k]), 2)  # rows scaled by √(1/n_k): least squares weighed 1/n_k
    A, y = bias_design(mean_h[k]) * root_w[:, None], P.reshape(-1) * root_w
    theta, cov = sandwich_lstsq(A, y)

    def fold(keep: np.ndarray) -> np.ndarray | None:
        rows = np.repeat(keep, 2)
        if np.linalg.cond(A[rows]) > 1e6:
            return None
        return np.linalg.lstsq(A[rows], y[rows], rcond=None)[0][B_COLUMNS]

    return theta[B_COLUMNS], larger(cov[B_COLUMNS, B_COLUMNS], jackknife_cov(fold, g))


def cov_in_acs(cov_b_mm2: Any, heading_deg: float) -> np.ndarray:
    """The ACS xy covariance a robot-frame bias of covariance ``cov_b_mm2`` (RCS) leaves in a mark taken at
    ``heading_deg``: R(ψ)·C_b·R(ψ)ᵀ."""
    c, s = math.cos(math.radians(heading_deg)), math.sin(math.radians(heading_deg))
    R = np.array([[c, -s], [s, c]])
    return R @ np.asarray(cov_b_mm2, dtype=float) @ R.T


def read_cov(value: Any, source: str) -> np.ndarray:
    """A stored 2 × 2 covariance (mm²); ValueError naming ``source`` when it is not a finite symmetric
    positive semi-definite 2 × 2."""
    try:
        C = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{source}: not a 2x2 covariance ({exc})") from None
    if C.shape != (2, 2) or not np.all(np.isfinite(C)) or not np.allclose(C, C.T) \
            or np.min(np.linalg.eigvalsh(C)) < -1e-12:
        raise ValueError(f"{source}: {np.asarray(value).tolist()} is not a finite symmetric positive "
                         f"semi-definite 2x2 (mm²)")
    return C


@dataclass(frozen=True)
class BiasRecheck:
    """What this experiment leaves of the stored bias against both covariances (module docstring)."""

    b_left_mm: list[float]
    cov_left_mm2: list[list[float]]
    stored_b_mm: list[float]
    stored_cov_mm2: list[list[float]]
    chi2: float
    p: float
    alpha: float
    ok: bool
    message: str | None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def recheck_bias(stored_b: Any, stored_cov: np.ndarray, b_left: np.ndarray, cov_left: np.ndarray,
                 source: str | None = None) -> BiasRecheck:
    """The stored bias ``stored_b`` (covariance ``stored_cov``) against what an experiment that applied it
    leaves, ``b_left`` (``cov_left``); ``source``: the job that stored it, for the message."""
    C = np.asarray(stored_cov, float) + np.asarray(cov_left, float)
    d = np.asarray(b_left, float).reshape(2)
    chi2 = float(d @ np.linalg.pinv(C) @ d)
    p = math.exp(-chi2 / 2.0)
    ok = p >= ALPHA
    sb = np.asarray(stored_b, float).reshape(2)
    message = None if ok else (
        f"the stored robot-frame bias b = ({sb[0]:.4f}, {sb[1]:.4f}) mm "
        f"± {math.sqrt(np.trace(stored_cov)):.4f}"
        f"{f' ({source})' if source else ''} does not hold here: this experiment leaves ({d[0]:.4f}, "
        f"{d[1]:.4f}) mm ± {math.sqrt(np.trace(cov_left)):.4f} after it (χ² {chi2:.1f} over 2 degrees of "
        f"freedom, P {p:.1e} < {ALPHA:g}): store this experiment's bias, or find what changed")
    return BiasRecheck(d.tolist(), np.asarray(cov_left, float).tolist(), sb.tolist(),
                       np.asarray(stored_cov, float).tolist(), chi2, p, ALPHA, ok, message)
