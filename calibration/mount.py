"""The reflector mount's eccentricity, measured by the referencing's reversal (docs/accuracy.md,
"The reflector mount").

The robot's SMR sits in a mount that turns to keep the tracker in sight (paper §Robot: its movement
in the chassis is "sub-mm" and taken as the RCS origin). Assumed: the mount turns about the robot's
vertical only (the paper does not say); one that also tilts toward the tracker would move the
offset with the elevation angle, which this model does not follow. A ball centre off the mount's axis by m
therefore keeps its place relative to the line of sight: in the frame ``los`` (x horizontal from
the reflector toward the tracker, z up, y = z × x) m is constant. In ACS it is the same at every
heading, so no per-stop datum and no robot-frame bias shows it, and every tracker point of the
robot is off by ``abs_R_los · m``.

Both referencings of a reversal (calibration/reversal.py) measured P0 with it, so run k's
rob_H_scn holds −R_kᵀ·m, with opposite signs for runs 180° apart. Half their difference, less
what a rotation about the reflector explains (the chord's heading error turns the camera about
the reflector; m turns nothing), gives it in ACS:

    m̂ = −abs_R_rob,0 · (½Δt + t × ½Δω)          (Δ: run 0 − run 1; t: rob_H_scn's translation)

A plate-fixed translation (nest coordinates, the tracker's pattern at the plate) enters m̂ with
the opposite sign and cannot be told apart by one reversal; the referencings' covariance
(nests, P0, P1, the camera's pose; :func:`half_diff_cov`) states its share. m̂ is applied only
when the data show it: significant against that σ and within the mount's sub-mm.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol, Sequence

import numpy as np

from calibration.frames import assert_rotation

#: χ² (2 degrees of freedom) above which the offset is taken as shown: 99 %
SIGNIFICANT_CHI2 = 9.21
#: the paper bounds the SMR's movement in the mount as sub-mm: a larger estimate is a fault, not a mount
MAX_OFFSET_MM = 1.0
#: the reversal's headings must be 180° apart within this for the plate-fixed errors to cancel
MAX_HEADING_ERROR_DEG = 20.0


def los_R(abs_P: Any, abs_t_trk: Any) -> np.ndarray:
    """``abs_R_los`` at the reflector ``abs_P``: x horizontal toward the tracker at ``abs_t_trk``, z up."""
    d = np.asarray(abs_t_trk, dtype=float).reshape(3) - np.asarray(abs_P, dtype=float).reshape(3)
    h = float(np.hypot(d[0], d[1]))
    if not np.isfinite(h) or h < 1.0:
        raise ValueError(f"los_R: the tracker at {np.round(abs_t_trk, 3).tolist()} is not beside the "
                         f"reflector at {np.round(abs_P, 3).tolist()} (horizontal distance {h:.3f} mm)")
    x = np.array([d[0] / h, d[1] / h, 0.0])
    R = np.column_stack([x, [-x[1], x[0], 0.0], [0.0, 0.0, 1.0]])
    assert_rotation(R, "abs_R_los")
    return R


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@dataclass(frozen=True)
class MountOffset:
    """The estimated offset m̂ in ``los`` (mm), its covariance, and whether marks may apply it."""

    los_mm: np.ndarray  # (2,): toward the tracker, left of it
    cov_los_mm2: np.ndarray  # (2, 2)
    significant: bool
    why: str = ""  # why it is not applied (empty when it is)
    warn: bool = False  # an estimate no mount can give: the referencing's verdict is warn

    @property
    def chi2(self) -> float:
        return float(self.los_mm @ np.linalg.solve(self.cov_los_mm2, self.los_mm))

    def offset_abs(self, abs_P: Any, abs_t_trk: Any) -> np.ndarray:
        """The ACS offset (3,) of a tracker point of the robot at ``abs_P``: subtract it to correct."""
        return los_R(abs_P, abs_t_trk)[:, :2] @ self.los_mm

    def corrected(self, abs_P: Any, abs_t_trk: Any) -> np.ndarray:
        """Points (3,) or (N, 3) with the offset removed, each turned to its own line of sight (over a
        0.2 m move 2 m from the tracker the line of sight turns 6°)."""
        P = np.asarray(abs_P, dtype=float)
        flat = P.reshape(-1, 3)
        return (flat - np.array([self.offset_abs(q, abs_t_trk) for q in flat])).reshape(P.shape)

    def cov_abs_xy(self, abs_P: Any, abs_t_trk: Any, applied: bool) -> np.ndarray:
        """ACS xy covariance (2, 2) the offset leaves in a mark: the estimate's own when it was applied;
        when it was not, the offset itself joins it (m̂ m̂ᵀ: the mark is off by it)."""
        R = los_R(abs_P, abs_t_trk)[:2, :2]
        C = self.cov_los_mm2 if applied else self.cov_los_mm2 + np.outer(self.los_mm, self.los_mm)
        return R @ C @ R.T

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (result.schema.json ``reflector_mount``)."""
        sd = np.sqrt(np.diag(self.cov_los_mm2))
        return {"los_mm": self.los_mm.tolist(), "cov_los_mm2": self.cov_los_mm2.tolist(),
                "sigma_los_mm": sd.tolist(), "magnitude_mm": float(np.hypot(*self.los_mm)),
                "chi2": self.chi2, "significant": self.significant, "why": self.why, "warn": self.warn}

    @classmethod
    def from_dict(cls, d: dict[str, Any], source: str = "reflector_mount") -> "MountOffset":
        """From :meth:`to_dict`; a malformed record is a ValueError naming ``source``."""
        try:
            m = np.asarray(d["los_mm"], dtype=float).reshape(2)
            C = np.asarray(d["cov_los_mm2"], dtype=float).reshape(2, 2)
            sig = bool(d["significant"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{source}: not a reflector mount offset ({exc})") from None
        finite = np.all(np.isfinite(m)) and np.all(np.isfinite(C))
        if not finite or np.linalg.eigvalsh((C + C.T) / 2)[0] <= 0:  # eigvalsh only of finite numbers
            raise ValueError(f"{source}: los_mm {m.tolist()} / cov_los_mm2 {C.tolist()} are not an offset "
                             f"and a positive-definite covariance")
        return cls(m, C, sig, str(d.get("why") or ""), bool(d.get("warn", False)))


def half_diff_cov(cov_runs: Sequence[np.ndarray]) -> np.ndarray:
    """Covariance (6 × 6) of half the two runs' difference, bounded: (C₀ + C₁)/2.

    Independent runs would give (C₀ + C₁)/4, but both runs share the nests' measurement, whose share
    of each run's error flips sign with the robot in RCS and so adds fully to the difference. The
    bound holds whatever that share, where /4 only just covers the errors (docs/accuracy.md), so the
    bound is taken."""
    if len(cov_runs) != 2:
        raise ValueError(f"half_diff_cov: two runs' covariances needed, got {len(cov_runs)}")
    return (np.asarray(cov_runs[0], dtype=float) + np.asarray(cov_runs[1], dtype=float)) / 2.0


def estimate(half_diff_t_mm: Sequence[float], half_diff_rot_deg: Sequence[float], rob_H_scn: np.ndarray,
             abs_H_rob0: np.ndarray, abs_t_trk: Any, cov_half: np.ndarray, headings_deg: Sequence[float]
             ) -> MountOffset:
    """m̂ from a two-run reversal (:class:`calibration.reversal.ReversalResult`'s half differences and
    combined ``rob_H_scn``; ``cov_half`` the half difference's covariance, :func:`half_diff_cov`), run 0's
    pose and the tracker's ACS position. Applied only when significant (χ² > :data:`SIGNIFICANT_CHI2`),
    within :data:`MAX_OFFSET_MM` and from headings 180° apart; ``why`` says which failed."""
    half_t = np.asarray(half_diff_t_mm, dtype=float).reshape(3)
    w = np.radians(np.asarray(half_diff_rot_deg, dtype=float).reshape(3))
    t = np.asarray(rob_H_scn, dtype=float)[:3, 3]
    R0 = np.asarray(abs_H_rob0, dtype=float)[:3, :3]
    assert_rotation(R0, "abs_H_rob0")
    J = np.hstack([np.eye(3), _skew(t)])  # d(½Δt + t × ½Δω) / d(δt, δω)
    C_acs = R0 @ J @ np.asarray(cov_half, dtype=float).reshape(6, 6) @ J.T @ R0.T
    m_acs = -R0 @ (half_t + np.cross(t, w))
    Rl = los_R(abs_H_rob0[:3, 3], abs_t_trk)[:2, :2]  # the offset is horizontal: ACS xy → los xy
    m = Rl.T @ m_acs[:2]
    C = Rl.T @ C_acs[:2, :2] @ Rl
    out = MountOffset(m, C, False)
    turn = abs((float(headings_deg[1]) - float(headings_deg[0])) % 360.0 - 180.0)
    mag = float(np.hypot(*m))
    if turn > MAX_HEADING_ERROR_DEG:
        why = f"the runs' headings are {180.0 - turn:.1f}° apart, not 180°: the offset does not separate"
    elif mag > MAX_OFFSET_MM:
        why = (f"|m̂| = {mag:.3f} mm exceeds the mount's sub-mm ({MAX_OFFSET_MM} mm): check the reflector's "
               f"seat and that the robot stood still on the plate for both runs")
    elif out.chi2 <= SIGNIFICANT_CHI2:
        sd = math.sqrt(float(np.trace(C)) / 2.0)
        why = (f"not shown by the data: |m̂| = {1000 * mag:.0f} µm against its σ {1000 * sd:.0f} µm "
               f"(χ² {out.chi2:.1f} ≤ {SIGNIFICANT_CHI2})")
    else:
        return MountOffset(m, C, True)
    return MountOffset(m, C, False, why, warn=mag > MAX_OFFSET_MM)


class _Run(Protocol):
    abs_H_rob: np.ndarray
    uncertainty: Any  # calibration.uncertainty.PoseUncertainty | None


def from_reversal(rev: Any, runs: Sequence[_Run], abs_t_trk: Any) -> tuple[MountOffset | None, str]:
    """The offset of a combined reversal (:class:`calibration.reversal.ReversalResult`) and its two runs
    (referencing results), or None and why it cannot be estimated."""
    covs = [r.uncertainty.cov_rob_H_scn for r in runs if getattr(r, "uncertainty", None) is not None]
    if len(runs) != 2 or rev.half_diff_t_mm is None or rev.half_diff_rot_deg is None:
        return None, f"the reversal has {len(runs)} runs; the offset needs two, 180° apart"
    if len(covs) != 2:
        return None, ("the runs state no covariance (Monte Carlo off): the offset's significance "
                      "cannot be tested")
    if abs_t_trk is None:
        return None, "P0 carries no abs_H_trk: the line of sight to the tracker is unknown"
    return estimate(rev.half_diff_t_mm, rev.half_diff_rot_deg, rev.rob_H_scn, runs[0].abs_H_rob, abs_t_trk,
                    half_diff_cov(covs), rev.headings_deg), ""


def message(m: MountOffset) -> str:
    """The referencing result's line about the offset."""
    sd = np.sqrt(np.diag(m.cov_los_mm2)) * 1000
    fig = (f"reflector mount offset {1000 * m.los_mm[0]:+.0f} µm toward the tracker, "
           f"{1000 * m.los_mm[1]:+.0f} µm left of it (±{sd[0]:.0f}, ±{sd[1]:.0f} µm)")
    why = "marks measured with compensation 'mount' correct it" if m.significant else m.why
    return f"{fig}: {why}"
