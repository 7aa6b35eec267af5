"""Plate survey, image side: patch corners and coloured nest rings in one RGB photograph.

Rings: a chroma score per colour (that channel minus the larger of the other two, so
grey plate, black/white print and the dark seat all score ≈ 0) is thresholded at half
its peak; the largest blob is the ring. Its edges are located to sub-pixel precision
as the crossings of the score with the level halfway between the ring's and its
surroundings' median score (linear interpolation between neighbouring pixels); the
crossings are split into the outer and the inner edge. Both edges are symmetric about
the ring centre, so blur moves them in opposite directions and leaves the centre.
Ellipse fitting, distortion and the perspective bias of the centre are handled by
:mod:`calibration.plate_survey`, which knows the camera.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from calibration.errors import CalibrationError
from calibration.patches import Patch
from calibration.plate import NEST_NAMES

#: channel of each nest colour in an RGB image
CHANNEL = {"red": 0, "green": 1, "blue": 2}
#: a ring must stand out of the grey surroundings by this many DN of chroma score
MIN_RING_SCORE_DN = 25.0
MIN_RING_AREA_PX = 40
MIN_EDGE_POINTS = 20


@dataclass
class RingEdges:
    """Sub-pixel edge points (px) of one nest ring in one image."""

    colour: str
    outer: np.ndarray  # (N, 2)
    inner: np.ndarray  # (M, 2)


def check_rgb(image: np.ndarray, name: str) -> np.ndarray:
    """``image`` as float32 (h, w, 3) RGB, or a ValueError naming ``name``."""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] not in (3, 4) or img.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"{name}: need an 8- or 16-bit colour (RGB) image to tell the nest rings apart, got "
                         f"shape {img.shape} {img.dtype}")
    out = img[..., :3].astype(np.float32)
    return out / 257.0 if img.dtype == np.uint16 else out


def chroma_score(rgb: np.ndarray, colour: str) -> np.ndarray:
    c = CHANNEL[colour]
    others = [k for k in range(3) if k != c]
    return rgb[..., c] - np.maximum(rgb[..., others[0]], rgb[..., others[1]])


#: the kernel erode/dilate use when given none (spelled out: their stubs do not take None)
_KERNEL_3X3 = np.ones((3, 3), np.uint8)


def find_ring(rgb: np.ndarray, colour: str, name: str) -> RingEdges:
    """Edge points of the ``colour`` ring in ``rgb`` (float RGB); CalibrationError naming image and colour."""
    s = cv2.GaussianBlur(chroma_score(rgb, colour), (0, 0), 0.7)
    # opening with OpenCV's default 3x3 kernel: a single hot pixel is no ring
    peak = float(cv2.dilate(cv2.erode(s, _KERNEL_3X3), _KERNEL_3X3).max())
    if peak < MIN_RING_SCORE_DN:
        raise CalibrationError(f"{name}: no {colour} ring found (strongest {colour} chroma {peak:.0f} DN, "
                               f"need >= {MIN_RING_SCORE_DN:.0f})")
    n, lab, stats, _ = cv2.connectedComponentsWithStats((s > 0.5 * peak).astype(np.uint8), connectivity=8)
    k = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    x, y, w, h, area = stats[k]
    if area < MIN_RING_AREA_PX:
        raise CalibrationError(f"{name}: the {colour} blob has only {area} px (need >= {MIN_RING_AREA_PX})")
    pad = 4
    x0, y0 = max(0, x - pad), max(0, y - pad)
    x1, y1 = min(s.shape[1], x + w + pad), min(s.shape[0], y + h + pad)
    roi, mask = s[y0:y1, x0:x1], (lab[y0:y1, x0:x1] == k).astype(np.uint8)
    around = cv2.dilate(mask, np.ones((5, 5), np.uint8)) - mask
    ring_level = float(np.median(roi[mask > 0]))
    level = 0.5 * (ring_level + float(np.median(roi[around > 0])))
    pts = _crossings(roi, level, cv2.dilate(mask, np.ones((3, 3), np.uint8)) > 0) + [x0, y0]
    outer, inner = _split(pts, mask, (x0, y0))
    for what, p in (("outer", outer), ("inner", inner)):
        if len(p) < MIN_EDGE_POINTS:
            raise CalibrationError(f"{name}: the {colour} ring's {what} edge has only {len(p)} points "
                                   f"(need >= {MIN_EDGE_POINTS}): ring cut off, covered or too small")
    return RingEdges(colour, outer, inner)


def _crossings(s: np.ndarray, level: float, near: np.ndarray) -> np.ndarray:
    """Sub-pixel points (x, y) where ``s`` crosses ``level`` between 4-neighbours inside ``near``."""
    d = s - level
    out = []
    for axis in (1, 0):
        a = d[:, :-1] if axis == 1 else d[:-1, :]
        b = d[:, 1:] if axis == 1 else d[1:, :]
        ok = (np.sign(a) != np.sign(b)) & (near[:, :-1] if axis == 1 else near[:-1, :])
        r, c = np.nonzero(ok)
        t = a[r, c] / (a[r, c] - b[r, c])
        out.append(np.column_stack([c + t, r]) if axis == 1 else np.column_stack([c, r + t]))
    return np.vstack(out).astype(float)


def _split(pts: np.ndarray, mask: np.ndarray, offset: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Outer and inner edge points: the blob's outer contour, mapped to a unit circle, splits them."""
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    c = max(contours, key=len).reshape(-1, 2).astype(np.float32) + np.asarray(offset, np.float32)
    if len(c) < 5:
        return pts[:0], pts[:0]
    (cx, cy), (a, b), ang = cv2.fitEllipse(c)
    t = np.radians(ang)
    R = np.array([[np.cos(t), np.sin(t)], [-np.sin(t), np.cos(t)]])
    q = (pts - [cx, cy]) @ R.T / [a / 2, b / 2]
    rho = np.hypot(q[:, 0], q[:, 1])
    # the inner edge of a 9/14 mm ring sits near 0.64 of the outer one
    return pts[rho > 0.82], pts[(rho < 0.82) & (rho > 0.3)]


def find_rings(rgb: np.ndarray, name: str) -> tuple[dict[str, RingEdges], dict[str, str]]:
    """Every ring found in one image, and for each one not found the reason."""
    found, missing = {}, {}
    for colour in NEST_NAMES:
        try:
            found[colour] = find_ring(rgb, colour, name)
        except CalibrationError as exc:
            missing[colour] = str(exc)
    return found, missing


def detect_patch_corners(grey: np.ndarray, patches: list[Patch], aruco_dict: str
                         ) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """Inner corners of every patch in view: (ref_P (N, 3) in PCS, uv (N, 2), corners per patch)."""
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, aruco_dict))
    m_corners, found_ids, _ = cv2.aruco.ArucoDetector(dictionary).detectMarkers(grey)
    m_ids: np.ndarray | None = found_ids  # None when no marker is found (the stub says an array, always)
    ref_P, uv, count = [], [], {}
    if m_ids is None:
        return np.zeros((0, 3)), np.zeros((0, 2)), {p.name: 0 for p in patches}
    m_ids = m_ids.reshape(-1)
    for p in patches:
        sel = np.flatnonzero((m_ids >= p.first_id) & (m_ids < p.first_id + p.n_markers))
        count[p.name] = 0
        if len(sel) < 2:
            continue
        det = cv2.aruco.CharucoDetector(p.board(aruco_dict))
        ch_c, found_ch, _, _ = det.detectBoard(grey, markerCorners=[m_corners[int(i)] for i in sel],
                                               markerIds=m_ids[sel].reshape(-1, 1))
        ch_ids: np.ndarray | None = found_ch  # None when no corner is found (the stub says an array, always)
        if ch_ids is None or len(ch_ids) == 0:
            continue
        ids = ch_ids.reshape(-1)
        ref_P.append(p.corners_ref(aruco_dict)[ids])
        uv.append(ch_c.reshape(-1, 2).astype(float))
        count[p.name] = len(ids)
    if not ref_P:
        return np.zeros((0, 3)), np.zeros((0, 2)), count
    return np.vstack(ref_P), np.vstack(uv), count
