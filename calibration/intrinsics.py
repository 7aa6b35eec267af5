"""Camera intrinsics from several ChArUco views (``cv2.calibrateCamera``).

The paper assumes the intrinsics are calibrated beforehand; this module does that
from images of the plate target (or any ChArUco board described by a Plate) taken
at different tilts and distances. Views with too few corners are left out and
listed in the report with the reason; fewer than ``min_views`` usable views is a
CalibrationError. The report gives the overall and per-view reprojection RMS and
OpenCV's standard deviations of the intrinsics.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

from calibration.camera_model import CameraModel
from calibration.errors import CalibrationError
from calibration.plate import Plate
from calibration.target import detect_corners, make_board

CALIB_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-12)
#: default flags: k3 stays at its initial value (0 unless given): with a board that
#: fills only part of a wide field it is poorly determined and trades off with k1, k2
DEFAULT_FLAGS = cv2.CALIB_FIX_K3


def _collect_views(images: Sequence[np.ndarray], plate: Plate, size: tuple[int, int], min_corners: int
                   ) -> tuple[list[np.ndarray], list[np.ndarray], list[dict[str, Any]]]:
    """Object and image points of every view with enough ChArUco corners, and a line per view."""
    w, h = size
    all_obj = np.asarray(make_board(plate).getChessboardCorners(), dtype=np.float32)
    obj_pts: list[np.ndarray] = []
    img_pts: list[np.ndarray] = []
    views: list[dict[str, Any]] = []
    for k, image in enumerate(images):
        if image.shape[:2] != (h, w):
            raise ValueError(f"image {k} is {image.shape[1]}x{image.shape[0]}, expected {w}x{h}")
        ids, uv = detect_corners(image, plate)
        entry: dict[str, Any] = {"index": k, "n_corners": int(len(ids)), "used": len(ids) >= min_corners}
        if entry["used"]:
            obj_pts.append(all_obj[ids].reshape(-1, 1, 3))
            img_pts.append(uv.astype(np.float32).reshape(-1, 1, 2))
        else:
            entry["reason"] = f"{len(ids)} corners < min_corners={min_corners}"
        views.append(entry)
    return obj_pts, img_pts, views


def _outliers(obj_pts: list[np.ndarray], img_pts: list[np.ndarray], rvecs: Any, tvecs: Any, K: np.ndarray,
              dist: np.ndarray, reject_factor: float) -> list[np.ndarray]:
    """Per view, a mask of the corners to keep: residual <= reject_factor x the median residual."""
    res = []
    for o, i, rv, tv in zip(obj_pts, img_pts, rvecs, tvecs):
        proj, _ = cv2.projectPoints(o, rv, tv, K, dist)
        res.append(np.linalg.norm(proj.reshape(-1, 2) - i.reshape(-1, 2), axis=1))
    limit = reject_factor * float(np.median(np.concatenate(res)))
    return [r <= limit for r in res]


def calibrate_intrinsics(images: Sequence[np.ndarray], plate: Plate, size: tuple[int, int],
                         initial: CameraModel | None = None, min_corners: int = 30, min_views: int = 4,
                         flags: int = DEFAULT_FLAGS, reject_factor: float | None = 3.0
                         ) -> tuple[CameraModel, dict[str, Any]]:
    """Estimate K and the distortion from ChArUco ``images`` of ``size`` (w, h).

    ``initial`` seeds the optimisation (CALIB_USE_INTRINSIC_GUESS); without it
    OpenCV initialises from the views' homographies. With ``reject_factor`` set,
    corners whose residual exceeds that many times the median residual (for
    Gaussian noise ~3.5 sigma) are dropped once and the calibration is repeated:
    foreshortened corners on the far side of tilted views are occasionally off by
    most of a pixel. The report counts them.
    """
    w, h = int(size[0]), int(size[1])
    obj_pts, img_pts, views = _collect_views(images, plate, (w, h), min_corners)
    if len(obj_pts) < min_views:
        raise CalibrationError(f"only {len(obj_pts)} of {len(views)} views have >= {min_corners} corners; "
                               f"need at least {min_views} views at different tilts")
    K0, d0 = np.eye(3), np.zeros(5)
    if initial is not None:
        if tuple(initial.size) != (w, h):
            raise ValueError(f"initial model is for {initial.size}, images are {(w, h)}")
        K0, d0 = initial.K.copy(), initial.dist.copy()
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS

    def run(K0: np.ndarray, d0: np.ndarray, flags: int) -> tuple:
        return cv2.calibrateCameraExtended(obj_pts, img_pts, (w, h), K0, d0, flags=flags, criteria=CALIB_CRITERIA)

    rms, K, dist, rvecs, tvecs, std_int, _, per_view = run(K0, d0, flags)
    rms_all, n_rejected = float(rms), 0
    if reject_factor is not None:
        keep = _outliers(obj_pts, img_pts, rvecs, tvecs, K, dist, reject_factor)
        n_rejected = int(sum((~k).sum() for k in keep))
        if n_rejected:
            obj_pts = [o[k] for o, k in zip(obj_pts, keep)]
            img_pts = [i[k] for i, k in zip(img_pts, keep)]
            rms, K, dist, rvecs, tvecs, std_int, _, per_view = run(K, dist, flags | cv2.CALIB_USE_INTRINSIC_GUESS)
    used = [v for v in views if v["used"]]
    for v, e in zip(used, np.asarray(per_view).reshape(-1)):
        v["rms_px"] = float(e)
    std = np.asarray(std_int).reshape(-1)
    report = {
        "rms_px": float(rms),  # after rejection
        "rms_px_all": rms_all,  # first pass, every detected corner
        "n_views_used": len(used),
        "n_corners": int(sum(v["n_corners"] for v in used)),
        "n_rejected": n_rejected,
        "views": views,
        "std": {"fx": float(std[0]), "fy": float(std[1]), "cx": float(std[2]), "cy": float(std[3]),
                "dist": std[4:9].tolist()},
        "flags": int(flags),
    }
    return CameraModel(K, dist.reshape(-1)[:5], (w, h)), report
