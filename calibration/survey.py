"""Plate survey: nest positions in PCS by triangulation (the paper's stereo step).

Each view k has a known plate pose ``ref_H_cam,k`` (from the target, e.g. the
inverse of ``cam_H_ref``) and the nest's image point ``uv_k``. Its viewing ray in PCS
starts at the camera centre ``C_k`` with direction ``d_k``; the nest centre is the
point closest to all rays in the least-squares sense,
``Σ (I − d_k d_kᵀ)·X = Σ (I − d_k d_kᵀ)·C_k``. Residuals are reported per view as the
distance of X from the ray (mm) and as reprojection error (px).

The surveyed ring centre is the nest seat ``ref_P_nst``; the mounted SMR centre is
``ref_P_smr = ref_P_nst − (0, 0, δ)`` (PCS z points into the plate), which
:class:`calibration.plate.Plate` applies.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from calibration.errors import CalibrationError
from calibration.frames import apply_H, check_H, inv_H
from calibration.plate import NEST_NAMES, Plate

if TYPE_CHECKING:  # the caller's models: this module needs no OpenCV
    from typing import TypeAlias

    from calibration.camera_model import CameraModel

    #: one model shared by every view, or one per view
    CameraModels: TypeAlias = CameraModel | list[CameraModel] | tuple[CameraModel, ...]

#: rays closer to parallel than this cannot locate a point along them
MIN_RAY_ANGLE_DEG = 2.0


@dataclass
class Triangulation:
    """One surveyed point with its per-view residuals."""

    ref_P: np.ndarray  # (3,) mm
    ray_dist_mm: list[float]  # distance of ref_P from each view's ray
    reproj_px: list[float]  # reprojection error per view
    max_angle_deg: float  # widest angle between two rays (the stereo baseline angle)

    @property
    def rms_mm(self) -> float:
        """RMS distance of the point from the rays, mm."""
        return float(np.sqrt(np.mean(np.square(self.ray_dist_mm))))

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return {"ref_P_mm": self.ref_P.tolist(), "ray_dist_mm": self.ray_dist_mm, "reproj_px": self.reproj_px,
                "rms_mm": self.rms_mm, "max_angle_deg": self.max_angle_deg}


def intersect_rays(C: Any, d: Any) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares point of rays (centres C (K, 3), directions d (K, 3)): (X, distances, max angle deg)."""
    C = np.asarray(C, dtype=float).reshape(-1, 3)
    d = np.asarray(d, dtype=float).reshape(-1, 3)
    if len(C) < 2 or len(C) != len(d):
        raise ValueError(f"intersect_rays: need >= 2 rays with matching centres, got {len(C)} and {len(d)}")
    if not (np.all(np.isfinite(C)) and np.all(np.isfinite(d))):
        raise ValueError("intersect_rays: non-finite ray centre or direction")
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    cosines = np.clip(np.abs(d @ d.T), 0.0, 1.0)
    max_angle = float(np.degrees(np.arccos(cosines.min())))
    if max_angle < MIN_RAY_ANGLE_DEG:
        raise CalibrationError(f"views are too close to parallel to triangulate: widest angle between rays "
                               f"{max_angle:.2f}° < {MIN_RAY_ANGLE_DEG}°")
    P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]  # projectors onto each ray's normal plane
    A = P.sum(axis=0)
    b = np.einsum("kij,kj->i", P, C)
    X = np.linalg.solve(A, b)
    dist = np.linalg.norm(np.einsum("kij,kj->ki", P, X - C), axis=1)
    return X, dist, max_angle


def triangulate(ref_H_cams: Sequence[np.ndarray], uvs: Any, models: CameraModels) -> Triangulation:
    """Triangulate one point seen at pixel ``uvs[k]`` by camera ``models[k]`` (or one shared model)
    at ``ref_H_cams[k]``."""
    uvs = np.asarray(uvs, dtype=float).reshape(-1, 2)
    if len(ref_H_cams) != len(uvs):
        raise ValueError(f"triangulate: {len(ref_H_cams)} poses but {len(uvs)} image points")
    ms = list(models) if isinstance(models, (list, tuple)) else [models] * len(uvs)
    if len(ms) != len(uvs):
        raise ValueError(f"triangulate: {len(ms)} camera models for {len(uvs)} views")
    Hs = [check_H(H, f"ref_H_cam[{k}]") for k, H in enumerate(ref_H_cams)]
    C = np.array([H[:3, 3] for H in Hs])
    d = np.array([H[:3, :3] @ m.rays(uv[None, :])[0] for H, m, uv in zip(Hs, ms, uvs)])
    X, dist, ang = intersect_rays(C, d)
    reproj = []
    for H, m, uv in zip(Hs, ms, uvs):
        P_cam = apply_H(inv_H(H), X)
        if P_cam[2] <= 0:
            raise CalibrationError(f"triangulated point {X.round(3).tolist()} is behind a camera")
        reproj.append(float(np.linalg.norm(m.project(P_cam[None, :])[0] - uv)))
    return Triangulation(X, dist.tolist(), reproj, ang)


@dataclass
class PlateSurvey:
    """Surveyed nest seats in PCS and the triangulation behind each."""

    nests_ref_nst: dict[str, list[float]]
    triangulations: dict[str, Triangulation] = field(default_factory=dict)

    def apply_to(self, plate: Plate, note: str = "nests from survey") -> Plate:
        """A copy of ``plate`` with the surveyed nest seats (validated by :class:`Plate`)."""
        return replace(plate, nests_ref_nst={k: list(v) for k, v in self.nests_ref_nst.items()},
                       notes=(plate.notes + "; " if plate.notes else "") + note)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return {"nests_ref_nst": self.nests_ref_nst,
                "triangulations": {k: t.to_dict() for k, t in self.triangulations.items()}}


def survey_nests(views: dict[str, tuple[Sequence[np.ndarray], Any]], models: CameraModels,
                 max_ray_dist_mm: float = 0.1) -> PlateSurvey:
    """Triangulate each nest from ``views[name] = (ref_H_cams, uvs)``; all three nests are required.

    A nest whose rays miss the solution by more than ``max_ray_dist_mm`` is an error
    (a mismatched ring or a wrong plate pose in one view).
    """
    missing = [n for n in NEST_NAMES if n not in views]
    if missing:
        raise ValueError(f"survey_nests: no views for nest(s) {missing}")
    out = PlateSurvey({})
    for name in NEST_NAMES:
        Hs, uvs = views[name]
        t = triangulate(Hs, uvs, models)
        worst = max(t.ray_dist_mm)
        if worst > max_ray_dist_mm:
            raise CalibrationError(f"nest {name!r}: rays miss the triangulated point by up to {worst:.3f} mm "
                                   f"(limit {max_ray_dist_mm} mm); check the ring detection and plate poses")
        out.nests_ref_nst[name] = t.ref_P.tolist()
        out.triangulations[name] = t
    return out
