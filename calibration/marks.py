"""Sub-pixel localisation of floor marks in the original (distorted) image.

Two mark kinds (localisation accuracy: docs/accuracy.md, "Image side"):

* ``dot``: a dark disc on a lighter floor. Normalised cross-correlation
  (``TM_CCOEFF_NORMED``, robust to gain and offset) with a disc template rendered
  at a known centre, then a 3-point parabola through the peak in x and in y.
* ``cross`` (alias ``checker``): a checker X-junction. A saddle search (most negative
  Hessian determinant of the smoothed image) gives the start point, ``cornerSubPix``
  the sub-pixel position. The saddle is rotation invariant, so the mark's
  orientation in the image does not matter.

Without ``approx_uv`` the whole image is searched coarse to fine: the image is
box-averaged by an integer factor so the mark is ~3 px, the same detector runs there,
and its best few peaks are refined by the full-resolution detector in a window each
(the best score wins). Inside a window the full-resolution scores are the ones a
whole-image search computes, so the result is the same, in a fraction of the time
(docs/benchmarks.md, "Calibration and vision").

Localise here, then map the point analytically with :meth:`calibration.scs.Scs.image_to_scn`;
never measure in a rectified image.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from calibration.errors import CalibrationError

#: minimum normalised correlation for a dot to count as found
MIN_DOT_SCORE = 0.6
KINDS = ("dot", "cross", "checker")
#: coarse search: mark size (dot radius / cross half-size) in the shrunk image, the
#: largest shrink factor, and how many coarse peaks are refined at full resolution
COARSE_SIZE_PX, MAX_COARSE_FACTOR, COARSE_CANDIDATES = 3.0, 8, 3


@dataclass
class MarkObservation:
    """A located mark: pixel position (column, row), a quality score in [0, 1], the method used."""

    uv: np.ndarray
    score: float
    method: str


def _check_image(image: np.ndarray) -> np.ndarray:
    img = np.asarray(image)
    if img.ndim != 2:
        raise ValueError(f"image: expected a 2-D grey image, got shape {img.shape}")
    if img.dtype != np.uint8:
        raise ValueError(f"image: expected dtype uint8, got {img.dtype}")
    return img


def _roi(shape: tuple[int, ...], approx_uv: np.ndarray | None, half: int) -> tuple[int, int, int, int]:
    """Clipped (x0, y0, x1, y1) window of half-size ``half`` around ``approx_uv`` (or the whole image)."""
    h, w = shape[:2]
    if approx_uv is None:
        return 0, 0, w, h
    u, v = np.asarray(approx_uv, dtype=float).reshape(2)
    if not (0 <= u < w and 0 <= v < h):
        raise ValueError(f"approx_uv={u:.1f},{v:.1f} is outside the {w}x{h} image")
    x0, y0 = max(0, int(u) - half), max(0, int(v) - half)
    return x0, y0, min(w, int(u) + half + 1), min(h, int(v) + half + 1)


def _estimate_dot_radius(patch: np.ndarray) -> float:
    """Radius (px) of the largest dark blob in ``patch`` (Otsu threshold)."""
    _, mask = cv2.threshold(patch, 0, 255, cv2.THRESH_BINARY_INV | cv2.THRESH_OTSU)
    n, _, stats, _ = cv2.connectedComponentsWithStats(mask)
    if n < 2:
        raise CalibrationError("no dark blob found for the dot mark (give size_px or approx_uv)")
    area = stats[1:, cv2.CC_STAT_AREA].max()
    return math.sqrt(area / math.pi)


@lru_cache(maxsize=16)
def dot_template(radius_px: float, blur_px: float = 1.0, ss: int = 8) -> np.ndarray:
    """A float32 template: dark disc (0) of ``radius_px`` on white (1), centred on its middle pixel.

    Cached (supersampling a disc costs more than a search) and therefore read-only.
    """
    half = int(math.ceil(1.6 * radius_px + 2 * blur_px)) + 1
    n = 2 * half + 1
    t = (np.arange(n * ss) + 0.5) / ss - 0.5 - half  # sub-sample offsets from the centre pixel
    r = np.hypot(t[None, :], t[:, None])
    disc = (r > radius_px).astype(np.float32).reshape(n, ss, n, ss).mean(axis=(1, 3))
    out = cv2.GaussianBlur(disc, (0, 0), blur_px) if blur_px > 0 else disc
    out.flags.writeable = False
    return out


def _parabola_offset(a: float, b: float, c: float) -> float:
    """Vertex offset of the parabola through (−1, a), (0, b), (1, c)."""
    den = a - 2 * b + c
    return 0.0 if den >= 0 else 0.5 * (a - c) / den


def _locate_dot(img: np.ndarray, approx_uv: np.ndarray | None, size_px: float | None,
                reach_px: int | None = None) -> MarkObservation:
    """Best template match within ``reach_px`` of ``approx_uv`` (default 3 radii), or in the whole image."""
    if size_px is None:
        x0, y0, x1, y1 = _roi(img.shape, approx_uv, 60)
        size_px = _estimate_dot_radius(img[y0:y1, x0:x1])
    if not 1.5 <= size_px <= 500:
        raise ValueError(f"size_px={size_px} is not a usable dot radius (1.5..500 px)")
    tmpl = dot_template(float(size_px))
    half = tmpl.shape[0] // 2
    reach = int(3 * size_px) + half if reach_px is None else reach_px
    x0, y0, x1, y1 = _roi(img.shape, approx_uv, reach + half)
    patch = img[y0:y1, x0:x1].astype(np.float32)
    if patch.shape[0] < tmpl.shape[0] + 2 or patch.shape[1] < tmpl.shape[1] + 2:
        raise CalibrationError(f"dot search window {patch.shape[1]}x{patch.shape[0]} px is smaller than the "
                               f"template ({tmpl.shape[0]} px): the mark is too close to the image border")
    res = cv2.matchTemplate(patch, tmpl, cv2.TM_CCOEFF_NORMED)
    _, score, _, (px, py) = cv2.minMaxLoc(res)
    if score < MIN_DOT_SCORE:
        raise CalibrationError(f"no dot found: best correlation {score:.2f} < {MIN_DOT_SCORE} "
                               f"(radius {size_px:.1f} px)")
    if not (0 < px < res.shape[1] - 1 and 0 < py < res.shape[0] - 1):
        raise CalibrationError(f"dot found only at the edge of the search window (score {score:.2f}); "
                               f"it is cut by the image border or approx_uv is off")
    dx = _parabola_offset(res[py, px - 1], res[py, px], res[py, px + 1])
    dy = _parabola_offset(res[py - 1, px], res[py, px], res[py + 1, px])
    uv = np.array([x0 + px + half + dx, y0 + py + half + dy])
    return MarkObservation(uv, float(score), "template-ncc+parabola")


def _hessian_det(patch: np.ndarray, scale_px: float) -> np.ndarray:
    """Hessian determinant of the smoothed ``patch``: strongly negative at saddles."""
    g = cv2.GaussianBlur(patch.astype(np.float32), (0, 0), max(1.0, scale_px / 3))
    gxx = cv2.Sobel(g, cv2.CV_32F, 2, 0, ksize=3)
    gyy = cv2.Sobel(g, cv2.CV_32F, 0, 2, ksize=3)
    gxy = cv2.Sobel(g, cv2.CV_32F, 1, 1, ksize=3)
    return gxx * gyy - gxy * gxy


def _saddle_start(patch: np.ndarray, scale_px: float) -> tuple[np.ndarray, float]:
    """Most saddle-like point of ``patch`` (most negative Hessian determinant) and its strength."""
    det = _hessian_det(patch, scale_px)
    _, _, (mx, my), _ = cv2.minMaxLoc(det)
    return np.array([mx, my], float), float(-det[my, mx])


def _locate_cross(img: np.ndarray, approx_uv: np.ndarray | None, size_px: float | None) -> MarkObservation:
    size = 8.0 if size_px is None else float(size_px)
    if not 3 <= size <= 500:
        raise ValueError(f"size_px={size_px} is not a usable cross half-size (3..500 px)")
    x0, y0, x1, y1 = _roi(img.shape, approx_uv, int(2 * size) + 8)
    patch = img[y0:y1, x0:x1]
    start, strength = _saddle_start(patch, size)
    contrast = float(np.percentile(patch, 95) - np.percentile(patch, 5))
    if contrast < 20 or strength <= 0:
        raise CalibrationError(f"no cross found: contrast {contrast:.0f} DN, saddle strength {strength:.3g}")
    win = int(max(2, min(size * 0.6, 15)))
    pts = (start + [x0, y0]).astype(np.float32).reshape(1, 1, 2)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
    refined = cv2.cornerSubPix(img, pts, (win, win), (-1, -1), crit).reshape(2).astype(float)
    off = np.linalg.norm(refined - pts.reshape(2))
    if off > win:
        raise CalibrationError(f"cross refinement ran off by {off:.1f} px")
    # score: strength of the two-cycle (X-junction) pattern on a circle around the point,
    # relative to an ideal checker of the same contrast; independent of the mark's rotation
    r = max(2.0, min(size * 0.6, 15.0))
    th = np.linspace(0, 2 * np.pi, 32, endpoint=False)
    # sample a small float patch only: converting a 12 MP image costs tens of ms
    bx, by = max(0, int(refined[0] - r) - 2), max(0, int(refined[1] - r) - 2)
    around = img[by:int(refined[1] + r) + 3, bx:int(refined[0] + r) + 3].astype(np.float32)
    mu = (refined[0] - bx + r * np.cos(th)).astype(np.float32).reshape(1, -1)
    mv = (refined[1] - by + r * np.sin(th)).astype(np.float32).reshape(1, -1)
    ring = cv2.remap(around, mu, mv, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).ravel()
    c2 = abs(np.mean(ring * np.exp(-2j * th)))
    score = float(min(1.0, c2 * np.pi / max(contrast, 1.0)))
    return MarkObservation(refined, score, "saddle+cornerSubPix")


def _coarse_candidates(img: np.ndarray, kind: str, size_px: float, f: int) -> list[np.ndarray]:
    """Full-image pixel positions of the best few mark-like peaks in ``img`` shrunk by ``f``."""
    h, w = img.shape
    # an exact f×f box average (crop to a multiple of f): coarse pixel i covers
    # full pixels f·i .. f·i + f − 1, centre f·i + (f − 1)/2
    small = cv2.resize(img[:h // f * f, :w // f * f], (w // f, h // f), interpolation=cv2.INTER_AREA)
    s = size_px / f
    if kind == "dot":
        tmpl = dot_template(s)
        half = tmpl.shape[0] // 2
        if min(small.shape) <= half:
            return []
        # mirror the borders: the coarse template is f× wider than the full-resolution
        # one, and a dot the full-resolution search can reach must stay reachable here
        padded = cv2.copyMakeBorder(small, half, half, half, half, cv2.BORDER_REFLECT_101)
        score = cv2.matchTemplate(padded.astype(np.float32), tmpl, cv2.TM_CCOEFF_NORMED)
    else:
        score = -_hessian_det(small, s)
    # local maxima at least a mark size apart, best first
    r = max(1, int(round(s)))
    peak = score >= cv2.dilate(score, np.ones((2 * r + 1, 2 * r + 1), np.uint8))
    ys, xs = np.nonzero(peak)
    best = np.argsort(score[ys, xs])[::-1][:COARSE_CANDIDATES]
    return [np.clip((np.array([xs[i], ys[i]], float) + 0.5) * f - 0.5, 0, [w - 1, h - 1]) for i in best]


def _coarse_to_fine(img: np.ndarray, kind: str, size_px: float, f: int) -> MarkObservation:
    """Whole-image search: coarse peaks, each refined at full resolution; the best score wins."""
    found: list[MarkObservation] = []
    why: list[str] = []
    for uv in _coarse_candidates(img, kind, size_px, f):
        try:
            # a coarse peak is within a coarse pixel (f px) of the full-resolution one
            found.append(_locate_dot(img, uv, size_px, reach_px=2 * f + 2) if kind == "dot"
                         else _locate_cross(img, uv, size_px))
        except CalibrationError as exc:
            why.append(f"near ({uv[0]:.0f}, {uv[1]:.0f}): {exc}")
    if found:
        return max(found, key=lambda o: o.score)
    if why:
        raise CalibrationError(f"no {kind} found in the whole image; the best candidate {why[0]}")
    raise CalibrationError(f"no {kind} found: the image is too small for a {size_px:.1f} px mark")


def locate_mark(image: np.ndarray, kind: str = "dot", approx_uv: np.ndarray | None = None,
                size_px: float | None = None, coarse_to_fine: bool = True) -> MarkObservation:
    """Locate one mark in ``image``; ``size_px`` is the dot radius or the cross half-size in pixels.

    Without ``approx_uv`` the whole image is searched, coarse to fine when ``size_px``
    is given and ``coarse_to_fine`` (``False``: at full resolution, the reference).
    Raises CalibrationError when no mark of that kind is found, ValueError on bad arguments.
    """
    img = _check_image(image)
    if kind not in KINDS:
        raise ValueError(f"kind={kind!r}: expected one of {KINDS}")
    if approx_uv is None and size_px is not None and coarse_to_fine:
        lo, hi = (1.5, 500) if kind == "dot" else (3, 500)
        if not lo <= size_px <= hi:
            raise ValueError(f"size_px={size_px} is not a usable {kind} size ({lo}..{hi} px)")
        f = int(min(MAX_COARSE_FACTOR, max(1.0, size_px // COARSE_SIZE_PX)))
        if f > 1:
            return _coarse_to_fine(img, kind, size_px, f)
    if kind == "dot":
        return _locate_dot(img, approx_uv, size_px)
    return _locate_cross(img, approx_uv, size_px)
