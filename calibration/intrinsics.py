"""Camera intrinsics from ChArUco views of a hand-held board (``cv2.calibrateCameraExtended``).

No initial guess: OpenCV initialises K from the views' homographies (Zhang, IEEE
TPAMI 22(11), 2000), so nothing about the camera has to be known beforehand. Views
with too few corners are left out and listed with the reason; fewer than
``min_views`` usable views is a CalibrationError.

The report gives the reprojection RMS overall and per view, each view's tilt, and a
1σ uncertainty per parameter: the larger of OpenCV's ``stdDeviationsIntrinsics`` (the
diagonal of (JᵀJ)⁻¹ scaled by the residual variance Σr²/(m − p)) and a leave-one-view-out
jackknife, which also sees errors shared by the corners of one view. Whether k3 is fitted is decided
by the data: the fit with k3 free replaces the one with k3 = 0 only when the drop in
the residual sum of squares is significant (F test, 1 extra parameter, 1 % level),
so a lens with k3 ≠ 0 gets it and one without does not trade k3 off against k1, k2.
``findings`` lists what makes the view set degenerate (``degenerate``: no model should
be used) and ``warnings`` what weakens it; each says which view to add
(:mod:`calibration.intrinsics_recipe`).
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

from calibration.camera_model import CameraModel
from calibration.errors import CalibrationError
from calibration.intrinsics_recipe import coverage_findings, tilt_findings, view_geometry
from calibration.board import detect_board_corners
from calibration.target import BoardLayout, make_board

CALIB_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
#: F(1, m − p) at the 1 % level for the large m (thousands of residuals) of a calibration:
#: the χ²₁ 99 % quantile (6.635), which F(1, n) approaches within 0.1 % for n > 2000
F_CRIT_1PCT = 6.635
PARAM_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


def _collect_views(images: Sequence[np.ndarray], board: BoardLayout, size: tuple[int, int], min_corners: int
                   ) -> tuple[list[np.ndarray], list[np.ndarray], list[dict[str, Any]]]:
    """Object and image points of every view with enough ChArUco corners, and a line per view."""
    w, h = size
    all_obj = np.asarray(make_board(board).getChessboardCorners(), dtype=np.float32)
    obj_pts: list[np.ndarray] = []
    img_pts: list[np.ndarray] = []
    views: list[dict[str, Any]] = []
    for k, image in enumerate(images):
        if image.shape[:2] != (h, w):
            raise ValueError(f"image {k} is {image.shape[1]}x{image.shape[0]}, expected {w}x{h}")
        ids, uv = detect_board_corners(image, board)
        entry: dict[str, Any] = {"index": k, "n_corners": int(len(ids)), "used": len(ids) >= min_corners}
        if entry["used"]:
            obj_pts.append(all_obj[ids].reshape(-1, 1, 3))
            img_pts.append(uv.astype(np.float32).reshape(-1, 1, 2))
        else:
            entry["reason"] = f"{len(ids)} corners < min_corners={min_corners}"
        views.append(entry)
    return obj_pts, img_pts, views


def _residuals(obj_pts: list[np.ndarray], img_pts: list[np.ndarray], fit: dict[str, Any]) -> list[np.ndarray]:
    """Per view, the reprojection error length of every corner (px)."""
    res = []
    for o, i, rv, tv in zip(obj_pts, img_pts, fit["rvecs"], fit["tvecs"]):
        proj, _ = cv2.projectPoints(o, rv, tv, fit["K"], fit["dist"])
        res.append(np.linalg.norm(proj.reshape(-1, 2) - i.reshape(-1, 2), axis=1))
    return res


def _fit(obj_pts: list[np.ndarray], img_pts: list[np.ndarray], size: tuple[int, int], k3: bool,
         start: dict[str, Any] | None = None) -> dict[str, Any]:
    """One calibration; ``start`` (an earlier fit of the same data) seeds it, else OpenCV initialises."""
    flags = 0 if k3 else cv2.CALIB_FIX_K3
    K0, d0 = np.eye(3), np.zeros(5)
    if start is not None:
        K0, d0 = start["K"].copy(), start["dist"].copy()
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS
    rms, K, dist, rvecs, tvecs, std, _, per_view = cv2.calibrateCameraExtended(
        obj_pts, img_pts, size, K0, d0, flags=flags, criteria=CALIB_CRITERIA)
    n_pts = int(sum(len(o) for o in obj_pts))
    return {"rms": float(rms), "K": K, "dist": dist.reshape(-1)[:5], "rvecs": rvecs, "tvecs": tvecs,
            "std": np.asarray(std).reshape(-1)[:9], "per_view": np.asarray(per_view).reshape(-1),
            "ssr": float(rms) ** 2 * n_pts, "dof": 2 * n_pts - (9 if k3 else 8) - 6 * len(obj_pts), "k3": k3}


def _k3_decision(fixed: dict[str, Any], free: dict[str, Any]) -> dict[str, Any]:
    """Keep k3 when freeing it lowers the residual significantly (F test) — never from its true value."""
    F = (fixed["ssr"] - free["ssr"]) / (free["ssr"] / free["dof"]) if free["dof"] > 0 else 0.0
    k3, s = float(free["dist"][4]), float(free["std"][8])
    fitted = F > F_CRIT_1PCT
    verb = "fitted" if fitted else "fixed at 0"
    return {"fitted": fitted, "k3_free": k3, "std_free": s, "F": float(F), "F_crit": F_CRIT_1PCT,
            "reason": f"k3 {verb}: freeing it changes the residual by F = {F:.2f} "
                      f"({'>' if fitted else '<='} {F_CRIT_1PCT} at 1 %); k3 free = {k3:.3g} ± {s:.2g}"}


def _params(fit: dict[str, Any]) -> np.ndarray:
    K = fit["K"]
    return np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], fit["dist"]]


def _jackknife(obj_pts: list[np.ndarray], img_pts: list[np.ndarray], size: tuple[int, int],
               fit: dict[str, Any]) -> np.ndarray:
    """Leave-one-view-out jackknife 1σ of the 9 parameters (Efron & Stein, Ann. Stat. 9(3), 1981).

    The covariance assumes independent corner errors; the errors of one view's corners are
    correlated (one pose, one lighting, one print region), which the jackknife over whole
    views accounts for. A set that leans on a single view shows it as a large σ.
    """
    n = len(obj_pts)
    thetas = [_params(_fit(obj_pts[:i] + obj_pts[i + 1:], img_pts[:i] + img_pts[i + 1:],
                           size, fit["k3"], fit)) for i in range(n)]
    t = np.array(thetas)
    return np.sqrt((n - 1) / n * ((t - t.mean(axis=0)) ** 2).sum(axis=0))


def _uncertainty(fit: dict[str, Any], jack: np.ndarray) -> dict[str, Any]:
    """1σ per parameter: the larger of the residual-scaled covariance and the jackknife (None for k3
    held at 0); both sources are kept under ``covariance`` and ``jackknife``."""
    cov = {n: float(v) for n, v in zip(PARAM_NAMES, fit["std"])}
    jk = {n: float(v) for n, v in zip(PARAM_NAMES, jack)}
    out: dict[str, float | None] = {n: max(cov[n], jk[n]) for n in PARAM_NAMES}
    covariance: dict[str, float | None] = {**cov}
    jackknife: dict[str, float | None] = {**jk}
    if not fit["k3"]:
        out["k3"] = covariance["k3"] = jackknife["k3"] = None
    return {**out, "covariance": covariance, "jackknife": jackknife}


def _calibrate(obj_pts: list[np.ndarray], img_pts: list[np.ndarray], size: tuple[int, int],
               reject_factor: float | None) -> tuple[dict[str, Any], dict[str, Any], list[np.ndarray], int]:
    """Fit without k3, drop outlier corners once, decide on k3: (fit, k3 decision, keep masks, n rejected)."""
    first = _fit(obj_pts, img_pts, size, k3=False)
    keep = [np.ones(len(o), bool) for o in obj_pts]
    if reject_factor is not None:
        res = _residuals(obj_pts, img_pts, first)
        limit = reject_factor * float(np.median(np.concatenate(res)))
        keep = [r <= limit for r in res]
    n_rejected = int(sum((~k).sum() for k in keep))
    obj = [o[k] for o, k in zip(obj_pts, keep)]
    img = [i[k] for i, k in zip(img_pts, keep)]
    fixed = _fit(obj, img, size, k3=False, start=first) if n_rejected else first
    fixed["rms_all"] = first["rms"]
    free = _fit(obj, img, size, k3=True, start=fixed)
    decision = _k3_decision(fixed, free)
    best = free if decision["fitted"] else fixed
    best["rms_all"] = first["rms"]
    return best, decision, keep, n_rejected


def calibrate_intrinsics(images: Sequence[np.ndarray], board: BoardLayout, size: tuple[int, int],
                         min_corners: int = 20, min_views: int = 6, reject_factor: float | None = 3.0
                         ) -> tuple[CameraModel, dict[str, Any]]:
    """Estimate K and the distortion from ChArUco ``images`` of ``size`` (w, h) of ``board``.

    ``board`` is a :class:`calibration.board.Board` (or anything with its board fields, e.g.
    a Plate). With ``reject_factor`` set, corners whose residual exceeds that many times
    the median residual (for Gaussian noise ~3.5σ) are dropped once and the fit repeated:
    foreshortened corners on the far side of tilted views are occasionally off by most
    of a pixel. The report counts them.
    """
    w, h = int(size[0]), int(size[1])
    obj_pts, img_pts, views = _collect_views(images, board, (w, h), min_corners)
    if len(obj_pts) < min_views:
        raise CalibrationError(f"only {len(obj_pts)} of {len(views)} views have >= {min_corners} board "
                               f"corners; need at least {min_views} views at different tilts "
                               f"(docs/operations.md, Intrinsic calibration)")
    fit, decision, keep, n_rejected = _calibrate(obj_pts, img_pts, (w, h), reject_factor)
    jack = _jackknife([o[k] for o, k in zip(obj_pts, keep)], [i[k] for i, k in zip(img_pts, keep)],
                      (w, h), fit)
    used = [v for v in views if v["used"]]
    for v, e, rv, k in zip(used, fit["per_view"], fit["rvecs"], keep):
        tilt, axis = view_geometry(rv)
        v.update(rms_px=float(e), tilt_deg=round(tilt, 2), n_rejected=int((~k).sum()),
                 tilt_axis=[round(float(a), 4) for a in axis])
    findings = tilt_findings(list(fit["rvecs"]))
    uv_all = np.concatenate([i.reshape(-1, 2) for i in img_pts])
    report = {
        "rms_px": fit["rms"],  # after rejection
        "rms_px_all": fit["rms_all"],  # first pass, every detected corner
        "n_views_used": len(used),
        "n_corners": int(sum(v["n_corners"] for v in used)),
        "n_rejected": n_rejected,
        "views": views,
        "std": _uncertainty(fit, jack),
        "k3": decision,
        "findings": findings,
        "degenerate": bool(findings),
        "warnings": coverage_findings(uv_all, (w, h)),
    }
    return CameraModel(fit["K"], fit["dist"], (w, h)), report
