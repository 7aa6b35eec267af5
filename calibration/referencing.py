"""The paper's referencing method: camera pose in the robot frame from one plate visit.

Three poses are chained (paper, Methodology, "Referencing"):

* ``abs_H_scn`` — plate pose from the three tracker-measured nests
  (:func:`calibration.registration.fit_plate`, with ``scn_P_i = scn_H_ref · ref_P_smr,i``
  and ``scn_H_ref = scn_H_cam · cam_H_ref``);
* ``abs_H_rob`` — robot pose from the reflector at P0 and after a straight move at P1,
  with z the upward normal n of the plate surface: ``v⊥ = v − (v·n)n``, ``c = n × v⊥``,
  ``abs_R_rob = [v⊥ c n]``, origin P0;
* ``rob_H_scn = inv(abs_H_rob) · abs_H_scn`` and ``rob_H_cam = rob_H_scn · scn_H_cam``.

:func:`reference` takes the raw observations and returns every frame with residuals,
a Monte Carlo uncertainty and a quality verdict.

The plate normal: the paper takes ``(Pb − Pr) × (Pg − Pr)`` of the measured nests,
assuming the nest seats are parallel to the plate surface. The robot stands on the
surface, so its z axis is the *surface* normal; here it is PCS −z mapped into ACS by
the nest fit (``−abs_R_ref[:, 2]``, :func:`surface_normal`). With parallel seats the
two are the same; seats at unequal heights, stated in the plate file, no longer tilt
the robot frame (0.6 mm over 400 mm would be 0.1°). The nest-triangle normal still
orients the fit (which side is up).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calibration.camera_model import CameraModel
from calibration.errors import CalibrationError
from calibration.frames import apply_H, assert_rotations, check_H, inv_H, make_H, rotation_angle
from calibration.model_check import ModelCheck, camera_height, check_camera_model
from calibration.plate import Plate
from calibration.registration import as_points, fit_plate, kabsch_many, nest_array
from calibration.uncertainty import Chain, PoseUncertainty, footprint, monte_carlo, pnp_covariance


def plate_normal(abs_P_nests: Any, abs_P_rob0: Any) -> np.ndarray:
    """Unit normal ``(Pb − Pr) × (Pg − Pr)`` of the measured nest triangle (the paper's plate
    normal), flipped to point toward the robot reflector; orients the plate fit."""
    P = nest_array(abs_P_nests, "abs_P_nests")
    P0 = as_points(abs_P_rob0, "abs_P_rob0", 1)[0]
    Pr, Pg, Pb = P
    n = np.cross(Pb - Pr, Pg - Pr)
    norm = float(np.linalg.norm(n))
    if norm < 1e-6 * max(float(np.linalg.norm(Pb - Pr)), 1.0) ** 2:
        raise CalibrationError(f"plate normal undefined: nests are collinear ({P.tolist()})")
    n = n / norm
    if float(n @ (P0 - P.mean(axis=0))) < 0:
        n = -n
    return n


def surface_normal(abs_H_ref: np.ndarray) -> np.ndarray:
    """Upward unit normal of the plate surface in ACS: PCS z points into the plate."""
    return -check_H(abs_H_ref, "abs_H_ref")[:3, 2].copy()


def seat_tilt_deg(ref_P_smr: Any) -> float:
    """Angle between the nest-centre triangle and the plate surface (PCS xy), degrees."""
    P = nest_array(ref_P_smr, "ref_P_smr")
    n = np.cross(P[1] - P[0], P[2] - P[0])
    return float(np.degrees(np.arccos(min(1.0, abs(n[2]) / max(np.linalg.norm(n), 1e-300)))))


def robot_pose(abs_P_rob: Any, abs_v: Any, abs_n: Any, min_move_mm: float = 1.0) -> np.ndarray:
    """``abs_H_rob`` with origin ``abs_P_rob``, x = motion ``abs_v`` projected ⊥ n, z = n."""
    P = as_points(abs_P_rob, "abs_P_rob", 1)[0]
    v = as_points(abs_v, "abs_v", 1)[0]
    n = as_points(abs_n, "abs_n", 1)[0]
    n_len = float(np.linalg.norm(n))
    if abs(n_len - 1.0) > 1e-6:
        raise ValueError(f"robot_pose: abs_n must be a unit vector, has length {n_len}")
    v_perp = v - (v @ n) * n
    length = float(np.linalg.norm(v_perp))
    if length < min_move_mm:
        raise CalibrationError(f"robot heading undefined: the move between the two reflector positions is "
                               f"{length:.3f} mm in the plane (need >= {min_move_mm} mm)")
    v_perp = v_perp / length
    c = np.cross(n, v_perp)
    return make_H(np.column_stack([v_perp, c, n]), P, "abs_H_rob")


def robot_poses(P: np.ndarray, v: np.ndarray, n: np.ndarray, min_move_mm: float = 1.0) -> np.ndarray:
    """:func:`robot_pose` for stacks of origins, motions and unit normals (n, 3): (n, 4, 4), same checks."""
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(v))):
        raise ValueError("robot_pose: the reflector positions contain non-finite values")
    n_len = np.linalg.norm(n, axis=1)
    bad = np.abs(n_len - 1.0) > 1e-6
    if np.any(bad):
        raise ValueError(f"robot_pose: abs_n must be a unit vector, has length {n_len[bad][0]}")
    v_perp = v - np.sum(v * n, axis=1)[:, None] * n
    length = np.linalg.norm(v_perp, axis=1)
    if np.any(length < min_move_mm):
        raise CalibrationError(f"robot heading undefined: the move between the two reflector positions is "
                               f"{length.min():.3f} mm in the plane (need >= {min_move_mm} mm)")
    v_perp = v_perp / length[:, None]
    R = assert_rotations(np.stack([v_perp, np.cross(n, v_perp), n], axis=2), "abs_H_rob")
    H = np.broadcast_to(np.eye(4), (len(P), 4, 4)).copy()
    H[:, :3, :3], H[:, :3, 3] = R, P
    return H


def chain(ref_P_smr: np.ndarray, scn_H_cam: np.ndarray) -> Chain:
    """The bare referencing chain for Monte Carlo: (nests, P0, P1, cam_H_ref) -> (rob_H_cam, rob_H_scn).

    Takes one sample or a stack of them (leading axis), see :data:`calibration.uncertainty.Chain`.
    """
    def run(abs_P: np.ndarray, P0: np.ndarray, P1: np.ndarray, cam_H_ref: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
        """One pass of the chain on (possibly perturbed) inputs, all samples at once."""
        abs_P = np.asarray(abs_P, dtype=float)
        one = abs_P.ndim == 2
        if one:
            abs_P, cam_H_ref = abs_P[None], cam_H_ref[None]
            P0, P1 = np.reshape(P0, (1, 3)), np.reshape(P1, (1, 3))
        scn_H_ref = scn_H_cam @ np.asarray(cam_H_ref, dtype=float)
        scn_P = ref_P_smr @ np.swapaxes(scn_H_ref[:, :3, :3], 1, 2) + scn_H_ref[:, None, :3, 3]
        abs_H_scn = kabsch_many(scn_P, abs_P)
        abs_H_ref = abs_H_scn @ scn_H_ref
        assert_rotations(abs_H_ref[:, :3, :3], "abs_H_ref")
        abs_H_rob = robot_poses(np.asarray(P0, float), np.asarray(P1, float) - P0, -abs_H_ref[:, :3, 2])
        R_t = np.swapaxes(abs_H_rob[:, :3, :3], 1, 2)  # inv_H of each robot pose
        rob_H_abs = np.broadcast_to(np.eye(4), abs_H_rob.shape).copy()
        rob_H_abs[:, :3, :3], rob_H_abs[:, :3, 3] = R_t, -np.einsum("nij,nj->ni", R_t, abs_H_rob[:, :3, 3])
        rob_H_scn = rob_H_abs @ abs_H_scn
        rob_H_cam = rob_H_scn @ scn_H_cam
        return (rob_H_cam[0], rob_H_scn[0]) if one else (rob_H_cam, rob_H_scn)
    return run


@dataclass
class Gates:
    """Quality limits for a referencing; 'fail' limits make the verdict fail, 'warn' ones warn."""

    warn_nest_rms_sigma: float = 2.0  # nest RMS in units of the expected σ (3σ raises)
    min_corners: int = 30
    warn_corners: int = 100
    min_ambiguity: float = 5.0  # IPPE best/second reprojection ratio (docs/accuracy.md, "Image side")
    max_rms_px: float = 0.5
    min_move_mm: float = 50.0  # P0 → P1 baseline: heading σ = √2·σ_t/d
    warn_move_mm: float = 150.0
    max_climb_deg: float = 2.0  # P0 → P1 should run along the plate, not up or down
    warn_seat_tilt_deg: float = 0.5  # nest seats vs plate surface in the plate file: a typo?


@dataclass
class ReferencingResult:
    """Everything one referencing produced, with its quality verdict."""

    rob_H_cam: np.ndarray
    rob_H_scn: np.ndarray
    abs_H_scn: np.ndarray
    scn_H_cam: np.ndarray
    cam_H_ref: np.ndarray
    abs_H_rob: np.ndarray
    abs_n: np.ndarray
    nest_residuals_mm: dict[str, list[float]]
    nest_rms_mm: float
    label_check: str
    n_corners: int | None
    rms_px: float | None
    ambiguity_ratio: float | None
    uncertainty: PoseUncertainty | None
    verdict: str = "ok"  # ok / warn / fail
    messages: list[str] = field(default_factory=list)
    model_check: ModelCheck | None = None  # camera-model checks on the image's corners (image runs only)

    @property
    def footprint_rob(self) -> np.ndarray:
        """Camera footprint (optical axis on the support plane) in RCS, mm."""
        return footprint(self.rob_H_cam, self.rob_H_scn)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form: matrices as nested lists, figures in mm and degrees."""
        out: dict[str, Any] = {}
        for k in ("rob_H_cam", "rob_H_scn", "abs_H_scn", "scn_H_cam", "cam_H_ref", "abs_H_rob"):
            out[k] = getattr(self, k).tolist()
        out.update(abs_n=self.abs_n.tolist(), nest_residuals_mm=self.nest_residuals_mm,
                   nest_rms_mm=self.nest_rms_mm, label_check=self.label_check, n_corners=self.n_corners,
                   rms_px=self.rms_px, ambiguity_ratio=self.ambiguity_ratio,
                   footprint_rob_mm=self.footprint_rob.tolist(),
                   uncertainty=None if self.uncertainty is None else self.uncertainty.to_dict(),
                   verdict=self.verdict, messages=list(self.messages),
                   model_check=None if self.model_check is None else self.model_check.to_dict())
        return out


def _verdict(gates: Gates, fit_rms: float, sigma: float, move_mm: float, climb_deg: float, seat_tilt: float,
             n_corners: int | None, rms_px: float | None, ambiguity: float | None) -> tuple[str, list[str]]:
    """Apply the gates; return the verdict and one plain message per finding."""
    fails: list[str] = []
    warns: list[str] = []
    if seat_tilt > gates.warn_seat_tilt_deg:
        warns.append(f"the plate file's nest seats are tilted {seat_tilt:.2f}° from the plate surface "
                     f"(> {gates.warn_seat_tilt_deg:g}°): check the seat z values")
    if fit_rms > gates.warn_nest_rms_sigma * sigma:
        warns.append(f"nest RMS {fit_rms * 1000:.1f} µm > {gates.warn_nest_rms_sigma:g}·σ "
                     f"({gates.warn_nest_rms_sigma * sigma * 1000:.1f} µm)")
    if move_mm < gates.min_move_mm:
        fails.append(f"P0→P1 move {move_mm:.1f} mm < {gates.min_move_mm:g} mm: heading too uncertain")
    elif move_mm < gates.warn_move_mm:
        warns.append(f"P0→P1 move {move_mm:.1f} mm < {gates.warn_move_mm:g} mm: heading error grows as 1/d")
    if climb_deg > gates.max_climb_deg:
        warns.append(f"P0→P1 leaves the plate plane by {climb_deg:.2f}° (> {gates.max_climb_deg:g}°)")
    if n_corners is not None:
        if n_corners < gates.min_corners:
            fails.append(f"only {n_corners} target corners (need >= {gates.min_corners})")
        elif n_corners < gates.warn_corners:
            warns.append(f"{n_corners} target corners (< {gates.warn_corners})")
    if ambiguity is not None and ambiguity < gates.min_ambiguity:
        fails.append(f"PnP ambiguity ratio {ambiguity:.2f} < {gates.min_ambiguity:g}: mirror pose possible")
    if rms_px is not None and rms_px > gates.max_rms_px:
        fails.append(f"corner reprojection RMS {rms_px:.3f} px > {gates.max_rms_px:g} px")
    if fails:
        return "fail", fails + warns
    return ("warn" if warns else "ok"), warns


def reference_pose(cam_H_ref: np.ndarray, scn_H_cam: np.ndarray, ref_P_smr: Any, abs_P_nests: Any,
                   abs_P_rob0: Any, abs_P_rob1: Any, sigma_t_mm: float = 0.010, sigma_plate_mm: float = 0.005,
                   cov_cam_H_ref: np.ndarray | None = None, n_corners: int | None = None,
                   rms_px: float | None = None, ambiguity_ratio: float | None = None,
                   gates: Gates | None = None, mc_samples: int = 200, seed: int = 0) -> ReferencingResult:
    """Referencing from an already estimated ``cam_H_ref`` and SCS (no image work).

    ``sigma_plate_mm`` is the per-coordinate uncertainty of the nest positions in the
    plate definition; with ``sigma_t_mm`` it sets the nest-fit limit (3σ raises).
    ``mc_samples = 0`` skips the Monte Carlo uncertainty.
    """
    gates = gates or Gates()
    check_H(cam_H_ref, "cam_H_ref")
    check_H(scn_H_cam, "scn_H_cam")
    ref_P = nest_array(ref_P_smr, "ref_P_smr")
    abs_P = nest_array(abs_P_nests, "abs_P_nests")
    P0 = as_points(abs_P_rob0, "abs_P_rob0", 1)[0]
    P1 = as_points(abs_P_rob1, "abs_P_rob1", 1)[0]
    for name, s in (("sigma_t_mm", sigma_t_mm), ("sigma_plate_mm", sigma_plate_mm)):
        if not np.isfinite(s) or s < 0:
            raise ValueError(f"reference: {name} must be >= 0, got {s}")
    sigma = float(np.hypot(sigma_t_mm, sigma_plate_mm)) or 1e-6

    scn_H_ref = scn_H_cam @ cam_H_ref
    # the nest triangle says which side is up; the fitted plate gives the surface normal
    fit = fit_plate(apply_H(scn_H_ref, ref_P), abs_P, sigma, abs_up=plate_normal(abs_P, P0))
    abs_H_scn = fit.abs_H_scn
    abs_n = surface_normal(abs_H_scn @ scn_H_ref)
    abs_H_rob = robot_pose(P0, P1 - P0, abs_n)
    rob_H_scn = inv_H(abs_H_rob) @ abs_H_scn
    rob_H_cam = rob_H_scn @ scn_H_cam
    for name, H in (("abs_H_rob", abs_H_rob), ("rob_H_scn", rob_H_scn), ("rob_H_cam", rob_H_cam)):
        check_H(H, name)

    v = P1 - P0
    move = float(np.linalg.norm(v - (v @ abs_n) * abs_n))
    climb = float(np.degrees(np.arcsin(min(1.0, abs(v @ abs_n) / max(np.linalg.norm(v), 1e-12)))))
    verdict, messages = _verdict(gates, fit.rms_mm, sigma, move, climb, seat_tilt_deg(ref_P), n_corners,
                                 rms_px, ambiguity_ratio)
    if fit.label_check != "unique":
        messages.append(f"nest labels: {fit.label_check}")
    unc = None
    if mc_samples:
        unc = monte_carlo(chain(ref_P, scn_H_cam), abs_P, P0, P1, cam_H_ref, sigma_t_mm,
                          cov_cam_H_ref, mc_samples, seed)
    return ReferencingResult(rob_H_cam, rob_H_scn, abs_H_scn, scn_H_cam, np.asarray(cam_H_ref, float),
                             abs_H_rob, abs_n, fit.residuals_mm, fit.rms_mm, fit.label_check, n_corners,
                             rms_px, ambiguity_ratio, unc, verdict, messages)


def board_corners_ref(plate: Plate, ids: Any) -> np.ndarray:
    """PCS coordinates of ChArUco chessboard corners by id (OpenCV board frame, z = 0)."""
    ids = np.asarray(ids, dtype=int).reshape(-1)
    per_row = plate.board_cols - 1
    if ids.size and (ids.min() < 0 or ids.max() >= per_row * (plate.board_rows - 1)):
        raise ValueError(f"corner ids out of range for a {plate.board_cols}x{plate.board_rows} board: "
                         f"{ids.min()}..{ids.max()}")
    col, row = ids % per_row + 1, ids // per_row + 1
    return np.column_stack([col * plate.square_mm, row * plate.square_mm, np.zeros(len(ids))])


def reference(model: CameraModel, plate: Plate, abs_P_nests: Any, abs_P_rob0: Any, abs_P_rob1: Any, *,
              image: np.ndarray | None = None, cam_ref: Any = None, sigma_t_mm: float = 0.010,
              sigma_plate_mm: float = 0.005, sigma_px: float | None = None, gates: Gates | None = None,
              mc_samples: int = 200, seed: int = 0, model_dict: dict[str, Any] | None = None
              ) -> ReferencingResult:
    """Referencing from raw observations: an image (or a ``CamRefPose`` / 4x4 ``cam_H_ref``).

    The image is turned into ``cam_H_ref`` by :func:`calibration.target.estimate_cam_H_ref`
    and the SCS by :func:`calibration.scs.make_scs`. The PnP covariance for the
    uncertainty uses ``sigma_px`` (default: the corner RMS of the fit). With corners
    (an image or a ``CamRefPose``) the camera model is checked against them
    (:mod:`calibration.model_check`; ``model_dict``, the camera_model.json content, adds
    its calibration report) and its findings join the verdict.
    """
    from calibration.scs import make_scs
    from calibration.target import estimate_cam_H_ref

    if (image is None) == (cam_ref is None):
        raise ValueError("reference: give exactly one of image= or cam_ref=")
    if plate.nests_sigma_mm:  # a surveyed plate states its seats' 1σ: the nest fit cannot beat it
        seats_rms = float(np.sqrt(np.mean(np.square(list(plate.nests_sigma_mm.values())))))
        sigma_plate_mm = max(sigma_plate_mm, seats_rms)
    if image is not None:
        cam_ref = estimate_cam_H_ref(image, model, plate)
    n_corners = rms_px = ambiguity = None
    cov = None
    if not hasattr(cam_ref, "cam_H_ref"):
        cam_H_ref = check_H(np.asarray(cam_ref, dtype=float), "cam_ref")
    else:
        cam_H_ref = np.asarray(cam_ref.cam_H_ref, dtype=float)
        n_corners, rms_px = int(cam_ref.n_corners), float(cam_ref.rms_px)
        ambiguity = float(cam_ref.ambiguity_ratio)
        s_px = sigma_px if sigma_px is not None else max(rms_px, 0.02)
        cov = pnp_covariance(model.K, model.dist, cam_H_ref, board_corners_ref(plate, cam_ref.ids), s_px)
    scs = make_scs(model, cam_H_ref)
    res = reference_pose(cam_H_ref, scs.scn_H_cam, plate.ref_P_smr(), abs_P_nests, abs_P_rob0, abs_P_rob1,
                         sigma_t_mm, sigma_plate_mm, cov, n_corners, rms_px, ambiguity, gates,
                         mc_samples, seed)
    if n_corners is not None:
        mc = check_camera_model(model, board_corners_ref(plate, cam_ref.ids), cam_ref.uv, cam_H_ref,
                                model_dict)
        cov_f = camera_height(mc, float(abs(cam_H_ref[:3, 2] @ cam_H_ref[:3, 3])), res.rob_H_cam)
        if res.uncertainty is not None:  # the stated t_z covers what the model's f leaves open
            res.uncertainty.cov_rob_H_cam[:3, :3] += cov_f
        res.model_check = mc
        res.messages.extend(mc.messages)
        order = ("ok", "warn", "fail")
        res.verdict = order[max(order.index(res.verdict), order.index(mc.verdict))]
    return res


def rob_H_cam_error(rob_H_cam: np.ndarray, rob_H_cam_true: np.ndarray) -> dict[str, float]:
    """Translation (xy, z, mm) and rotation (deg) error of an estimate against truth."""
    d = rob_H_cam[:3, 3] - rob_H_cam_true[:3, 3]
    return {"t_xy_mm": float(np.hypot(d[0], d[1])), "t_z_mm": float(abs(d[2])),
            "rot_deg": float(np.degrees(rotation_angle(rob_H_cam[:3, :3].T @ rob_H_cam_true[:3, :3])))}

