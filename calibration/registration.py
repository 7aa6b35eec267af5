"""Plate pose from the three reflector nests: rigid least-squares fit without scale.

The tracker measures the three mounted SMRs in ACS (``abs_P_i``); the plate definition
and the image give the same centres in SCS (``scn_P_i = scn_H_ref · ref_P_smr,i``).
Kabsch's SVD solution with the reflection fix (Kabsch 1976; Umeyama 1991) gives
``abs_H_scn``. No scale is fitted: tracker and plate are both metric, and a scale from
three points would only absorb errors.

Swapped nest labels are caught two ways: a transposition of an (almost) symmetric
triangle can only be fitted by turning the plate upside down, so fits whose SCS z axis
points away from the robot are rejected; any other relabelling shows up as a large
residual. A symmetric triangle cannot tell a cyclic relabelling from the truth; the
fit says so in ``label_check`` instead of pretending to have verified it.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calibration.errors import CalibrationError
from calibration.frames import apply_H, assert_rotations, check_H, make_H
from calibration.plate import NEST_NAMES

#: a relabelling must beat the labels as given by this factor to be called a swap
SWAP_FACTOR = 5.0


def as_points(P: Any, name: str, n: int | None = None) -> np.ndarray:
    """Return ``P`` as a finite float (N, 3) array or raise ValueError naming it."""
    a = np.asarray(P, dtype=float)
    if a.ndim == 1 and a.shape == (3,):
        a = a[None, :]
    if a.ndim != 2 or a.shape[1] != 3 or (n is not None and a.shape[0] != n):
        want = f"({n}, 3)" if n is not None else "(N, 3)"
        raise ValueError(f"{name}: expected a {want} array of points, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: contains non-finite values {a.tolist()}")
    return a


def nest_array(P: Any, name: str) -> np.ndarray:
    """Nest points as a (3, 3) array in the order red, green, blue (dict or array input)."""
    if isinstance(P, dict):
        missing = [n for n in NEST_NAMES if n not in P]
        if missing:
            raise ValueError(f"{name}: missing nest(s) {missing}; have {sorted(P)}")
        P = [P[n] for n in NEST_NAMES]
    return as_points(P, name, 3)


@dataclass
class RigidFit:
    """Result of a rigid fit ``B_P ≈ B_H_A · A_P``."""

    B_H_A: np.ndarray
    residuals: np.ndarray  # (N, 3): B_P − B_H_A · A_P, mm
    rms: float  # sqrt(mean |residual|²), mm


def kabsch(A_P: Any, B_P: Any) -> RigidFit:
    """Least-squares rigid transform (no scale) mapping points ``A_P`` onto ``B_P``."""
    A = as_points(A_P, "A_P")
    B = as_points(B_P, "B_P", len(A))
    if len(A) < 3:
        raise ValueError(f"kabsch: need at least 3 point pairs, got {len(A)}")
    a_mean, b_mean = A.mean(axis=0), B.mean(axis=0)
    a, b = A - a_mean, B - b_mean
    s = np.linalg.svd(a, compute_uv=False)
    if s[1] < 1e-6 * max(s[0], 1e-12):
        raise CalibrationError(f"kabsch: points are collinear (singular values {s.round(6).tolist()}); "
                               "the rotation about their line is undetermined")
    U, _, Vt = np.linalg.svd(a.T @ b)
    # three points are coplanar (rank 2): without the sign fix about half the noisy
    # cases come back as reflections
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0)])
    R = Vt.T @ D @ U.T
    H = make_H(R, b_mean - R @ a_mean, "kabsch B_H_A")
    res = B - apply_H(H, A)
    return RigidFit(H, res, float(np.sqrt(np.mean(np.sum(res ** 2, axis=1)))))


def kabsch_many(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """:func:`kabsch` of a stack of point sets (n, N, 3) onto (n, N, 3): the transforms (n, 4, 4).

    The same solution and the same checks (finite points, not collinear, a proper
    rotation) for every set at once; for the Monte Carlo samples of a referencing.
    """
    A, B = np.asarray(A, dtype=float), np.asarray(B, dtype=float)
    if A.ndim != 3 or A.shape[2] != 3 or B.shape != A.shape or A.shape[1] < 3:
        raise ValueError(f"kabsch_many: expected two (n, N>=3, 3) stacks, got {A.shape} and {B.shape}")
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(B))):
        raise ValueError("kabsch_many: contains non-finite values")
    a_mean, b_mean = A.mean(axis=1), B.mean(axis=1)
    a, b = A - a_mean[:, None], B - b_mean[:, None]
    s = np.linalg.svd(a, compute_uv=False)
    bad = s[:, 1] < 1e-6 * np.maximum(s[:, 0], 1e-12)
    if np.any(bad):
        sv = s[bad][0].round(6).tolist()
        raise CalibrationError(f"kabsch: points are collinear (singular values {sv}); "
                               "the rotation about their line is undetermined")
    U, _, Vt = np.linalg.svd(np.swapaxes(a, 1, 2) @ b)
    V, Ut = np.swapaxes(Vt, 1, 2), np.swapaxes(U, 1, 2)
    d = np.sign(np.linalg.det(V @ Ut))
    V[:, :, 2] *= np.where(d == 0, 1.0, d)[:, None]  # the reflection fix of kabsch: V·diag(1, 1, d)
    R = V @ Ut
    assert_rotations(R, "kabsch B_H_A")
    H = np.broadcast_to(np.eye(4), (len(A), 4, 4)).copy()
    H[:, :3, :3] = R
    H[:, :3, 3] = b_mean - np.einsum("nij,nj->ni", R, a_mean)
    return H


@dataclass
class PlateFit:
    """Plate pose ``abs_H_scn`` with per-nest residuals and the label check."""

    abs_H_scn: np.ndarray
    residuals_mm: dict[str, list[float]]
    rms_mm: float
    rms_limit_mm: float
    label_check: str  # "unique" or why the labels could not be verified
    permutation_rms_mm: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (lists, floats)."""
        return {"abs_H_scn": self.abs_H_scn.tolist(), "residuals_mm": self.residuals_mm,
                "rms_mm": self.rms_mm, "rms_limit_mm": self.rms_limit_mm,
                "label_check": self.label_check, "permutation_rms_mm": self.permutation_rms_mm}


def describe_permutation(perm: tuple[int, ...]) -> str:
    """Plain words for a relabelling: 'red<->green' or 'red->green->blue->red'."""
    moved = [i for i in range(3) if perm[i] != i]
    if not moved:
        return "as labelled"
    if len(moved) == 2:
        return f"{NEST_NAMES[moved[0]]}<->{NEST_NAMES[moved[1]]}"
    # perm[i] = j: the point labelled i is really nest j
    return "->".join(NEST_NAMES[k] for k in (0, perm[0], perm[perm[0]], 0))


def fit_plate(scn_P: Any, abs_P: Any, sigma_mm: float, abs_up: Any | None = None,
              rms_factor: float = 3.0) -> PlateFit:
    """Fit ``abs_H_scn`` to the three nests and check labels and residuals.

    ``scn_P`` and ``abs_P`` are the SMR centres of red, green, blue (array rows or
    dict). ``sigma_mm`` is the expected per-coordinate error of a nest (tracker and
    plate definition combined); RMS above ``rms_factor·sigma_mm`` is an error.
    ``abs_up`` is a direction the plate's SCS z axis must point along (toward the
    robot reflector); a fit needing an upside-down plate is treated as mislabelled.
    """
    scn = nest_array(scn_P, "scn_P nests")
    ab = nest_array(abs_P, "abs_P nests")
    if not np.isfinite(sigma_mm) or sigma_mm <= 0:
        raise ValueError(f"fit_plate: sigma_mm must be > 0, got {sigma_mm}")
    up = None if abs_up is None else as_points(abs_up, "abs_up", 1)[0]
    limit = rms_factor * sigma_mm

    fits: dict[tuple[int, ...], tuple[RigidFit, bool]] = {}
    for perm in itertools.permutations(range(3)):
        # the point labelled i is taken to be nest perm[i]
        f = kabsch(scn[list(perm)], ab)
        upright = up is None or float(f.B_H_A[:3, 2] @ up) > 0
        fits[perm] = (f, upright)
    ident = (0, 1, 2)
    f0, up0 = fits[ident]
    valid = {p: f.rms for p, (f, ok) in fits.items() if ok}
    perm_rms = {describe_permutation(p): round(f.rms, 6) for p, (f, ok) in fits.items()}
    others = {p: r for p, r in valid.items() if p != ident}
    best = min(others, key=lambda p: others[p]) if others else None

    if not up0 or f0.rms > limit:
        why = ("needs the plate upside down (SCS z away from the robot)" if not up0
               else f"RMS {f0.rms:.4f} mm > {limit:.4f} mm ({rms_factor:g}·σ)")
        if best is not None and others[best] <= limit:
            by_rms = sorted(others.items(), key=lambda x: x[1])
            fitting = " or ".join(describe_permutation(p) for p, r in by_rms if r <= limit)
            raise CalibrationError(
                f"nest labels look swapped ({fitting}): the fit as labelled {why}; "
                f"relabelled it fits with RMS {others[best]:.4f} mm. Check which SMR sits in which nest.")
        raise CalibrationError(f"nest fit as labelled {why}, and no relabelling fits within "
                               f"{limit:.4f} mm (best {min(valid.values(), default=float('nan')):.4f} mm); "
                               "check the nest measurements and the plate definition")
    if best is not None and others[best] * SWAP_FACTOR < f0.rms and f0.rms > sigma_mm:
        raise CalibrationError(
            f"nest labels look swapped ({describe_permutation(best)}): RMS {f0.rms:.4f} mm as labelled, "
            f"{others[best]:.4f} mm relabelled")
    if best is not None and others[best] <= limit:
        label_check = (f"ambiguous: relabelling {describe_permutation(best)} fits too "
                       f"(RMS {others[best]:.4f} mm; symmetric nest triangle), labels taken as given")
    else:
        label_check = "unique"
    check_H(f0.B_H_A, "abs_H_scn")
    residuals = {n: f0.residuals[i].tolist() for i, n in enumerate(NEST_NAMES)}
    return PlateFit(f0.B_H_A, residuals, f0.rms, limit, label_check, perm_rms)
