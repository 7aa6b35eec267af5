"""The intrinsic-calibration recipe: which board views the operator presents, and the view checks.

Zhang's method (IEEE TPAMI 22(11), 2000) needs views of a planar board at clearly
different orientations: a board seen square-on at one distance cannot tell the focal
length from the distance (the near-nadir plate views of the old procedure). The recipe
asks for tilts of 25-40° about *both* image axes, a rotated view, a near view and the
board in each image corner (the distortion is largest there). Each entry says what the
operator does in words; the numbers are the nominal pose the words describe (they are
never used by the calibration, only by the simulated operator in ``fakes/board.py``).

The pose convention: the board centre sits ``distance_mm`` in front of the lens (along
the optical axis) in the direction (``aim_x_deg``, ``aim_y_deg``) from the axis (x right,
y down in the image); the board is tilted by ``tilt_y_deg`` about the image y axis
(positive: its right edge comes towards the camera), then by ``tilt_x_deg`` about the
image x axis (positive: its top edge comes towards the camera), then turned by
``rot_deg`` in the image plane (positive: clockwise as seen in the image).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class ViewSpec:
    key: str
    tilt_x_deg: float = 0.0
    tilt_y_deg: float = 0.0
    rot_deg: float = 0.0
    aim_x_deg: float = 0.0
    aim_y_deg: float = 0.0
    distance_mm: float = 40.0

    def instruction(self) -> str:
        """The operator's instruction for this view, in words."""
        parts = [f"hold the board about {self.distance_mm:.0f} mm from the lens"]
        where = _where(self.aim_x_deg, self.aim_y_deg)
        parts.append(f"with its centre {where}")
        if self.rot_deg:
            sense = "clockwise" if self.rot_deg > 0 else "anticlockwise"
            parts.append(f"turned {abs(self.rot_deg):.0f}° {sense} in the image")
        if self.tilt_x_deg:
            parts.append(f"tilted ~{abs(self.tilt_x_deg):.0f}° about the image x axis (top edge "
                         f"{'towards' if self.tilt_x_deg > 0 else 'away from'} the camera)")
        if self.tilt_y_deg:
            parts.append(f"tilted ~{abs(self.tilt_y_deg):.0f}° about the image y axis (right edge "
                         f"{'towards' if self.tilt_y_deg > 0 else 'away from'} the camera)")
        if not (self.tilt_x_deg or self.tilt_y_deg):
            parts.append("square to the camera")
        return ", ".join(parts)


def _where(ax: float, ay: float) -> str:
    if not ax and not ay:
        return "in the middle of the image"
    v = "top" if ay < 0 else "bottom" if ay > 0 else ""
    h = "left" if ax < 0 else "right" if ax > 0 else ""
    return f"in the {'-'.join(w for w in (v, h) if w)} {'corner' if v and h else 'half'} of the image"


#: the recipe, in the order the procedure asks for the views
RECIPE: tuple[ViewSpec, ...] = (
    ViewSpec("flat"),
    ViewSpec("tilt-x+35", tilt_x_deg=35),
    ViewSpec("tilt-x-35", tilt_x_deg=-35),
    ViewSpec("tilt-y+35", tilt_y_deg=35),
    ViewSpec("tilt-y-35", tilt_y_deg=-35),
    ViewSpec("tilt-xy+25-rot45", tilt_x_deg=25, tilt_y_deg=25, rot_deg=45),
    ViewSpec("tilt-xy-25-rot30", tilt_x_deg=-25, tilt_y_deg=-25, rot_deg=-30),
    ViewSpec("top-left", tilt_x_deg=15, tilt_y_deg=-15, aim_x_deg=-27, aim_y_deg=-21),
    ViewSpec("top-right", tilt_x_deg=15, tilt_y_deg=15, aim_x_deg=27, aim_y_deg=-21),
    ViewSpec("bottom-left", tilt_x_deg=-15, tilt_y_deg=-15, aim_x_deg=-27, aim_y_deg=21),
    ViewSpec("bottom-right", tilt_x_deg=-15, tilt_y_deg=15, aim_x_deg=27, aim_y_deg=21),
    ViewSpec("near-rot90", tilt_x_deg=20, rot_deg=90, distance_mm=30),
)
SPECS = {s.key: s for s in RECIPE}

#: two views whose common corners moved less than this fraction of the image width
#: add (almost) nothing: the operator is asked to present that view again
SAME_VIEW_FRACTION = 0.03


def same_as(ids: np.ndarray, uv: np.ndarray, previous: list[tuple[np.ndarray, np.ndarray]],
            width: int) -> int | None:
    """Index of an earlier view this one repeats (same corners within 3 % of the width), else None."""
    for k, (ids0, uv0) in enumerate(previous):
        common, i, j = np.intersect1d(ids, ids0, return_indices=True)
        if len(common) < 0.5 * max(len(ids), 1):
            continue
        if float(np.median(np.linalg.norm(uv[i] - uv0[j], axis=1))) < SAME_VIEW_FRACTION * width:
            return k
    return None


#: a view counts as tilted from this angle between the board normal and the optical axis
MIN_TILT_DEG = 15.0
#: tilted views needed (Zhang: 3 views fix the 5 linear intrinsics; one spare)
MIN_TILTED_VIEWS = 4
#: smallest/largest eigenvalue of the tilt-axis scatter below which the tilts are about one axis
MIN_AXIS_SPREAD = 0.1
#: image corner regions (fraction of width and height from each corner) that need corners
CORNER_REGION = 0.2


def view_geometry(rvec: np.ndarray) -> tuple[float, np.ndarray]:
    """A view's tilt (degrees between the board normal and the optical axis) and its tilt
    axis in the image (a unit 2-vector, sign-free; zero when the board is square-on)."""
    n = cv2.Rodrigues(np.asarray(rvec, float).reshape(3))[0][:, 2]
    tilt = float(np.degrees(np.arccos(min(1.0, abs(n[2])))))
    axis = np.array([-n[1], n[0]])  # optical axis x board normal: the line the board turned about
    norm = float(np.linalg.norm(axis))
    return tilt, axis / norm if norm > 1e-9 else np.zeros(2)


def _axis_name(axis: np.ndarray) -> str:
    return "x" if abs(axis[0]) >= abs(axis[1]) else "y"


def tilt_findings(rvecs: list[np.ndarray]) -> list[str]:
    """What makes the views' orientations degenerate, each finding saying which view to add.

    They make the set degenerate for the focal length: no or too few tilted views
    (f trades off against the distance), or tilts about one image axis only (the
    focal length along the other axis is then not separated from the distance).
    """
    geo = [view_geometry(r) for r in rvecs]
    tilted = [(t, a) for t, a in geo if t >= MIN_TILT_DEG]
    largest = max((t for t, _ in geo), default=0.0)
    add_both = "add views tilted ~35° about the image x axis and about the image y axis (recipe views " \
               "tilt-x+35, tilt-y+35)"
    if not tilted:
        return [f"all views are near square-on (largest tilt {largest:.0f}° < {MIN_TILT_DEG:.0f}°): the "
                f"focal length cannot be told from the distance; {add_both}"]
    if len(tilted) < MIN_TILTED_VIEWS:
        return [f"only {len(tilted)} view(s) tilted by {MIN_TILT_DEG:.0f}° or more "
                f"(need {MIN_TILTED_VIEWS}): {add_both}"]
    S = sum(np.sin(np.radians(t)) ** 2 * np.outer(a, a) for t, a in tilted)
    lam, vec = np.linalg.eigh(S)
    if lam[0] < MIN_AXIS_SPREAD * lam[1]:
        about = _axis_name(vec[:, 1])
        other = "y" if about == "x" else "x"
        return [f"every tilted view is tilted about the image {about} axis: add views tilted ~35° about the "
                f"image {other} axis (recipe views tilt-{other}+35, tilt-{other}-35)"]
    return []


CORNERS = {"top-left": (0, 0), "top-right": (1, 0), "bottom-left": (0, 1), "bottom-right": (1, 1)}


def reaches_corner(uv: np.ndarray, size: tuple[int, int], corner: str) -> bool:
    """Does any board corner in ``uv`` lie within CORNER_REGION of the image's ``corner``?"""
    w, h = size
    fx, fy = CORNERS[corner]
    uv = np.asarray(uv, float).reshape(-1, 2)
    dx = np.abs(uv[:, 0] - fx * (w - 1)) <= CORNER_REGION * w
    dy = np.abs(uv[:, 1] - fy * (h - 1)) <= CORNER_REGION * h
    return bool(np.any(dx & dy))


def coverage_findings(uv_all: np.ndarray, size: tuple[int, int]) -> list[str]:
    """Warnings for image corners without board corners (the distortion is extrapolated there)."""
    return [f"no board corner within {100 * CORNER_REGION:.0f} % of the image's {name} corner: "
            f"the distortion there is extrapolated; add a view with the board in the {name} corner "
            f"(recipe view {name})"
            for name in CORNERS if not reaches_corner(uv_all, size, name)]
