"""Floor-mark measurement: image → SCS → RCS → ACS (paper, "Point measurement").

``rob_P_mrk = rob_H_scn · (map_image→scn(uv), 0, 1)`` and ``abs_P_mrk = abs_H_rob · rob_P_mrk``.
At use the robot pose comes from the reflector at its stop (P_at) and one earlier
position on the straight approach (P_prev): x = the approach direction projected
onto the floor, z = the floor normal (default ACS z), origin P_at. When the base
reports roll and pitch, the frame is rotated by them about its own axes
(``R = [v⊥ c n] · R_y(pitch) · R_x(roll)``, the world's convention), which removes
the tilt × reflector-height error (docs/accuracy.md, "Error magnitudes").

The uncertainty is first order: a numerical Jacobian of the whole mapping with
respect to the two tracker points (σ_t each), the mark's pixel position (σ_px),
the calibration ``rob_H_scn`` (its Monte Carlo covariance), the reported tilt and the
heading (σ_ψ: the robot pose turned about the floor normal through P_at). The heading
term is the one the tracker points cannot show: the chord P_prev → P_at is off the final
heading by the path's bend (:data:`CHORD_HEADING_SIGMA_RAD`), and it moves the mark by
σ_ψ × its lever arm from the reflector. :func:`tracker_sigma_mm` gives σ_t from the
tracker's data-sheet MPE at its distance to the points (docs/accuracy.md).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from calibration.frames import apply_H, check_H, make_H, rot_x, rot_y
from calibration.referencing import robot_pose
from calibration.registration import as_points
from calibration.uncertainty import perturb_pose, rotmat

if TYPE_CHECKING:  # imported by the caller that builds one: measuring needs no cv2 of its own
    from calibration.scs import Scs

#: tracker 1σ per coordinate when neither the dataset nor the tracker's distance gives one (mm)
DEFAULT_SIGMA_T_MM = 0.010
#: AT901 U_xyz MPE = ±(A + B·D): A (mm) and B (mm per m of distance) (docs/accuracy.md, "Reference figures")
AT901_MPE_A_MM, AT901_MPE_B_MM_PER_M = 0.015, 0.006
#: typical = ½ MPE (Leica, AT500 manual p. 39), taken as 1σ
MPE_TO_SIGMA = 0.5
#: the drive's lateral path deviation over the approach it refers to (mm; docs/accuracy.md, "Error
#: magnitudes")
PATH_DEVIATION_MM, APPROACH_MM = 0.050, 200.0
#: the chord P_prev → P_at's 1σ heading error from that deviation: 50 µm / 200 mm = 250 µrad
CHORD_HEADING_SIGMA_RAD = PATH_DEVIATION_MM / APPROACH_MM
#: finite-difference steps: mm, rad, px
_STEP_MM, _STEP_RAD, _STEP_PX = 1e-3, 1e-6, 1e-2
#: the inputs' blocks in the Jacobian's parameter vector (a 17-vector), by name
BLOCKS = {"tracker": slice(0, 6), "pixel": slice(6, 8), "calibration": slice(8, 14), "tilt": slice(14, 16),
          "heading": slice(16, 17)}


def tracker_sigma_mm(distance_mm: float) -> float:
    """The tracker's 1σ per coordinate (mm) at ``distance_mm`` from its head, from the data sheet's MPE.

    Leica AT901: U_xyz MPE = ±15 µm + 6 µm/m (docs/accuracy.md, "Reference figures"; Leica publishes
    exactly this for the AT500, manual p. 39 — unverified for the AT901), typical = ½ MPE,
    taken as 1σ: σ = ½·(15 µm + 6 µm/m · D). 7.5 µm at the head, 22.2 µm at 4.9 m. Per
    coordinate and independent per point, which overstates the relative error of nearby points
    (they share most of the systematic part): conservative for the heading between two stops.
    """
    d = float(distance_mm)
    if not np.isfinite(d) or d < 0:
        raise ValueError(f"tracker_sigma_mm: distance must be a finite length >= 0 (mm), got {distance_mm}")
    return MPE_TO_SIGMA * (AT901_MPE_A_MM + AT901_MPE_B_MM_PER_M * d / 1000.0)


def stated_tracker_sigma(stated_mm: float | None, distance_mm: float | None) -> tuple[float, str]:
    """(σ_t mm, its source): the dataset's ``sigma_t_mm`` when stated ("dataset"), else the MPE at the
    tracker's distance ("distance"), else :data:`DEFAULT_SIGMA_T_MM` ("default")."""
    if stated_mm is not None:
        return float(stated_mm), "dataset"
    if distance_mm is not None:
        return tracker_sigma_mm(distance_mm), "distance"
    return DEFAULT_SIGMA_T_MM, "default"


def robot_pose_at(abs_P_prev: Any, abs_P_at: Any, abs_n: Any = None, roll_deg: float | None = None,
                  pitch_deg: float | None = None) -> np.ndarray:
    """``abs_H_rob`` at a stop from the approach (P_prev → P_at), floor normal and reported tilt."""
    P_prev = as_points(abs_P_prev, "abs_P_prev", 1)[0]
    P_at = as_points(abs_P_at, "abs_P_at", 1)[0]
    n = np.array([0.0, 0.0, 1.0]) if abs_n is None else as_points(abs_n, "abs_n", 1)[0]
    H = robot_pose(P_at, P_at - P_prev, n)
    if (roll_deg is None) != (pitch_deg is None):
        raise ValueError(f"robot_pose_at: give both roll and pitch or neither (roll={roll_deg}, "
                         f"pitch={pitch_deg})")
    if roll_deg is not None and pitch_deg is not None:
        for name, a in (("roll_deg", roll_deg), ("pitch_deg", pitch_deg)):
            if not np.isfinite(a) or abs(a) > 10:
                raise ValueError(f"robot_pose_at: {name}={a} is not a plausible tilt (|a| <= 10°)")
        R = H[:3, :3] @ rot_y(math.radians(pitch_deg)) @ rot_x(math.radians(roll_deg))
        H = make_H(R, H[:3, 3], "abs_H_rob")
    return H


@dataclass
class MarkMeasurement:
    """A floor mark in ACS with every intermediate frame and a 2D covariance."""

    abs_P: np.ndarray  # (3,) mm
    rob_P: np.ndarray  # (3,) mm
    scn_xy: np.ndarray  # (2,) mm
    uv: np.ndarray  # (2,) px
    abs_H_rob: np.ndarray
    cov_xy_mm2: np.ndarray  # ACS x, y covariance, mm²
    #: each input's share of std_mm (mm, radial): tracker, pixel, calibration, tilt, heading (BLOCKS)
    std_parts_mm: dict[str, float] = field(default_factory=dict)  # + "mount", "bias" when given

    @property
    def std_xy_mm(self) -> np.ndarray:
        """Std of the ACS x and y coordinates, mm."""
        return np.sqrt(np.diag(self.cov_xy_mm2))

    @property
    def std_mm(self) -> float:
        """Radial std sqrt(σx² + σy²)."""
        return float(np.sqrt(np.trace(self.cov_xy_mm2)))

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return {"abs_P_mm": self.abs_P.tolist(), "rob_P_mm": self.rob_P.tolist(),
                "scn_xy_mm": self.scn_xy.tolist(),
                "uv_px": self.uv.tolist(), "abs_H_rob": self.abs_H_rob.tolist(),
                "cov_xy_mm2": self.cov_xy_mm2.tolist(), "std_xy_mm": self.std_xy_mm.tolist(),
                "std_mm": self.std_mm,
                "std_parts_mm": dict(self.std_parts_mm)}


def mark_to_abs(uv: Any, scs: Scs, rob_H_scn: np.ndarray, abs_H_rob: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Map one pixel position to (abs_P, rob_P, scn_xy) with the paper's two equations."""
    scn_xy = scs.image_to_scn(np.asarray(uv, dtype=float).reshape(1, 2))[0]
    rob_P = apply_H(rob_H_scn, np.array([scn_xy[0], scn_xy[1], 0.0]))
    return apply_H(abs_H_rob, rob_P), rob_P, scn_xy


def _pose(x: np.ndarray, abs_n: Any, tilt: bool) -> np.ndarray:
    """``abs_H_rob`` of one parameter vector: the approach pose, turned by x[16] (rad) about the floor normal
    through P_at (the heading's perturbation)."""
    H = robot_pose_at(x[0:3], x[3:6], abs_n, x[14] if tilt else None, x[15] if tilt else None)
    n = np.array([0.0, 0.0, 1.0]) if abs_n is None else as_points(abs_n, "abs_n", 1)[0]
    R = rotmat(n / np.linalg.norm(n) * x[16]) @ H[:3, :3]
    return make_H(R, H[:3, 3], "abs_H_rob")


def _input_cov(sigma_t_mm: float, sigma_px: float, cov_rob_H_scn: Any, sigma_tilt_deg: float,
               sigma_heading_rad: float) -> np.ndarray:
    """The 17 × 17 covariance of the parameter vector (:data:`BLOCKS`)."""
    S = np.zeros((17, 17))
    S[BLOCKS["tracker"], BLOCKS["tracker"]] = np.eye(6) * sigma_t_mm ** 2
    S[BLOCKS["pixel"], BLOCKS["pixel"]] = np.eye(2) * sigma_px ** 2
    if cov_rob_H_scn is not None:
        c = np.asarray(cov_rob_H_scn, dtype=float)
        if c.shape != (6, 6):
            raise ValueError(f"measure_mark: cov_rob_H_scn must be 6x6, got {c.shape}")
        S[BLOCKS["calibration"], BLOCKS["calibration"]] = c
    S[BLOCKS["tilt"], BLOCKS["tilt"]] = np.eye(2) * sigma_tilt_deg ** 2
    S[16, 16] = sigma_heading_rad ** 2
    return S


def measure_mark(uv: Any, scs: Scs, rob_H_scn: np.ndarray, abs_P_prev: Any, abs_P_at: Any, *,
                 abs_n: Any = None, roll_deg: float | None = None, pitch_deg: float | None = None,
                 sigma_t_mm: float = DEFAULT_SIGMA_T_MM, sigma_px: float = 0.05, sigma_tilt_deg: float = 0.0,
                 cov_rob_H_scn: np.ndarray | None = None, sigma_heading_rad: float = 0.0,
                 cov_mount_xy_mm2: Any = None, cov_bias_xy_mm2: Any = None) -> MarkMeasurement:
    """ACS position of a mark seen at pixel ``uv`` from a robot stop, with a first-order covariance.

    ``sigma_heading_rad``: the heading's 1σ beyond what the two tracker points show (the chord's
    :data:`CHORD_HEADING_SIGMA_RAD`, or a heading fit's own σ); 0 leaves it out.
    ``cov_mount_xy_mm2``: the ACS xy covariance the reflector mount's offset leaves (calibration/mount.py;
    a translation of both tracker points moves the mark by itself), added as the part ``mount``.
    ``cov_bias_xy_mm2``: the ACS xy covariance of the robot-frame bias the mark was corrected by
    (calibration/bias_check.py: a correction's own uncertainty), added as the part ``bias``.
    """
    uv = np.asarray(uv, dtype=float).reshape(-1)
    if uv.shape != (2,) or not np.all(np.isfinite(uv)):
        raise ValueError(f"measure_mark: uv must be 2 finite pixel coordinates, got {uv.tolist()}")
    check_H(rob_H_scn, "rob_H_scn")
    P_prev = as_points(abs_P_prev, "abs_P_prev", 1)[0]
    P_at = as_points(abs_P_at, "abs_P_at", 1)[0]
    for name, s in (("sigma_t_mm", sigma_t_mm), ("sigma_px", sigma_px), ("sigma_tilt_deg", sigma_tilt_deg),
                    ("sigma_heading_rad", sigma_heading_rad)):
        if not np.isfinite(s) or s < 0:
            raise ValueError(f"measure_mark: {name} must be >= 0, got {s}")
    tilt = roll_deg is not None

    def run(x: np.ndarray) -> np.ndarray:
        """ACS xy of the mark for one parameter vector (for the Jacobian)."""
        # x: P_prev (3), P_at (3), uv (2), rob_H_scn perturbation (6), roll, pitch (deg), heading (rad)
        return mark_to_abs(x[6:8], scs, perturb_pose(rob_H_scn, x[8:14]), _pose(x, abs_n, tilt))[0][:2]

    x0 = np.concatenate([P_prev, P_at, uv, np.zeros(6), [roll_deg or 0.0, pitch_deg or 0.0, 0.0]])
    abs_H_rob = robot_pose_at(P_prev, P_at, abs_n, roll_deg, pitch_deg)
    abs_P, rob_P, scn_xy = mark_to_abs(uv, scs, rob_H_scn, abs_H_rob)

    steps = np.array([_STEP_MM] * 6 + [_STEP_PX] * 2 + [_STEP_MM] * 3 + [_STEP_RAD] * 3 + [1e-4] * 2
                     + [_STEP_RAD])
    J = np.zeros((2, 17))
    for k in [k for k in range(17) if tilt or k not in (14, 15)]:
        dx = np.zeros(17)
        dx[k] = steps[k]
        J[:, k] = (run(x0 + dx) - run(x0 - dx)) / (2 * steps[k])
    S = _input_cov(sigma_t_mm, sigma_px, cov_rob_H_scn, sigma_tilt_deg, sigma_heading_rad)
    parts = {name: float(np.sqrt(np.trace(J[:, b] @ S[b, b] @ J[:, b].T))) for name, b in BLOCKS.items()}
    cov = J @ S @ J.T
    for name, given in (("mount", cov_mount_xy_mm2), ("bias", cov_bias_xy_mm2)):
        if given is not None:  # a part that is the same at every stop of one heading, added in ACS
            C = np.asarray(given, dtype=float)
            if C.shape != (2, 2) or not np.all(np.isfinite(C)):
                raise ValueError(f"measure_mark: cov_{name}_xy_mm2 must be a finite 2x2, got {C.tolist()}")
            cov, parts[name] = cov + C, float(np.sqrt(np.trace(C)))
    return MarkMeasurement(abs_P, rob_P, scn_xy, uv, abs_H_rob, cov, parts)


def measure_image(image: np.ndarray, scs: Scs, rob_H_scn: np.ndarray, abs_P_prev: Any, abs_P_at: Any, *,
                  kind: str = "dot", approx_uv: Any = None, mark_size_mm: float | None = None,
                  **kw: Any) -> MarkMeasurement:
    """Locate the mark in ``image`` (:func:`calibration.marks.locate_mark`) and measure it.

    ``mark_size_mm`` (dot radius or cross half-size) is turned into pixels with the
    SCS ground sample distance, so the locator need not guess it.
    """
    from calibration.marks import locate_mark

    size_px = None if mark_size_mm is None else float(mark_size_mm) / float(scs.gsd_mm)
    obs = locate_mark(image, kind=kind, approx_uv=approx_uv, size_px=size_px)
    return measure_mark(obs.uv, scs, rob_H_scn, abs_P_prev, abs_P_at, **kw)
