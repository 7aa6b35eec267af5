"""Camera-model checks for the referencing verdict: can this image vouch for the model?

A nadir view of a flat target at one distance sees only z/f: a camera model whose
focal length is wrong but *self-consistent* (distortion fitted for the wrong f, as a
near-nadir intrinsic calibration produces) gives the same pixels, a PnP distance
scaled by the same factor and an unchanged reprojection RMS. No check on one such
image, nor the 0°/180° height comparison, nor a ground-sample-distance check against
the tracker-measured drive, can see it (docs/architecture.md, "Referencing verdict: the
camera-model check").
What can be checked:

* **focal refit** — the pose and a common scale of fx, fy refitted to the corners,
  distortion kept. A model whose f does not match its own distortion (f changed, or
  distortion calibrated at another f) has radial residuals that a different f
  explains; the refit gives the focal error the image supports, its σ from the
  corner noise, and the camera height that f implies. Gated on significance *and*
  on the implied height change against the t_z budget.
* **radial pattern** — the radial residual component fitted by odd powers of the
  radius, its F ratio against the tangential residuals (same noise, no radial
  signal) and its peak size on the plate; catches distortion errors that an f
  change does not explain.
* **calibration uncertainty** — the model's own focal-length σ when the
  camera_model.json carries it (``std``, written by the intrinsics procedure); the only
  check that sees a self-consistent wrong f, because only the calibration views could.

Every finding names the camera model and says what to do.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from calibration.camera_model import CameraModel

#: 1σ of the focal length assumed when the model states none: the ±5 % focal-length tolerance typical of
#: machine-vision lens data sheets (unverified for a particular lens), taken as 1σ
UNSTATED_F_REL = 0.05
#: what to do about a bad camera model, appended to every finding
ADVICE = ("re-run `ritactl intrinsics` with the tilted board views of its recipe (docs/operations.md) and "
          "install the new model")


@dataclass
class ModelCheckGates:
    """Limits of the camera-model checks (derivations in docs/architecture.md)."""

    min_significance: float = 5.0  # |Δf|/σ_f of the refit; two-sided Gaussian false alarm 6e-7
    # implied camera-height change: 1/3 of the nominal t_z limit (docs/accuracy.md)
    warn_height_mm: float = 0.015
    fail_height_mm: float = 0.045  # the nominal t_z limit (docs/accuracy.md, "Acceptance thresholds")
    radial_min_f_ratio: float = 10.0  # F(3, N) above 10: chance ~1e-6 under corner noise alone
    # peak radial pattern on the plate: the noise-free footprint limit (docs/accuracy.md)
    radial_warn_plate_mm: float = 0.005
    model_k_sigma: float = 3.0  # the model's own 3σ focal error, as a height error, against the t_z limit


@dataclass
class FocalRefit:
    """Focal scale the corners support (model f × scale), with σ and the implied height change."""

    scale: float
    sigma: float
    height_mm: float  # camera to plate distance with the model's f
    height_change_mm: float  # refitted minus given
    rms_px: float  # reprojection RMS after the refit

    # height change at the significance gate: what this image can see
    resolvable_height_mm: float = float("nan")

    @property
    def significance(self) -> float:
        return abs(self.scale - 1.0) / max(self.sigma, 1e-15)


@dataclass
class RadialPattern:
    """Radial residuals fitted by a·ρ + b·ρ³ + c·ρ⁵ (ρ = pixel radius / f)."""

    f_ratio: float
    peak_px: float
    peak_plate_mm: float
    sigma_px: float  # per-coordinate noise from the tangential residuals
    model_peak_px: float = 0.0  # the peak the model's own stated 1σ can leave (model_spread)


@dataclass
class ModelCheck:
    """Findings of every camera-model check; ``verdict`` is ok / warn / fail."""

    focal: FocalRefit | None = None
    radial: RadialPattern | None = None
    model_sigma_f: float | None = None  # relative 1σ of f from the camera_model.json's std
    verdict: str = "ok"
    messages: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form; non-finite figures are null."""
        out: dict[str, Any] = {"verdict": self.verdict, "messages": list(self.messages),
                               "model_sigma_f_rel": _num(self.model_sigma_f)}
        if self.focal is not None:
            f = self.focal
            out["focal_refit"] = {k: _num(v) for k, v in (
                ("scale", f.scale), ("sigma", f.sigma), ("significance", f.significance),
                ("height_mm", f.height_mm),
                ("height_change_mm", f.height_change_mm), ("rms_px", f.rms_px),
                ("resolvable_height_mm", f.resolvable_height_mm))}
        if self.radial is not None:
            r = self.radial
            out["radial_pattern"] = {k: _num(v) for k, v in (("f_ratio", r.f_ratio), ("peak_px", r.peak_px),
                                                               ("peak_plate_mm", r.peak_plate_mm),
                                                               ("sigma_px", r.sigma_px),
                                                               ("model_peak_px", r.model_peak_px))}
        return out


def _num(x: float | None) -> float | None:
    """A JSON-safe number: non-finite values (a refit that could not run) become null."""
    return float(x) if x is not None and np.isfinite(x) else None


def _plane_distance(cam_H_ref: np.ndarray) -> float:
    """Distance from the camera centre to the target plane (PCS z = 0), mm."""
    return float(abs(cam_H_ref[:3, 2] @ cam_H_ref[:3, 3]))


def _project(obj: np.ndarray, x: np.ndarray, model: CameraModel) -> tuple[np.ndarray, np.ndarray]:
    """Projections and Jacobian w.r.t. (rvec, tvec, log focal scale) at parameters ``x``."""
    K = model.K.copy()
    K[:2, :2] *= np.exp(x[6])
    uv, J = cv2.projectPoints(obj, x[:3], x[3:6], K, model.dist)
    Jf = J[:, 6:7] * K[0, 0] + J[:, 7:8] * K[1, 1]  # d/d(log s) through fx and fy together
    return uv.reshape(-1), np.hstack([J[:, :6], Jf])


def focal_refit(model: CameraModel, obj: np.ndarray, uv: np.ndarray, cam_H_ref: np.ndarray,
                iterations: int = 20) -> FocalRefit:
    """Gauss–Newton refit of the pose and a common focal scale, distortion and centre fixed.

    σ of the scale comes from the residual RMS and the normal matrix (Gaussian,
    independent corners); started at the PnP pose and scale 1. A refit that runs off
    (non-finite, or a focal scale beyond e^±0.5) returns scale 1 with σ = inf: the
    check then only notes that it could not vouch for the model.
    """
    obj = np.asarray(obj, float).reshape(-1, 3)
    target = np.asarray(uv, float).reshape(-1)
    rvec, _ = cv2.Rodrigues(cam_H_ref[:3, :3])
    x = np.concatenate([rvec.reshape(3), cam_H_ref[:3, 3], [0.0]])
    h0 = _plane_distance(cam_H_ref)
    for _ in range(iterations):
        proj, J = _project(obj, x, model)
        step = np.linalg.lstsq(J, target - proj, rcond=None)[0]
        if not np.all(np.isfinite(step)) or abs(x[6] + step[6]) > 0.5:
            # no focal within a factor 1.6 explains the corners: no verdict from this check
            return FocalRefit(1.0, float("inf"), h0, 0.0, float("nan"))
        x = x + step
        if np.abs(step).max() < 1e-12:
            break
    proj, J = _project(obj, x, model)
    r = target - proj
    dof = max(len(r) - 7, 1)
    s2 = float(r @ r) / dof
    cov = s2 * np.linalg.pinv(J.T @ J)
    R, _ = cv2.Rodrigues(x[:3])
    H = np.eye(4)
    H[:3, :3], H[:3, 3] = R, x[3:6]
    return FocalRefit(float(np.exp(x[6])), float(np.exp(x[6]) * np.sqrt(cov[6, 6])), h0,
                      _plane_distance(H) - h0, float(np.sqrt(2 * s2)))


def radial_pattern(model: CameraModel, uv: np.ndarray, residuals: np.ndarray, height_mm: float
                   ) -> RadialPattern:
    """Fit the radial residual component (about the principal point) by odd powers of ρ.

    The tangential component carries the same corner noise but no radial-distortion
    signal, so its mean square is the noise variance for the F ratio.
    """
    uv = np.asarray(uv, float).reshape(-1, 2)
    res = np.asarray(residuals, float).reshape(-1, 2)
    d = uv - model.K[:2, 2]
    rad = np.linalg.norm(d, axis=1)
    ok = rad > 1e-6
    u = d[ok] / rad[ok, None]
    e_r = np.sum(res[ok] * u, axis=1)
    e_t = u[:, 0] * res[ok, 1] - u[:, 1] * res[ok, 0]
    rho = rad[ok] / model.f
    B = np.column_stack([rho, rho ** 3, rho ** 5])
    a = np.linalg.lstsq(B, e_r, rcond=None)[0]
    fit = B @ a
    s2 = float(np.mean(e_t ** 2))
    f_ratio = float(fit @ fit) / B.shape[1] / max(s2, 1e-30)
    grid = np.linspace(0.0, float(rho.max()), 200)
    peak = float(np.abs(np.column_stack([grid, grid ** 3, grid ** 5]) @ a).max())
    return RadialPattern(f_ratio, peak, peak * height_mm / model.f, float(np.sqrt(s2)))


def model_sigma_f(model_dict: dict[str, Any] | None) -> float | None:
    """Relative 1σ of the focal length from the ``std`` a camera_model.json may carry.

    ``std.fx`` / ``std.fy`` are in pixels, as the intrinsics procedure writes them
    (docs/datasets.md, "Camera model"); the larger relative one is returned. A file
    without them (older files, a model typed in by hand) gives None: no finding.
    """
    std = (model_dict or {}).get("std")
    if model_dict is None or not isinstance(std, dict):
        return None
    K = np.asarray(model_dict.get("K", np.eye(3)), float)
    rel = []
    for key, f in (("fx", K[0, 0]), ("fy", K[1, 1])):
        v = std.get(key)
        if isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) and v >= 0 and f > 0:
            rel.append(float(v) / float(f))
    return max(rel) if rel else None


def _findings(check: ModelCheck, gates: ModelCheckGates) -> None:
    """Apply the gates to the measured statistics; set the verdict and the messages."""
    fails: list[str] = []
    warns: list[str] = []
    f = check.focal
    if f is not None and f.significance >= gates.min_significance:
        text = (f"camera model: with its distortion, the target corners fit a focal length "
                f"{100 * (f.scale - 1):+.2f} % ± {100 * f.sigma:.2f} % from the model's, which moves the "
                f"camera height by {1000 * f.height_change_mm:+.0f} µm")
        if abs(f.height_change_mm) >= gates.fail_height_mm:
            fails.append(f"{text} (limit {1000 * gates.fail_height_mm:.0f} µm); {ADVICE}")
        elif abs(f.height_change_mm) >= gates.warn_height_mm:
            warns.append(f"{text} (> {1000 * gates.warn_height_mm:.0f} µm); {ADVICE}")
    r = check.radial
    if (r is not None and r.f_ratio >= gates.radial_min_f_ratio
            and r.peak_plate_mm >= gates.radial_warn_plate_mm
            and r.peak_px > gates.model_k_sigma * r.model_peak_px):  # beyond what the model's 3σ allows
        warns.append(f"camera model: radial pattern in the corner residuals, up to {r.peak_px:.3f} px "
                     f"({1000 * r.peak_plate_mm:.1f} µm on the plate, F = {r.f_ratio:.0f}): the distortion "
                     f"does not fit this camera; {ADVICE}")
    if check.model_sigma_f is not None and f is not None:
        dz = gates.model_k_sigma * check.model_sigma_f * f.height_mm
        if dz >= gates.fail_height_mm:
            warns.append(f"camera model: its calibration gives the focal length to ±"
                         f"{100 * check.model_sigma_f:.2f} % (1σ), i.e. camera height ±{1000 * dz:.0f} µm at "
                         f"{gates.model_k_sigma:g}σ (limit {1000 * gates.fail_height_mm:.0f} µm); {ADVICE}")
    notes: list[str] = []
    if f is not None and not np.isfinite(f.sigma):
        notes.append("camera model (note): no focal length near the model's fits the target corners, so this "
                     "image cannot vouch for the model")
    elif f is not None and f.resolvable_height_mm >= gates.fail_height_mm:
        # too few or too noisy corners to vouch for the model: say so, but it is no finding against it
        notes.append(f"camera model (note): this image checks the focal length only to ±"
                     f"{100 * gates.min_significance * f.sigma:.2f} % ({gates.min_significance:g}σ), i.e. a "
                     f"camera height error below {1000 * f.resolvable_height_mm:.0f} µm would go unseen")
    check.messages = fails + warns + notes
    check.verdict = "fail" if fails else ("warn" if warns else "ok")


def camera_height(check: ModelCheck, height_mm: float, rob_H_cam: np.ndarray) -> np.ndarray:
    """What the model's focal length leaves of the camera's position: a 3×3 covariance (rob frame, mm²).

    f and a distortion fitted for it trade off against the distance to a flat target (the
    degeneracy above), so a relative focal error ε moves the camera by ε·height along its
    optical axis. That term joins rob_H_cam's stated uncertainty, with the model's own σ of f,
    or, for a model that states none, the focal tolerance of a lens nobody measured
    (``UNSTATED_F_REL``), and a note says the camera height is not resolved by this model.
    The marks, measured through the same SCS, are not affected.
    """
    axis = np.asarray(rob_H_cam, float)[:3, 2]
    sigma_f = check.model_sigma_f
    if sigma_f is None:
        sigma_f = UNSTATED_F_REL
        check.messages.append(
            f"camera model (note): camera height not resolved by this model: "
            f"±{sigma_f * height_mm * 1000:.0f} µm (1σ, in rob_H_cam's stated uncertainty) — "
            f"camera_model.json states no focal-length σ (std.fx, std.fy), so ±{100 * sigma_f:g} % of f is "
            f"assumed, and a view of the flat plate cannot tell a focal length wrong with its distortion "
            f"from the distance (floor marks are not affected); a model from `ritactl intrinsics` states "
            f"its σ")
    return (sigma_f * height_mm) ** 2 * np.outer(axis, axis)

#: where each uncertain parameter of camera_model.json's ``std`` sits: (row, col) of K, or a dist index
_STD_SLOTS: dict[str, tuple[str, tuple[int, int] | int]] = {"cx": ("K", (0, 2)), "cy": ("K", (1, 2)),
                                                           "k1": ("dist", 0), "k2": ("dist", 1),
                                                           "p1": ("dist", 2),
              "p2": ("dist", 3), "k3": ("dist", 4)}


def _perturbed(model: CameraModel, name: str, delta: float) -> CameraModel:
    K, dist = model.K.copy(), np.resize(model.dist, 5).astype(float)
    where, idx = _STD_SLOTS[name]
    if where == "K":
        K[idx] += delta
    else:
        dist[idx] += delta
    return CameraModel(K, dist, model.size)


def model_spread(model: CameraModel, obj: np.ndarray, uv: np.ndarray, cam_H_ref: np.ndarray,
                 model_dict: dict[str, Any] | None) -> tuple[float, float]:
    """What the model's own stated 1σ (centre, distortion) does to this view's checks.

    A fitted model is uncertain: a distortion 1–2σ off makes the focal refit move and leaves a
    radial pattern, although the model is as good as its calibration says. Each parameter with
    a σ in ``std`` is moved by 1σ; the focal scale change and the radial pattern peak (px) it
    causes are added in quadrature (correlations ignored: conservative for a jackknife σ).
    Returns (σ of the focal scale, radial peak px); (0, 0) without ``std``.
    """
    std = (model_dict or {}).get("std")
    if not isinstance(std, dict):
        return 0.0, 0.0
    base = focal_refit(model, obj, uv, cam_H_ref).scale
    rvec, _ = cv2.Rodrigues(cam_H_ref[:3, :3])
    proj0, _ = cv2.projectPoints(obj, rvec, cam_H_ref[:3, 3], model.K, model.dist)
    ds2 = dr2 = 0.0
    for name in _STD_SLOTS:
        sigma = std.get(name)
        if not isinstance(sigma, (int, float)) or not np.isfinite(sigma) or sigma <= 0:
            continue
        moved = _perturbed(model, name, float(sigma))
        ds2 += (focal_refit(moved, obj, uv, cam_H_ref).scale - base) ** 2
        proj, _ = cv2.projectPoints(obj, rvec, cam_H_ref[:3, 3], moved.K, moved.dist)
        dr2 += radial_pattern(model, uv, (proj - proj0).reshape(-1, 2), 1.0).peak_px ** 2
    return float(np.sqrt(ds2)), float(np.sqrt(dr2))


def check_camera_model(model: CameraModel, obj: np.ndarray, uv: np.ndarray, cam_H_ref: np.ndarray,
                       model_dict: dict[str, Any] | None = None, gates: ModelCheckGates | None = None
                       ) -> ModelCheck:
    """Run every camera-model check on one referencing image's corners.

    ``obj`` are the corners' PCS points (N, 3), ``uv`` their detected pixels (N, 2),
    ``cam_H_ref`` the PnP pose with ``model``; ``model_dict`` the camera_model.json
    content (for its ``std``, optional).
    """
    gates = gates or ModelCheckGates()
    obj = np.asarray(obj, float).reshape(-1, 3)
    uv = np.asarray(uv, float).reshape(-1, 2)
    if len(obj) != len(uv) or len(obj) < 8:
        raise ValueError(f"check_camera_model: need >= 8 matching corners, got {len(obj)} points and "
                         f"{len(uv)} pixels")
    rvec, _ = cv2.Rodrigues(np.asarray(cam_H_ref, float)[:3, :3])
    proj, _ = cv2.projectPoints(obj, rvec, np.asarray(cam_H_ref, float)[:3, 3], model.K, model.dist)
    check = ModelCheck()
    check.focal = focal_refit(model, obj, uv, cam_H_ref)
    spread_f, spread_r = model_spread(model, obj, uv, np.asarray(cam_H_ref, float), model_dict)
    check.focal.sigma = float(np.hypot(check.focal.sigma, spread_f))  # the image's and the model's own σ
    check.focal.resolvable_height_mm = gates.min_significance * check.focal.sigma * check.focal.height_mm
    check.radial = radial_pattern(model, uv, proj.reshape(-1, 2) - uv, check.focal.height_mm)
    check.radial.model_peak_px = spread_r
    check.model_sigma_f = model_sigma_f(model_dict)
    _findings(check, gates)
    return check
