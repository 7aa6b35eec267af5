"""The plate's ChArUco target: board model, corner detection and the pose cam_H_ref.

PCS (``ref``) is the OpenCV board frame (origin at the board's outer first corner,
x along columns, y along rows, z into the plate), so the board's object points are
``ref_P`` directly. ``estimate_cam_H_ref`` solves the planar PnP with IPPE, which
returns both mirror solutions; it keeps the better one only when its reprojection
RMS beats the other by ``min_ambiguity_ratio`` (calibration.md §2.2), then polishes
it with Levenberg–Marquardt.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from calibration.camera_model import CameraModel
from calibration.errors import CalibrationError
from calibration.frames import make_H
from calibration.plate import Plate

LM_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


@lru_cache(maxsize=8)
def _board(cols: int, rows: int, square_mm: float, marker_mm: float, dict_name: str) -> cv2.aruco.CharucoBoard:
    code = getattr(cv2.aruco, dict_name, None)
    if not isinstance(code, int) or not dict_name.startswith("DICT_"):
        raise ValueError(f"unknown ArUco dictionary {dict_name!r} (expected e.g. 'DICT_5X5_1000')")
    dictionary = cv2.aruco.getPredefinedDictionary(code)
    n_markers = (cols * rows) // 2
    if n_markers > dictionary.bytesList.shape[0]:
        raise ValueError(f"board {cols}x{rows} needs {n_markers} markers but {dict_name} has only "
                         f"{dictionary.bytesList.shape[0]}")
    # keep only the markers the board uses: marker identification in OpenCV 5 costs
    # time in proportion to the dictionary size (1000 vs 600: ~1.7x), and ids the
    # board cannot contain are rejected outright
    board_dict = cv2.aruco.Dictionary(dictionary.bytesList[:n_markers].copy(), dictionary.markerSize,
                                      dictionary.maxCorrectionBits)
    return cv2.aruco.CharucoBoard((cols, rows), square_mm, marker_mm, board_dict)


def make_board(plate: Plate) -> cv2.aruco.CharucoBoard:
    """The OpenCV ChArUco board described by ``plate`` (cached)."""
    return _board(plate.board_cols, plate.board_rows, float(plate.square_mm), float(plate.marker_mm),
                  plate.aruco_dict)


@lru_cache(maxsize=8)
def _detector(cols: int, rows: int, square_mm: float, marker_mm: float, dict_name: str) -> cv2.aruco.CharucoDetector:
    board = _board(cols, rows, square_mm, marker_mm, dict_name)
    return cv2.aruco.CharucoDetector(board)


def _gray(image: np.ndarray) -> np.ndarray:
    """A uint8 single-channel view of ``image`` or a ValueError naming what is wrong."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if img.ndim != 2:
        raise ValueError(f"image: expected a 2-D grey image, got shape {img.shape}")
    if img.dtype != np.uint8:
        raise ValueError(f"image: expected dtype uint8, got {img.dtype}")
    return img


def detect_corners(image: np.ndarray, plate: Plate, model: CameraModel | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Detect ChArUco inner corners: ``(ids (N,), uv (N, 2))``, empty when none are found.

    ``model`` is only used to check that the image has the model's size.
    """
    img = _gray(image)
    if model is not None and (img.shape[1], img.shape[0]) != tuple(model.size):
        raise ValueError(f"image is {img.shape[1]}x{img.shape[0]} but the camera model is for "
                         f"{model.size[0]}x{model.size[1]}")
    det = _detector(plate.board_cols, plate.board_rows, float(plate.square_mm), float(plate.marker_mm),
                    plate.aruco_dict)
    corners, ids, _, _ = det.detectBoard(img)
    if ids is None or len(ids) == 0:
        return np.zeros(0, int), np.zeros((0, 2))
    return ids.reshape(-1).astype(int), corners.reshape(-1, 2).astype(float)


@dataclass
class CamRefPose:
    """The target pose in the camera, with the evidence it rests on."""

    cam_H_ref: np.ndarray
    rms_px: float  # reprojection RMS of the accepted solution
    n_corners: int
    ambiguity_ratio: float  # RMS of the mirror solution / RMS of the accepted one
    ids: np.ndarray
    uv: np.ndarray


def _rms(obj: np.ndarray, uv: np.ndarray, rvec: np.ndarray, tvec: np.ndarray, model: CameraModel) -> float:
    proj, _ = cv2.projectPoints(obj, rvec, tvec, model.K, model.dist)
    return float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - uv) ** 2, axis=1))))


def pose_from_corners(ids: np.ndarray, uv: np.ndarray, model: CameraModel, plate: Plate,
                      min_corners: int = 12, min_ambiguity_ratio: float = 5.0) -> CamRefPose:
    """cam_H_ref from detected corner ids and pixel positions (see :func:`estimate_cam_H_ref`)."""
    ids = np.asarray(ids, dtype=int).reshape(-1)
    uv = np.asarray(uv, dtype=float).reshape(-1, 2)
    if len(ids) != len(uv):
        raise ValueError(f"pose_from_corners: {len(ids)} ids but {len(uv)} points")
    if len(ids) < max(min_corners, 4):
        raise CalibrationError(f"only {len(ids)} ChArUco corner(s) found, need at least {max(min_corners, 4)}: "
                               f"is the target in view, lit and in focus?")
    board = make_board(plate)
    obj = np.asarray(board.getChessboardCorners(), dtype=np.float64)
    if ids.min() < 0 or ids.max() >= len(obj):
        raise ValueError(f"pose_from_corners: corner ids must be in 0..{len(obj) - 1}, got {ids.min()}..{ids.max()}")
    obj = obj[ids].reshape(-1, 1, 3)
    img = uv.reshape(-1, 1, 2)
    n, rvecs, tvecs, errs = cv2.solvePnPGeneric(obj, img, model.K, model.dist, flags=cv2.SOLVEPNP_IPPE)
    if n == 0:
        raise CalibrationError(f"solvePnP (IPPE) found no pose from {len(ids)} corners")
    # IPPE returns both mirror solutions sorted by reprojection error; compare them as
    # returned (a refined mirror solution may slide into the true minimum)
    errs = np.asarray(errs, dtype=float).reshape(-1)
    ratio = float(errs[1] / max(errs[0], 1e-12)) if n > 1 else float("inf")
    if ratio < min_ambiguity_ratio:
        raise CalibrationError(f"ambiguous target pose: mirror solution RMS {errs[1]:.3f} px is only "
                               f"{ratio:.2f}x the best {errs[0]:.3f} px (need >= {min_ambiguity_ratio}x)")
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, model.K, model.dist, rvecs[0].reshape(3, 1).copy(),
                                      tvecs[0].reshape(3, 1).copy(), LM_CRITERIA)
    rms = _rms(obj, uv, rvec, tvec, model)
    R, _ = cv2.Rodrigues(rvec)
    cam_H_ref = make_H(R, tvec.reshape(3), "cam_H_ref")
    if cam_H_ref[2, 3] <= 0:
        raise CalibrationError(f"target pose puts the plate behind the camera (z = {cam_H_ref[2, 3]:.3f} mm)")
    return CamRefPose(cam_H_ref, rms, len(ids), float(ratio), ids, uv)


def estimate_cam_H_ref(image: np.ndarray, model: CameraModel, plate: Plate, min_corners: int = 12,
                       min_ambiguity_ratio: float = 5.0) -> CamRefPose:
    """Pose of the plate target in the camera from one image (raises CalibrationError)."""
    ids, uv = detect_corners(image, plate, model)
    return pose_from_corners(ids, uv, model, plate, min_corners, min_ambiguity_ratio)
