"""Square marker candidates as OpenCV's ArUco detector finds them, without its quadratic grouping.

:func:`calibration.target._detect_markers` reads every candidate's bits itself; from
OpenCV it needs only the candidates (``ArucoDetector.detectMarkers`` with a one-marker
dictionary returns them all). OpenCV 5 finds them by adaptive thresholding at several
window sizes, contours and a polygon fit, then groups candidates closer than an eighth of
their perimeter by comparing *every pair* (~7 million pairs for a 4024×3036 plate image
reduced to 1341 px, about half the detection time). This module does the same steps with
OpenCV's own primitives and the same single-precision arithmetic, but compares only pairs
whose centres are near enough to pass: the candidates are identical (the test suite
checks them against OpenCV's on rendered images).

Steps as in OpenCV's ``aruco_detector.cpp`` (``_detectInitialCandidates``,
``_reorderCandidatesCorners``, ``filterTooCloseCandidates``), for a detector without
corner refinement or the ArUco3 pyramid.
"""
from __future__ import annotations

import cv2
import numpy as np


def _scale_candidates(grey: np.ndarray, win: int, p: cv2.aruco.DetectorParameters) -> np.ndarray:
    """Convex quadrilaterals (n, 4, 2) of one adaptive-threshold window size, in contour order."""
    win += 1 - win % 2  # OpenCV makes the window odd
    thresh = cv2.adaptiveThreshold(grey, 255, cv2.ADAPTIVE_THRESH_MEAN_C, cv2.THRESH_BINARY_INV, win,
                                   p.adaptiveThreshConstant)
    contours, _ = cv2.findContours(thresh, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    side = max(grey.shape)
    lo, hi = int(p.minMarkerPerimeterRate * side), int(p.maxMarkerPerimeterRate * side)
    sizes = np.fromiter(map(len, contours), int, len(contours))
    quads, lengths = [], []
    for k in np.flatnonzero((sizes >= lo) & (sizes <= hi)).tolist():
        q = cv2.approxPolyDP(contours[k], float(sizes[k]) * p.polygonalApproxAccuracyRate, True)
        if len(q) == 4 and cv2.isContourConvex(q):
            quads.append(q)
            lengths.append(sizes[k])
    if not quads:
        return np.zeros((0, 4, 2), np.float32)
    q = np.array(quads, np.float64).reshape(-1, 4, 2)
    d2 = np.sum((q - np.roll(q, -1, axis=1)) ** 2, axis=2).min(axis=1)
    return q[d2 >= (np.array(lengths, np.float64) * p.minCornerDistanceRate) ** 2].astype(np.float32)


def _clockwise(q: np.ndarray) -> np.ndarray:
    """Corners in clockwise image order (OpenCV swaps the 2nd and 4th of a counter-clockwise quad)."""
    d1, d2 = q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]
    ccw = d1[:, 0].astype(np.float64) * d2[:, 1] - d1[:, 1].astype(np.float64) * d2[:, 0] < 0
    q = q.copy()
    q[ccw, 1], q[ccw, 3] = q[ccw, 3], q[ccw, 1].copy()
    return q


def _sq(d: np.ndarray) -> np.ndarray:
    """|d|² in single precision, x² + y² in OpenCV's order."""
    return d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]


def _near_pairs(centre: np.ndarray, radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i < j) whose centres are closer than ``radius[i]``, found through a grid of cells
    as large as the largest radius (a pair can only be in the same or a neighbouring cell)."""
    if len(centre) < 2:
        return np.zeros(0, int), np.zeros(0, int)
    cell = np.floor(centre / max(float(radius.max()), 1e-9)).astype(np.int64)
    cell -= cell.min(axis=0) - 1
    rows = int(cell[:, 1].max()) + 2
    key = cell[:, 0] * rows + cell[:, 1]
    order = np.argsort(key, kind="stable")
    sorted_key = key[order]
    pi, pj = [], []
    for dx, dy in ((0, 0), (0, 1), (1, -1), (1, 0), (1, 1)):  # each pair of cells once
        want = key + dx * rows + dy
        start = np.searchsorted(sorted_key, want, "left")
        count = np.searchsorted(sorted_key, want, "right") - start
        a = np.repeat(np.arange(len(key)), count)
        offset = np.arange(len(a)) - np.repeat(np.cumsum(count) - count, count)
        b = order[start[a] + offset]
        keep = a < b if (dx, dy) == (0, 0) else slice(None)
        pi.append(np.minimum(a, b)[keep])
        pj.append(np.maximum(a, b)[keep])
    i, j = np.concatenate(pi), np.concatenate(pj)
    ok = np.hypot(*(centre[i] - centre[j]).T) < radius[i]
    return i[ok], j[ok]


def _groups(n: int, close_i: np.ndarray, close_j: np.ndarray) -> np.ndarray:
    """Group number of each candidate, assigned in OpenCV's pair order (i, then j, ascending).

    A pair joins the group one of them has; two candidates already grouped stay where they
    are (OpenCV does not merge groups). A candidate without a close pair is a group alone.
    """
    group = [-1] * n
    count = 0
    for k in np.lexsort((close_j, close_i)).tolist():
        i, j = int(close_i[k]), int(close_j[k])
        gi, gj = group[i], group[j]
        if gi < 0 and gj < 0:
            group[i] = group[j] = count
            count += 1
        elif gj < 0:
            group[j] = gi
        elif gi < 0:
            group[i] = gj
    out = np.array(group)
    alone = out < 0
    out[alone] = count + np.arange(int(alone.sum()))
    return out


def find_candidates(grey: np.ndarray, p: cv2.aruco.DetectorParameters | None = None) -> np.ndarray:
    """All square candidates OpenCV's ``detectMarkers`` would examine: (N, 4, 2) float32, clockwise.

    The order is OpenCV's: by perimeter, largest first; of each group of nearly coinciding
    candidates only the largest, and none within ``minDistanceToBorder`` of the edge.
    """
    p = p or cv2.aruco.DetectorParameters()
    wins = range(p.adaptiveThreshWinSizeMin, p.adaptiveThreshWinSizeMax + 1, p.adaptiveThreshWinSizeStep)
    q = np.concatenate([_scale_candidates(grey, w, p) for w in wins])
    if not len(q):
        return q
    q = _clockwise(q)
    sides = np.sqrt(_sq(q - np.roll(q, -1, axis=1)))
    perim = ((sides[:, 0] + sides[:, 1]) + sides[:, 2]) + sides[:, 3]
    order = np.argsort(-perim, kind="stable")  # std::stable_sort, largest first
    q, perim = q[order], perim[order]
    rate = np.float32(p.minMarkerDistanceRate)
    # the mean corner distance is at least the centre distance: farther centres cannot group
    i, j = _near_pairs(q.mean(axis=1, dtype=np.float64), perim.astype(np.float64) * float(rate) * 1.01 + 1.0)
    best = np.full(len(i), np.inf, np.float32)
    for fc in range(4):  # OpenCV's getAverageDistance: the best of the four corner correspondences
        d = np.zeros(len(i), np.float32)  # 0 + x is x exactly: the same float32 sums as OpenCV's
        for c in range(4):
            d = d + _sq(q[i, (c + fc) % 4] - q[j, c])
        best = np.minimum(best, d)
    close = np.sqrt(best * np.float32(0.25)) < perim[j] * rate if len(i) else np.zeros(0, bool)
    group = _groups(len(q), i[close], j[close])
    first = np.unique(group, return_index=True)[1]  # the lowest index (largest candidate) of each group
    h, w = grey.shape[:2]
    b = p.minDistanceToBorder
    cq = q[first]
    inside = np.all((cq[..., 0] >= b) & (cq[..., 1] >= b) & (cq[..., 0] <= w - 1 - b) & (cq[..., 1] <= h - 1 - b),
                    axis=1)
    return q[np.sort(first[inside])]


__all__ = ["find_candidates"]
