"""The plate's ChArUco target: board model, corner detection and the pose cam_H_ref.

PCS (``ref``) is the OpenCV board frame (origin at the board's outer first corner,
x along columns, y along rows, z into the plate), so the board's object points are
``ref_P`` directly. ``estimate_cam_H_ref`` solves the planar PnP with IPPE, which
returns both mirror solutions; it keeps the better one only when its reprojection
RMS beats the other by ``min_ambiguity_ratio`` (docs/accuracy.md, "Image side"), then polishes
it with Levenberg–Marquardt.

Marker candidates are the squares OpenCV's detector finds, but the markers are
identified here: OpenCV 5 matches each candidate against the dictionary one entry at a
time, which is slow for a board of hundreds of markers (docs/benchmarks.md, "Referencing
compute"); reading each candidate's bits once and matching them against all markers and
rotations at once finds the same markers. A match may differ in as many bits as OpenCV
allows for the dictionary (none for DICT_4X4_1000), and a marker whose id disagrees with
its image neighbours is dropped. OpenCV's CharucoDetector then interpolates and refines
the chessboard corners from those markers; if its board check rejects the marker set,
OpenCV's own detector decides (``fast=False`` uses OpenCV for both steps).
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import lru_cache
from typing import Protocol

import cv2
import numpy as np

from calibration.camera_model import CameraModel
from calibration.errors import CalibrationError
from calibration.frames import make_H
from calibration.plate import Plate

LM_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


@lru_cache(maxsize=8)
def _board(cols: int, rows: int, square_mm: float, marker_mm: float,
           dict_name: str) -> cv2.aruco.CharucoBoard:
    code = getattr(cv2.aruco, dict_name, None)
    if not isinstance(code, int) or not dict_name.startswith("DICT_"):
        raise ValueError(f"unknown ArUco dictionary {dict_name!r} (expected e.g. 'DICT_5X5_1000')")
    dictionary = cv2.aruco.getPredefinedDictionary(code)
    n_markers = (cols * rows) // 2
    if n_markers > dictionary.bytesList.shape[0]:
        raise ValueError(f"board {cols}x{rows} needs {n_markers} markers but {dict_name} has only "
                         f"{dictionary.bytesList.shape[0]}")
    # keep only the markers the board uses: marker identification in OpenCV 5 costs
    # time in proportion to the dictionary size, and ids the board cannot contain are
    # rejected outright
    board_dict = cv2.aruco.Dictionary(dictionary.bytesList[:n_markers].copy(), dictionary.markerSize,
                                      dictionary.maxCorrectionBits)
    return cv2.aruco.CharucoBoard((cols, rows), square_mm, marker_mm, board_dict)


class BoardLayout(Protocol):
    """What a ChArUco board is made from: the plate's target (:class:`Plate`) or a printed intrinsics
    board (:class:`calibration.board.Board`)."""

    @property
    def board_cols(self) -> int: ...
    @property
    def board_rows(self) -> int: ...
    @property
    def square_mm(self) -> float: ...
    @property
    def marker_mm(self) -> float: ...
    @property
    def aruco_dict(self) -> str: ...


def make_board(plate: BoardLayout) -> cv2.aruco.CharucoBoard:
    """The OpenCV ChArUco board described by ``plate`` (cached)."""
    return _board(plate.board_cols, plate.board_rows, float(plate.square_mm), float(plate.marker_mm),
                  plate.aruco_dict)


@lru_cache(maxsize=8)
def _detector(cols: int, rows: int, square_mm: float, marker_mm: float,
              dict_name: str) -> cv2.aruco.CharucoDetector:
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


#: canonical marker image for bit reading: pixels per cell and the cell margin ignored
_CELL_PX, _CELL_MARGIN = 10, 2
#: largest width at which marker candidates are searched (bigger images are shrunk)
_CANDIDATE_WIDTH = 1400


@lru_cache(maxsize=8)
def _marker_codes(board: cv2.aruco.CharucoBoard) -> tuple[np.ndarray, int, int, cv2.aruco.ArucoDetector]:
    """Packed inner bits of every board marker, the marker size, the bits a match may
    differ in, and a candidate finder."""
    d = board.getDictionary()
    n = d.markerSize
    weights = 1 << np.arange(n * n, dtype=np.int64)
    codes = np.array([int(d.getBitsFromByteList(d.bytesList[k:k + 1], n).reshape(-1).astype(np.int64)
                          @ weights) for k in range(d.bytesList.shape[0])])
    # a one-marker dictionary: OpenCV then finds and returns all square candidates
    # quickly, and the identification below matches them against the board's markers
    finder = cv2.aruco.ArucoDetector(cv2.aruco.Dictionary(d.bytesList[:1].copy(), n, 0))
    # the dictionary's own limit, scaled as OpenCV's identification does: markers of
    # a dense dictionary (DICT_4X4_1000: 0 bits) differ from a neighbour in one bit, so
    # accepting a wrong bit there would read a misread marker as another id
    max_bits = int(d.maxCorrectionBits * cv2.aruco.DetectorParameters().errorCorrectionRate)
    return codes, n, max_bits, finder


def _read_codes(img: np.ndarray, quads: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Packed inner bits of each quad (full-image pixels, (N, 4, 2)) in its four rotations.

    Returns (codes (M, 4), indices (M,) of the quads that look like a marker: black and
    white cells, an all-black border). Each quad is warped to a canonical image, then
    the cells of all of them are read at once.
    """
    cells = n + 2
    side = cells * _CELL_PX
    dst = np.array([[0, 0], [side, 0], [side, side], [0, side]], np.float32)
    patches = np.empty((len(quads), side, side), np.uint8)
    q32 = quads.astype(np.float32)

    def warp(part: range) -> None:
        for k in part:
            cv2.warpPerspective(img, cv2.getPerspectiveTransform(q32[k], dst), (side, side), dst=patches[k],
                                flags=cv2.INTER_LINEAR)
    half = len(quads) // 2
    with ThreadPoolExecutor(2) as pool:  # each warp is small: two threads beat OpenCV's own split
        list(pool.map(warp, (range(half), range(half, len(quads)))))
    lo, hi = _CELL_MARGIN, _CELL_PX - _CELL_MARGIN
    # exact integer sums of the 6×6 inner pixels, then the mean
    cell_px = patches.reshape(-1, cells, _CELL_PX, cells, _CELL_PX)[:, :, lo:hi, :, lo:hi]
    means = cell_px.sum(axis=4, dtype=np.uint16).sum(axis=2, dtype=np.uint16) / (hi - lo) ** 2
    p10, p90 = np.percentile(means.reshape(len(quads), -1), [10, 90], axis=1)
    bits = means > ((p10 + p90) / 2)[:, None, None]
    border = (bits[:, 0].sum(axis=1) + bits[:, -1].sum(axis=1) + bits[:, 1:-1, 0].sum(axis=1)
              + bits[:, 1:-1, -1].sum(axis=1))
    # black/white structure and an all-black border (two stray cells allowed)
    keep = np.flatnonzero((p90 - p10 >= 15) & (border <= 2))
    inner = bits[keep, 1:-1, 1:-1].reshape(len(keep), -1).astype(np.int64)
    weights = 1 << np.arange(n * n, dtype=np.int64)
    order = np.arange(n * n).reshape(n, n)
    codes = np.stack([inner[:, np.rot90(order, r).reshape(-1)] @ weights for r in range(4)], axis=1)
    return codes, keep


def _detect_markers(img: np.ndarray, board: cv2.aruco.CharucoBoard) -> tuple[list[np.ndarray], np.ndarray]:
    """Board markers in ``img``: corners (each (1, 4, 2) float32, OpenCV order) and ids (N, 1).

    OpenCV 5's identification step compares every candidate with every dictionary
    entry one by one (~2 s for 800 candidates and 600 markers); here the candidates'
    bits are read once and matched against all markers and rotations with
    vectorised Hamming distances, accepting as many wrong bits as OpenCV would for
    this dictionary (``maxCorrectionBits`` × ``errorCorrectionRate``).
    """
    codes, n, max_bits, finder = _marker_codes(board)
    f = max(1, int(np.ceil(img.shape[1] / _CANDIDATE_WIDTH)))
    size = (img.shape[1] // f, img.shape[0] // f)
    small = img if f == 1 else cv2.resize(img, size, interpolation=cv2.INTER_AREA)
    found, _, rejected = finder.detectMarkers(small)
    quads = np.array([np.reshape(q, (4, 2)) for q in (*found, *rejected)], np.float64)
    if not len(quads):
        return [], np.zeros((0, 1), np.int32)
    quads = (quads + 0.5) * f - 0.5  # back to full-image pixel coordinates
    cand_codes, keep = _read_codes(img, quads, n)
    if not len(keep):
        return [], np.zeros((0, 1), np.int32)
    dist = np.bitwise_count(cand_codes[:, :, None] ^ codes[None, None, :])  # (N, 4, markers)
    flat = dist.reshape(len(keep), -1).argmin(axis=1)
    rot, ident = np.unravel_index(flat, dist.shape[1:])
    best = dist.reshape(len(keep), -1)[np.arange(len(keep)), flat]
    # per id the candidate with the fewest wrong bits, then the largest area, then the first
    ok = np.flatnonzero(best <= max_bits)
    k, marker, bits, r = keep[ok], ident[ok], best[ok], rot[ok]
    area = np.array([abs(cv2.contourArea(q)) for q in quads[k].astype(np.float32)])
    order = np.lexsort((np.arange(len(k)), -area, bits, marker))
    first = order[np.r_[True, np.diff(marker[order]) != 0]] if len(order) else order
    # bits read from corners in native order equal the marker rotated by r:
    # the marker's own first corner is r places further along
    turn = (np.arange(4)[None, :] + r[first, None]) % 4
    chosen = quads[k[first][:, None], turn].astype(np.float32)
    corners = [c.reshape(1, 4, 2) for c in chosen]
    ids = marker[first]
    return _consistent(corners, np.array(ids, np.int32).reshape(-1, 1), board)


#: neighbours a marker is checked against, and the largest disagreement (in squares)
_NEIGHBOURS, _MAX_OFF_SQUARES = 8, 0.5


def _consistent(corners: list[np.ndarray], ids: np.ndarray, board: cv2.aruco.CharucoBoard
                ) -> tuple[list[np.ndarray], np.ndarray]:
    """Drop markers whose id puts them where their image neighbours say they are not.

    A misread marker can match another id exactly (a dense dictionary has codes one
    bit apart). Around each marker the board-to-image map is nearly affine, so an
    affine map fitted (RANSAC) to its nearest neighbours in the image predicts its
    board position; a marker more than half a square off is dropped. Markers with too
    few agreeing neighbours to judge are kept (the board check still sees them).
    """
    if len(ids) <= _NEIGHBOURS:
        return corners, ids
    centres = _marker_centres(board)
    uv = np.concatenate(corners).reshape(-1, 4, 2).mean(axis=1).astype(np.float64)
    xy = np.array([centres[int(i)] for i in ids.ravel()])
    d2 = ((uv[:, None, :] - uv[None, :, :]) ** 2).sum(axis=2)
    near = np.argsort(d2, axis=1)[:, 1:_NEIGHBOURS + 1]
    uv_near, xy_near = uv[near], xy[near]  # (N, 8, 2) each
    A = np.full((len(ids), 2, 3), np.nan)
    for j in range(len(ids)):
        fit, inl = cv2.estimateAffine2D(uv_near[j], xy_near[j], method=cv2.RANSAC,
                                        ransacReprojThreshold=_MAX_OFF_SQUARES / 2, refineIters=0)
        if fit is not None and int(inl.sum()) >= 4:
            A[j] = fit
    off = np.linalg.norm(np.einsum("nij,nj->ni", A[:, :, :2], uv) + A[:, :, 2] - xy, axis=1)
    keep = np.isnan(off) | (off <= _MAX_OFF_SQUARES)  # too few agreeing neighbours: kept
    return [c for c, k in zip(corners, keep) if k], ids[keep]


def _detect_board(det: cv2.aruco.CharucoDetector, img: np.ndarray, markers: list[np.ndarray] | None = None,
                  marker_ids: np.ndarray | None = None) -> tuple[np.ndarray | None, np.ndarray | None]:
    """OpenCV's ``detectBoard`` (corners, ids), from the given markers or its own; both are None when
    it finds no corner (its stub says arrays, always)."""
    if markers is None:
        corners, ids, _, _ = det.detectBoard(img)
    else:
        corners, ids, _, _ = det.detectBoard(img, markerCorners=markers, markerIds=marker_ids)
    return corners, ids


@lru_cache(maxsize=8)
def _marker_centres(board: cv2.aruco.CharucoBoard) -> dict[int, np.ndarray]:
    """Board position of each marker's centre, in squares."""
    obj = np.array(board.getObjPoints(), np.float64).reshape(-1, 4, 3)[:, :, :2]
    return dict(zip(np.asarray(board.getIds()).ravel().tolist(), obj.mean(axis=1) / board.getSquareLength()))


def detect_corners(image: np.ndarray, plate: BoardLayout, model: CameraModel | None = None,
                   fast: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Detect ChArUco inner corners: ``(ids (N,), uv (N, 2))``, empty when none are found.

    ``model`` is only used to check that the image has the model's size. ``fast``
    uses this module's marker identification (the same markers, much quicker); the
    chessboard corners are interpolated and refined as OpenCV's CharucoDetector does
    either way. When OpenCV's board check keeps fewer corners than half the markers
    found, OpenCV's own marker detection runs too and the larger corner set is kept.
    """
    img = _gray(image)
    if model is not None and (img.shape[1], img.shape[0]) != tuple(model.size):
        raise ValueError(f"image is {img.shape[1]}x{img.shape[0]} but the camera model is for "
                         f"{model.size[0]}x{model.size[1]}")
    det = _detector(plate.board_cols, plate.board_rows, float(plate.square_mm), float(plate.marker_mm),
                    plate.aruco_dict)
    board = make_board(plate)
    corners: np.ndarray | None = None
    ids: np.ndarray | None = None
    if fast:
        m_corners, m_ids = _detect_markers(img, board)
        if len(m_ids):
            corners, ids = _detect_board(det, img, m_corners, m_ids)
        # OpenCV's board check rejects a marker set it finds inconsistent (no or few
        # corners from many markers): let OpenCV's own detector decide then
        fast = len(m_ids) == 0 or (ids is not None and len(ids) >= len(m_ids) // 2)
    if not fast:
        corners_cv, ids_cv = _detect_board(det, img)
        if ids_cv is not None and (ids is None or len(ids_cv) > len(ids)):
            corners, ids = corners_cv, ids_cv
    if ids is None or corners is None or len(ids) == 0:
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
        raise CalibrationError(f"only {len(ids)} ChArUco corner(s) found, need at least "
                               f"{max(min_corners, 4)}: is the target in view, lit and in focus?")
    board = make_board(plate)
    obj = np.asarray(board.getChessboardCorners(), dtype=np.float64)
    if ids.min() < 0 or ids.max() >= len(obj):
        raise ValueError(f"pose_from_corners: corner ids must be in 0..{len(obj) - 1}, "
                         f"got {ids.min()}..{ids.max()}")
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
