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
            parts.append(f"turned {abs(self.rot_deg):.0f}° {'clockwise' if self.rot_deg > 0 else 'anticlockwise'} "
                         f"in the image")
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
    ViewSpec("top-left", tilt_x_deg=-15, tilt_y_deg=15, aim_x_deg=-26, aim_y_deg=-20),
    ViewSpec("top-right", tilt_x_deg=-15, tilt_y_deg=-15, aim_x_deg=26, aim_y_deg=-20),
    ViewSpec("bottom-left", tilt_x_deg=15, tilt_y_deg=15, aim_x_deg=-26, aim_y_deg=20),
    ViewSpec("bottom-right", tilt_x_deg=15, tilt_y_deg=-15, aim_x_deg=26, aim_y_deg=20),
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


__all__ = ["RECIPE", "SAME_VIEW_FRACTION", "SPECS", "ViewSpec", "same_as"]
