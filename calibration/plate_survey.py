"""Plate survey: nest seats in PCS from whole-plate photographs of an uncalibrated camera.

Pipeline (docs/operations.md, "Plate survey"):

1. patch corners in every photograph (:mod:`calibration.survey_detect`); the patches'
   PCS coordinates come from the plate definition, so every photograph is a view of one
   planar target: ``cv2.calibrateCamera`` gives the intrinsics and the poses;
2. nest rings: edge points undistorted to the normalised image plane, one ellipse per
   edge (outer, inner) fitted there (a circle's image under a pinhole is an exact
   conic); their centres are not the image of the ring centre (perspective bias, large
   against the seats' goal: docs/accuracy.md, "Reference figures"): the bias is computed
   from the current pose and seat estimate and removed; the mean of the two corrected
   centres is the ring's observation;
3. a Gauss–Newton bundle (:mod:`calibration.survey_bundle`): camera from the corners,
   seats from the rings; each seat's covariance holds the ring residuals' σ and the
   camera's covariance propagated to it. A ring observation far off the others'
   solution (another object of that colour) is dropped, reported, and the bundle rerun.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable

import cv2
import numpy as np

from calibration.camera_model import CameraModel
from calibration.errors import CalibrationError
from calibration.plate import NEST_NAMES, Plate
from calibration.survey import intersect_rays
from calibration.survey_bundle import Bundle, adjust
from calibration.survey_detect import RingEdges, check_rgb, detect_patch_corners, find_rings

MIN_CORNERS = 12  # per usable photograph
MIN_VIEWS = 3
#: a ring observation this far (px) from the bundle's solution is not the ring (σ_ring is ~0.02 px)
RING_OUTLIER_PX = 0.5
#: ``progress(fraction done, step)``: how far the survey is, for a caller that shows it
Progress = Callable[[float, str], None]


@dataclass
class View:
    """One photograph's detections."""

    name: str
    ref_P: np.ndarray  # (N, 3) patch corners in PCS
    uv: np.ndarray  # (N, 2)
    rings: dict[str, RingEdges]
    missing: dict[str, str]  # colour -> why not found


def detect_views(images: dict[str, np.ndarray], plate: Plate,
                 progress: Progress | None = None) -> tuple[list[View], dict[str, str]]:
    """Detections of every photograph with enough corners, and {name: why skipped} for the others."""
    patches = plate.survey_patches()
    if not patches:
        raise ValueError(f"plate {plate.plate_id!r} has no survey patches: the survey needs a plate "
                         f"definition with `patches` (docs/datasets.md)")
    views, skipped = [], {}
    for i, (name, image) in enumerate(images.items()):
        if progress:
            progress(i / len(images), f"patch corners and rings in {name} ({i + 1}/{len(images)})")
        rgb = check_rgb(image, name)
        grey = cv2.cvtColor(np.clip(rgb, 0, 255).astype(np.uint8), cv2.COLOR_RGB2GRAY)
        ref_P, uv, _ = detect_patch_corners(grey, patches, plate.aruco_dict)
        if len(uv) < MIN_CORNERS:
            skipped[name] = f"only {len(uv)} patch corners (need >= {MIN_CORNERS})"
            continue
        rings, missing = find_rings(rgb, name)
        views.append(View(name, ref_P, uv, rings, missing))
    return views, skipped


def calibrate(views: list[View], size: tuple[int, int]) -> tuple[CameraModel, list[np.ndarray], float]:
    """Intrinsics and per-view (rvec, tvec) from the patch corners: (model, [6-vectors], corner RMS px)."""
    obj = [v.ref_P.astype(np.float32) for v in views]
    img = [v.uv.astype(np.float32) for v in views]
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
    # k3 starts at 0: free from the start, it trades against k2 into values far outside any lens
    # (k2 1.5, k3 −26 on 6 views); the bundle then keeps it only when the data support it
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj, img, size, None, None, flags=cv2.CALIB_FIX_K3,
                                                     criteria=crit)
    poses = [np.concatenate([r.reshape(3), t.reshape(3)]) for r, t in zip(rvecs, tvecs)]
    return CameraModel(K, dist.reshape(-1)[:5], size), poses, float(rms)


def _fit_ellipse(xy: np.ndarray, f: float) -> tuple[np.ndarray, float]:
    """(centre, semi-major axis) of the ellipse through normalised points ``xy`` (fitted in pixel-like
    units about their mean, for float32 conditioning)."""
    m = xy.mean(axis=0)
    (cx, cy), (w, h), _ = cv2.fitEllipseDirect(((xy - m) * f).astype(np.float32))
    return m + np.array([cx, cy]) / f, max(w, h) / 2 / f


def _pose_H(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    R, _ = cv2.Rodrigues(p[:3])
    return R, p[3:]


def ring_observation(edges: RingEdges, model: CameraModel, pose: np.ndarray, X: np.ndarray | None
                     ) -> tuple[np.ndarray, float]:
    """The ring centre's image (px, distorted) with the perspective bias removed; and the bias (px).

    ``X`` is the current seat estimate in PCS (None: no correction yet).
    """
    f = model.f
    centres, biases = [], []
    R, t = _pose_H(pose)
    for pts in (edges.outer, edges.inner):
        xy = model.undistort(pts)
        c, a = _fit_ellipse(xy, f)
        bias = np.zeros(2)
        if X is not None:
            bias = _perspective_bias(R, t, X, a, f)
        centres.append(c - bias)
        biases.append(np.linalg.norm(bias) * f)
    c = np.mean(centres, axis=0)
    uv, _ = cv2.projectPoints(np.array([[c[0], c[1], 1.0]]), np.zeros(3), np.zeros(3), model.K, model.dist)
    return uv.reshape(2), float(np.mean(biases))


def _perspective_bias(R: np.ndarray, t: np.ndarray, X: np.ndarray, a: float, f: float) -> np.ndarray:
    """Centre of the imaged circle minus the image of its centre (normalised), for a circle at ``X``
    in the plate plane whose radius matches the observed ellipse's semi-major axis ``a``."""
    Xc = R @ X + t
    x0 = Xc[:2] / Xc[2]
    # ρ from the unforeshortened axis and the depth: first order is enough, the bias scales
    # with ρ², so 1 % in ρ is 2 % of a sub-pixel bias
    rho = a * Xc[2]
    th = np.linspace(0, 2 * np.pi, 72, endpoint=False)
    P = X[None, :] + rho * np.column_stack([np.cos(th), np.sin(th), np.zeros_like(th)])
    Pc = P @ R.T + t
    return _fit_ellipse(Pc[:, :2] / Pc[:, 2:], f)[0] - x0


def initial_seats(views: list[View], model: CameraModel, poses: list[np.ndarray], seats: dict[str, np.ndarray]
                  ) -> dict[str, np.ndarray]:
    """Seats by ray intersection of the (bias-corrected when ``seats`` has one) ring observations."""
    out = {}
    for colour in NEST_NAMES:
        C, d = [], []
        for v, p in zip(views, poses):
            if colour not in v.rings:
                continue
            uv, _ = ring_observation(v.rings[colour], model, p, seats.get(colour))
            R, t = _pose_H(p)
            C.append(-R.T @ t)
            d.append(R.T @ model.rays(uv[None, :])[0])
        if len(C) < 2:
            raise CalibrationError(f"the {colour} ring was found in {len(C)} photograph(s), need >= 2 "
                                   f"({_why_missing(views, colour)})")
        out[colour] = intersect_rays(np.array(C), np.array(d))[0]  # too close to parallel: it raises
    return out


def _why_missing(views: list[View], colour: str) -> str:
    why = [f"{v.name}: {v.missing[colour]}" for v in views if colour in v.missing]
    return "; ".join(why[:3]) + (" ..." if len(why) > 3 else "") if why else "no usable photograph"




@dataclass
class SurveyResult:
    """The surveyed plate definition and the survey's report."""

    plate: Plate
    report: dict[str, Any]


def _same_size(images: dict[str, np.ndarray]) -> tuple[int, int]:
    sizes = {name: (int(np.shape(im)[1]), int(np.shape(im)[0])) for name, im in images.items()}
    first = next(iter(sizes.values()))
    odd = [f"{n} is {w}x{h}" for n, (w, h) in sizes.items() if (w, h) != first]
    if odd:
        raise ValueError(f"every photograph must come from one camera at one size ({first[0]}x{first[1]}); "
                         f"{', '.join(odd[:3])}")
    return first


def _ring_obs(views: list[View], model: CameraModel, poses: list[np.ndarray], seats: dict[str, np.ndarray]
              ) -> tuple[list[dict[int, np.ndarray]], list[dict[str, float]]]:
    obs, bias = [], []
    for v, p in zip(views, poses):
        o, b = {}, {}
        for i, colour in enumerate(NEST_NAMES):
            if colour in v.rings:
                o[i], b[colour] = ring_observation(v.rings[colour], model, p, seats[colour])
        obs.append(o)
        bias.append(b)
    return obs, bias


def _bundle(views: list[View], model: CameraModel, poses: list[np.ndarray], seats: dict[str, np.ndarray],
            fit_k3: bool) -> tuple[Bundle, list[dict[str, float]]]:
    """Two rounds: ring observations from the current estimate (bias removed), then the bundle."""
    corners = [(v.ref_P, v.uv) for v in views]
    b: Bundle | None = None
    bias: list[dict[str, float]] = []
    for _ in range(2):
        rings, bias = _ring_obs(views, model, poses, seats)
        b = adjust(model, poses, np.array([seats[c] for c in NEST_NAMES]), corners, rings, fit_k3)
        model, poses, seats = b.model, b.poses, dict(zip(NEST_NAMES, b.seats))
    assert b is not None
    return b, bias


def run_survey(images: dict[str, np.ndarray], plate: Plate, progress: Progress | None = None) -> SurveyResult:
    """Survey the nest seats from RGB photographs ``{name: image}`` of the whole plate.

    ``plate`` is the plate's design (board, patches, δ); the result is a copy with the
    surveyed seats, their 1σ and the report. Raises CalibrationError (not enough data,
    a ring missing everywhere) or ValueError (bad input), each naming the file or colour.
    ``progress(fraction, step)``, when given, hears each photograph's detection and the bundle.
    """
    if not images:
        raise ValueError("no photographs to survey")
    size = _same_size(images)
    views, skipped = detect_views(images, plate, progress)
    if len(views) < MIN_VIEWS:
        skips = "; ".join(f"{n}: {why}" for n, why in list(skipped.items())[:4])
        raise CalibrationError(f"only {len(views)} usable photograph(s) of {len(images)} "
                               f"(need >= {MIN_VIEWS}): {skips}")
    if progress:
        progress(1.0, f"camera calibration and bundle adjustment over {len(views)} photographs")
    model, poses, rms0 = calibrate(views, size)
    seats = initial_seats(views, model, poses, {})
    seats = initial_seats(views, model, poses, seats)
    b, bias = _bundle(views, model, poses, seats, fit_k3=True)
    k3_kept = abs(b.model.dist[4]) >= 3 * b.intr_sigma[8]
    if not k3_kept:  # the data do not support k3: fix it at 0 (its 3σ interval contains 0)
        b, bias = _bundle(views, b.model, b.poses, dict(zip(NEST_NAMES, b.seats)), fit_k3=False)
    if _drop_outliers(views, b):  # a blob of the ring's colour that is not the ring: survey without it
        initial_seats(views, b.model, b.poses, {})  # still >= 2 views per ring, or a clear error
        b, bias = _bundle(views, b.model, b.poses, dict(zip(NEST_NAMES, b.seats)), fit_k3=k3_kept)
    sig = {c: np.sqrt(np.diag(b.seat_cov[i])).tolist() for i, c in enumerate(NEST_NAMES)}
    report = _report(views, skipped, b, bias, k3_kept, rms0)
    seats_out = {c: b.seats[i].tolist() for i, c in enumerate(NEST_NAMES)}
    note = f"nests surveyed from {len(views)} photographs"
    out = replace(plate, nests_ref_nst=seats_out, nests_sigma_mm=sig, survey=report,
                  notes=(plate.notes + "; " if plate.notes else "") + note)
    return SurveyResult(out, report)


def _drop_outliers(views: list[View], b: Bundle) -> bool:
    """Move ring observations off by > :data:`RING_OUTLIER_PX` (and 5σ) to ``missing``; any dropped?"""
    limit = max(RING_OUTLIER_PX, 5 * b.sigma_ring_px)
    dropped = False
    for v, rr in zip(views, b.ring_res):
        for i, r in rr.items():
            off = float(np.linalg.norm(r))
            if off > limit:
                colour = NEST_NAMES[i]
                v.missing[colour] = f"{v.name}: {colour} ring dropped, {off:.2f} px off the other " \
                                    f"photographs' solution (limit {limit:.2f} px): another {colour} object?"
                del v.rings[colour]
                dropped = True
    return dropped


def _report(views: list[View], skipped: dict[str, str], b: Bundle, bias: list[dict[str, float]],
            k3_kept: bool, rms0: float) -> dict[str, Any]:
    per_view = []
    for v, cr, rr, bb in zip(views, b.corner_res, b.ring_res, bias):
        per_view.append({"image": v.name, "corners": len(v.uv),
                         "corner_rms_px": float(np.sqrt(np.mean(np.sum(cr ** 2, axis=1)))),
                         "ring_residual_px": {NEST_NAMES[i]: float(np.linalg.norm(r)) for i, r in rr.items()},
                         "ring_bias_px": bb, "rings_missing": v.missing})
    nests = {c: {"ref_P_nst_mm": b.seats[i].tolist(), "sigma_mm": np.sqrt(np.diag(b.seat_cov[i])).tolist(),
                 "cov_mm2": b.seat_cov[i].tolist(), "views": sum(i in rr for rr in b.ring_res)}
             for i, c in enumerate(NEST_NAMES)}
    return {"method": "self-calibrating bundle over patch corners and ring centres (docs/operations.md)",
            "views": per_view, "skipped": skipped, "nests": nests,
            "sigma_corner_px": b.sigma_corner_px, "sigma_ring_px": b.sigma_ring_px,
            "calibrate_camera_rms_px": rms0, "k3_fitted": bool(k3_kept),
            "camera_model": b.model.to_dict(), "intrinsics_sigma": b.intr_sigma.tolist()}
