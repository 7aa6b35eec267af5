"""Instrument reversal of referencings (Evans, Hocken and Estler, "Self-calibration:
reversal, redundancy, error separation, and absolute testing", CIRP Annals 45(2), 1996).

Referencing twice with the robot turned 180° on the plate flips the sign of every
plate-fixed error (nest coordinates, target-to-nest offset, tracker systematics) as
seen in the robot frame, while robot-fixed errors stay. The mean of the two
``rob_H_scn`` cancels the plate-fixed share to first order; half their difference
measures it. With N referencings at ψ0 + k·360°/N the mean also averages the
random errors.

Each referencing makes its own SCS (``make_scs`` places it from its image), so all
``rob_H_scn`` are first re-expressed in the SCS of the first referencing:
``rob_H_scn,k' = rob_H_cam,k · cam_H_scn,0``. Translations are averaged, rotations
by the chordal mean (the arithmetic mean projected back onto SO(3)). To measure
with the combined ``rob_H_scn``, use the SCS of the first referencing
(``make_scs(model, results[0].cam_H_ref)``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, Sequence

import numpy as np

from calibration.frames import check_H, inv_H, make_H, rotation_angle
from calibration.uncertainty import PoseUncertainty, footprint, rotvec


def chordal_mean(Rs: Sequence[np.ndarray]) -> np.ndarray:
    """Rotation closest (Frobenius) to the arithmetic mean of ``Rs``: a proper rotation."""
    if len(Rs) == 0:
        raise ValueError("chordal_mean: no rotations given")
    M = np.mean(np.asarray(Rs, dtype=float), axis=0)
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(U @ Vt)) or 1.0)])
    return U @ D @ Vt


@dataclass
class ReversalResult:
    """Combined calibration and the separated plate-fixed error."""

    rob_H_scn: np.ndarray  # mean, in the SCS of the first referencing
    rob_H_cam: np.ndarray
    scn_H_cam: np.ndarray  # the common SCS
    headings_deg: list[float]  # robot heading of each referencing in ACS
    half_diff_t_mm: list[float] | None  # (t_0 − t_1)/2 of rob_H_scn, RCS, two referencings only
    half_diff_rot_deg: list[float] | None  # half the rotation vector of R_0·R_1ᵀ, degrees
    half_diff_footprint_mm: list[float] | None  # half the footprint difference, RCS xy
    footprint_dev_mm: list[list[float]]  # each referencing's footprint minus the combined one
    messages: list[str] = field(default_factory=list)
    #: covariance of the combined rob_H_scn (δt mm, δr rad): Σ cov_k / N², None if any input lacks one
    cov_rob_H_scn: np.ndarray | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return {"rob_H_scn": self.rob_H_scn.tolist(), "rob_H_cam": self.rob_H_cam.tolist(),
                "scn_H_cam": self.scn_H_cam.tolist(), "headings_deg": self.headings_deg,
                "half_diff_t_mm": self.half_diff_t_mm, "half_diff_rot_deg": self.half_diff_rot_deg,
                "half_diff_footprint_mm": self.half_diff_footprint_mm,
                "footprint_dev_mm": self.footprint_dev_mm, "messages": list(self.messages),
                "cov_rob_H_scn": None if self.cov_rob_H_scn is None else self.cov_rob_H_scn.tolist()}


class Referenced(Protocol):
    """What :func:`combine` needs of one referencing (:class:`calibration.referencing.ReferencingResult`
    is one); an ``uncertainty`` (:class:`PoseUncertainty`) is used when every referencing has one."""

    rob_H_cam: np.ndarray
    scn_H_cam: np.ndarray
    abs_H_rob: np.ndarray


def combine(results: Sequence[Referenced], max_heading_error_deg: float = 20.0) -> ReversalResult:
    """Combine referencings (objects with ``rob_H_cam``, ``scn_H_cam``, ``abs_H_rob``) by reversal.

    The headings should be evenly spread (180° apart for two); a larger departure than
    ``max_heading_error_deg`` is reported in ``messages``, since the plate-fixed errors
    then no longer cancel.
    """
    if len(results) < 2:
        raise ValueError(f"combine: reversal needs at least 2 referencings, got {len(results)}")
    scn_H_cam = check_H(results[0].scn_H_cam, "scn_H_cam[0]")
    cam_H_scn = inv_H(scn_H_cam)
    rob_H_scns = [check_H(r.rob_H_cam, f"rob_H_cam[{i}]") @ cam_H_scn for i, r in enumerate(results)]
    R = chordal_mean([H[:3, :3] for H in rob_H_scns])
    t = np.mean([H[:3, 3] for H in rob_H_scns], axis=0)
    rob_H_scn = make_H(R, t, "combined rob_H_scn")
    rob_H_cam = rob_H_scn @ scn_H_cam
    foot = footprint(rob_H_cam, rob_H_scn)
    feet = [footprint(H @ scn_H_cam, H) for H in rob_H_scns]

    headings = [float(np.degrees(np.arctan2(r.abs_H_rob[1, 0], r.abs_H_rob[0, 0]))) for r in results]
    messages = []
    n = len(results)
    order = np.sort(np.mod(np.array(headings) - headings[0], 360.0))
    ideal = np.arange(n) * 360.0 / n
    worst = float(np.max(np.abs((order - ideal + 180.0) % 360.0 - 180.0)))
    if worst > max_heading_error_deg:
        messages.append(f"headings {np.round(headings, 1).tolist()} are up to {worst:.1f}° from an even "
                        f"{360.0 / n:.0f}° spacing: plate-fixed errors cancel only partly")
    half_t = half_r = half_f = None
    if n == 2:
        a, b = rob_H_scns
        half_t = ((a[:3, 3] - b[:3, 3]) / 2).tolist()
        half_r = (np.degrees(rotvec(a[:3, :3] @ b[:3, :3].T)) / 2).tolist()
        half_f = ((feet[0] - feet[1])[:2] / 2).tolist()
        spread = np.degrees(rotation_angle(a[:3, :3] @ b[:3, :3].T))
        messages.append(f"separated plate-fixed error: footprint {np.hypot(*half_f) * 1000:.1f} µm, "
                        f"rotation {spread / 2:.4f}°")
    # independent referencings: the mean's covariance is Σ cov_k / N² (the SCS origins differ
    # by millimetres, which moves the translation part by far less than a micrometre)
    uncs: list[PoseUncertainty | None] = [getattr(r, "uncertainty", None) for r in results]
    covs = [u.cov_rob_H_scn for u in uncs if u is not None]
    cov = None if len(covs) < n else sum(covs, np.zeros_like(covs[0])) / n ** 2
    return ReversalResult(rob_H_scn, rob_H_cam, scn_H_cam, headings, half_t, half_r, half_f,
                          [(f - foot)[:2].tolist() for f in feet], messages, cov)
