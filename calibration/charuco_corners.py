"""ChArUco chessboard corners from detected markers, as OpenCV's ``CharucoDetector.detectBoard`` gives them.

With markers given and no camera matrix, OpenCV 5 interpolates each chessboard corner from
the local homographies of its two neighbouring markers, refines it with ``cornerSubPix``
in a window kept clear of the markers' corners, drops corners without both markers and
finally checks the whole board for consistency. It finds every marker by a linear search
of the id list, inside loops over corners and markers (its board check alone is ~10⁸
steps for 800 corners and 424 markers: as long as everything else in the detection). This
module does the same steps with OpenCV's own primitives (``getPerspectiveTransform``,
``perspectiveTransform``, ``cornerSubPix``) and the same single-precision arithmetic, with
indexed look-ups: the corners are OpenCV's, to the bit (the test suite compares them).
A board whose layout is not the one this relies on (two nearest markers per corner) is
left to OpenCV.

Steps as in OpenCV's ``charuco_detector.cpp`` (``interpolateCornersCharucoLocalHom``,
``getMaximumSubPixWindowSizes``, ``selectAndRefineChessboardCorners``,
``filterCornersWithoutMinMarkers``, ``checkBoard``).
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import cv2
import numpy as np

F32_MAX = np.float32(np.finfo(np.float32).max)


@dataclass(frozen=True)
class _Layout:
    """What the board says about its corners: PCS points and, per corner, its two nearest markers."""

    marker_xy: np.ndarray  # (M, 4, 2) float32, marker corners (PCS x, y)
    ids: np.ndarray  # (M,) marker id of each board marker
    corner_xy: np.ndarray  # (C, 2) float32, chessboard corners (PCS x, y)
    nearest: np.ndarray  # (C, 2) board marker index of the two nearest markers, ascending
    nearest_corner: np.ndarray  # (C, 2) which corner (0..3) of each of those markers is nearest
    uses: np.ndarray  # (2C,) flat (corner, slot) indices grouped by marker: marker b's are uses[at[b]:at[b + 1]]
    at: np.ndarray  # (M + 1,)


@lru_cache(maxsize=8)
def _layout(board: cv2.aruco.CharucoBoard) -> _Layout | None:
    """The board's corner neighbourhoods (OpenCV's ``calcNearestMarkerCorners``), or None when a
    corner has not exactly two nearest markers.

    OpenCV compares every corner with every marker centre; markers sit centred in squares, so
    the nearest ones are among the (at most four) markers of the squares around the corner,
    the next at 2.2 times their distance: only those are compared.
    """
    obj = np.array(board.getObjPoints(), np.float32).reshape(-1, 4, 3)
    chess = np.asarray(board.getChessboardCorners(), np.float32).reshape(-1, 3)
    square = board.getSquareLength()
    centre = obj.sum(axis=1, dtype=np.float32) / np.float32(4)
    cols, rows = board.getChessboardSize()
    grid = np.full((cols + 2, rows + 2), -1)
    cell = np.floor(centre[:, :2] / square).astype(int)
    if cell.min() < 0 or np.any(cell >= (cols, rows)):
        return None
    grid[cell[:, 0] + 1, cell[:, 1] + 1] = np.arange(len(obj))
    at = np.rint(chess[:, :2] / square).astype(int)  # corner (i, j) touches squares i-1..i, j-1..j
    cand = np.stack([grid[at[:, 0] + dx, at[:, 1] + dy] for dx in (0, 1) for dy in (0, 1)], axis=1)  # (C, 4)
    d = chess[:, None, :2] - centre[cand][..., :2]
    sq = np.where(cand >= 0, (d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]).astype(np.float64), np.inf)
    near = np.abs(sq - sq.min(axis=1, keepdims=True)) < (0.01 * square) ** 2
    if np.any(near.sum(axis=1) != 2):
        return None
    nearest = np.sort(cand[near].reshape(-1, 2), axis=1)  # OpenCV lists them by marker index
    dc = chess[:, None, None, :2] - obj[nearest][..., :2]
    corner = np.argmin(dc[..., 0] * dc[..., 0] + dc[..., 1] * dc[..., 1], axis=2)
    uses = np.argsort(nearest.ravel(), kind="stable")
    at = np.searchsorted(nearest.ravel()[uses], np.arange(len(obj) + 1))
    return _Layout(np.ascontiguousarray(obj[..., :2]), np.asarray(board.getIds()).ravel(),
                   np.ascontiguousarray(chess[:, :2]), nearest, corner, uses, at)


def _interpolate(lay: _Layout, corners: np.ndarray, found: np.ndarray) -> np.ndarray:
    """Each chessboard corner from the local homographies of its detected neighbours; (-1, -1) when none."""
    C = len(lay.corner_xy)
    pos = np.full((C, 2, 2), np.nan, np.float32)
    for b in np.flatnonzero(found >= 0).tolist():  # b: board marker index, found[b]: its detection
        H = cv2.getPerspectiveTransform(lay.marker_xy[b], corners[found[b]])
        if abs(cv2.determinant(H)) <= 1e-6:
            continue
        flat = lay.uses[lay.at[b]:lay.at[b + 1]]
        c, slot = flat // 2, flat % 2
        if len(c):
            pos[c, slot] = cv2.perspectiveTransform(lay.corner_xy[c].reshape(-1, 1, 2), H).reshape(-1, 2)
    have = ~np.isnan(pos[:, :, 0])
    out = np.full((C, 2), -1.0, np.float32)
    both = have.all(axis=1)
    out[both] = (pos[both, 0] + pos[both, 1]) * np.float32(0.5)  # OpenCV: (p0 + p1) / 2.
    for side in (0, 1):
        one = have[:, side] & ~both
        out[one] = pos[one, side]
    return out


def _window_sizes(lay: _Layout, corners: np.ndarray, found: np.ndarray, pos: np.ndarray, default: int) -> np.ndarray:
    """The refinement half-window of each corner: distance to the nearest marker corner − 2, within 1..10."""
    k = found[lay.nearest]  # (C, 2) detection index of each neighbour, -1 if not detected
    mc = corners[np.maximum(k, 0), lay.nearest_corner]  # (C, 2, 2) that marker's nearest corner
    d = (mc - pos[:, None, :]).astype(np.float64)  # Point2f difference, then cv::norm in double
    dist = np.where(k >= 0, np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]), np.inf)
    win = np.clip(np.trunc(dist.min(axis=1) - 2), 1, 10).astype(int)
    unset = (k < 0).all(axis=1) | ((pos[:, 0] == -1) & (pos[:, 1] == -1))
    win[unset] = default
    return win


def _refine(img: np.ndarray, pos: np.ndarray, win: np.ndarray, p: cv2.aruco.DetectorParameters) -> np.ndarray:
    """``cornerSubPix`` of each corner with its own window, one call per window size (corners are
    independent), the corners split over two threads (the calls release the GIL)."""
    crit = (cv2.TERM_CRITERIA_MAX_ITER | cv2.TERM_CRITERIA_EPS, p.cornerRefinementMaxIterations,
            p.cornerRefinementMinAccuracy)
    out = pos.copy()

    def refine(part: slice) -> None:
        for w in np.unique(win[part]).tolist():
            sel = np.flatnonzero(win[part] == w) + (part.start or 0)
            # zero zone Size() = (0, 0), as OpenCV's ChArUco detector passes it: the window's centre pixel ignored
            out[sel] = cv2.cornerSubPix(img, pos[sel].reshape(-1, 1, 2).copy(), (w, w), (0, 0), crit).reshape(-1, 2)
    half = len(pos) // 2
    with ThreadPoolExecutor(2) as pool:
        list(pool.map(refine, (slice(0, half), slice(half, len(pos)))))
    return out


def _board_ok(lay: _Layout, corners: np.ndarray, ids: np.ndarray, uv: np.ndarray, ch: np.ndarray) -> bool:
    """OpenCV's ``checkBoard``: each corner lies nearer its own two markers than any other marker's centre,
    and nearer their corner than the midpoints of that corner's edges."""
    on = np.isin(ids, lay.ids)
    corners, ids = corners[on], ids[on]
    near_ids = lay.ids[lay.nearest[ch]]  # (K, 2)
    is0, is1 = ids[None, :] == near_ids[:, :1], ids[None, :] == near_ids[:, 1:]  # (K, N)
    near = is0 | is1
    s = ((corners[:, 0] + corners[:, 1]) + corners[:, 2]) + corners[:, 3]
    centre = s / np.float32(4)

    def length(d: np.ndarray) -> np.ndarray:
        return np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1])
    far = np.where(near, F32_MAX, length(centre[None, :, :] - uv[:, None, :])).min(axis=1)
    k, j = np.nonzero(near)
    nc = np.where(is0[k, j], lay.nearest_corner[ch[k], 0], lay.nearest_corner[ch[k], 1])
    corner = corners[j, nc]
    to_near = length(corner - uv[k])
    mid1 = (corners[j, (nc + 1) % 4] + corner) * np.float32(0.5)
    mid2 = (corners[j, (nc + 3) % 4] + corner) * np.float32(0.5)
    if np.any(np.minimum(length(mid1 - uv[k]), length(mid2 - uv[k])) < to_near):
        return False
    own = np.zeros(len(uv), np.float32)
    np.maximum.at(own, k, to_near)
    return not np.any((own > 0) & (far < F32_MAX) & (own > far))


def detect_board(img: np.ndarray, board: cv2.aruco.CharucoBoard, detector: cv2.aruco.CharucoDetector,
                 marker_corners: list[np.ndarray], marker_ids: np.ndarray
                 ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """``detector.detectBoard(img, markerCorners=..., markerIds=...)``'s corners (K, 2) and ids (K,).

    ``detector`` must be for ``board`` and have no camera matrix; its parameters are used.
    (None, None) when no corner is found or the board check fails, as OpenCV returns.
    """
    lay = _layout(board)
    cp = detector.getCharucoParameters()
    camera: Any = cp.cameraMatrix  # None unless set, whatever the stub says
    if lay is None or camera is not None or img.ndim != 2 or not len(marker_ids):
        corners, ids, _, _ = detector.detectBoard(img, markerCorners=marker_corners, markerIds=marker_ids)
        return corners, ids
    corners = np.concatenate([np.asarray(c, np.float32).reshape(1, 4, 2) for c in marker_corners])
    mids = np.asarray(marker_ids).reshape(-1)
    found = np.full(len(lay.ids), -1)
    index = {int(m): b for b, m in enumerate(lay.ids.tolist())}
    for k in range(len(mids) - 1, -1, -1):  # the first detection of an id wins, as OpenCV's search
        b = index.get(int(mids[k]))
        if b is not None:
            found[b] = k
    p = detector.getDetectorParameters()
    pos = _interpolate(lay, corners, found)
    win = _window_sizes(lay, corners, found, pos, p.cornerRefinementWinSize)
    h, w = img.shape
    inside = (pos[:, 0] >= 2) & (pos[:, 0] < w - 2) & (pos[:, 1] >= 2) & (pos[:, 1] < h - 2)
    ch = np.flatnonzero(inside & ((found[lay.nearest] >= 0).sum(axis=1) >= cp.minMarkers))
    if not len(ch):
        return None, None
    uv = _refine(img, pos[ch], win[ch], p)
    if cp.checkMarkers and not _board_ok(lay, corners, mids, uv, ch):
        return None, None
    return uv, ch.astype(np.int32)


__all__ = ["detect_board"]
