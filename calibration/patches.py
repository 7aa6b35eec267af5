"""Survey patches: small ChArUco boards printed on the plate next to each nest.

The plate's main target (80×60 mm, 2 mm squares) is made for the robot's nadir camera
at ~50 mm; a camera that sees the whole plate (nests 400 mm apart) from ~1 m cannot
read its 1.5 mm markers, and a pose from a target that covers a few percent of the
image is a long lever to nests 230 mm away (docs/operations.md, "Plate survey"). The
survey therefore uses larger patches near each nest, with marker ids that follow
the main board's, so one dictionary identifies every board without ambiguity.

A patch is an OpenCV ChArUco board whose frame (origin at its outer corner, axes
along its columns and rows, z into the plate) is the PCS shifted by ``origin_mm``:
``ref_P = patch_P + (origin_x, origin_y, 0)``. The patches are part of the same print
as the main target, so their placement in PCS is a design value like the squares'.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from functools import lru_cache
from typing import Any

import cv2
import numpy as np


@dataclass(frozen=True)
class Patch:
    """One survey patch (mm, PCS-aligned)."""

    name: str
    cols: int
    rows: int
    square_mm: float
    marker_mm: float
    first_id: int  # marker ids first_id .. first_id + n_markers − 1
    origin_mm: tuple[float, float]  # the patch's outer corner in PCS xy

    @property
    def n_markers(self) -> int:
        return (self.cols * self.rows) // 2

    def board(self, aruco_dict: str) -> cv2.aruco.CharucoBoard:
        """The OpenCV board (cached)."""
        return _patch_board(self.cols, self.rows, float(self.square_mm), float(self.marker_mm), aruco_dict,
                            int(self.first_id))

    def corners_ref(self, aruco_dict: str) -> np.ndarray:
        """Inner chessboard corners in PCS (N, 3), in OpenCV's corner-id order."""
        P = np.asarray(self.board(aruco_dict).getChessboardCorners(), dtype=float).copy()
        P[:, 0] += self.origin_mm[0]
        P[:, 1] += self.origin_mm[1]
        return P

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["origin_mm"] = list(self.origin_mm)
        return d


@lru_cache(maxsize=16)
def _patch_board(cols: int, rows: int, square: float, marker: float, dict_name: str,
                 first_id: int) -> cv2.aruco.CharucoBoard:
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dict_name))
    ids = np.arange(first_id, first_id + (cols * rows) // 2, dtype=np.int32)
    return cv2.aruco.CharucoBoard((cols, rows), square, marker, dictionary, ids)


def dictionary_size(dict_name: str) -> int:
    """Number of markers in an OpenCV predefined dictionary (ValueError for an unknown name)."""
    code = getattr(cv2.aruco, dict_name, None) if dict_name.startswith("DICT_") else None
    if not isinstance(code, int):
        raise ValueError(f"aruco_dict {dict_name!r} is not an OpenCV predefined dictionary")
    return int(cv2.aruco.getPredefinedDictionary(code).bytesList.shape[0])


_KEYS: dict[str, type | tuple[type, ...]] = {"name": str, "cols": int, "rows": int, "square_mm": (int, float),
                                             "marker_mm": (int, float), "first_id": int, "origin_mm": list}


def _patch(d: Any, where: str) -> Patch:
    if not isinstance(d, dict):
        raise ValueError(f"{where} must be a JSON object, got {d!r}")
    missing = [k for k in _KEYS if k not in d]
    unknown = sorted(set(d) - set(_KEYS))
    if missing or unknown:
        raise ValueError(f"{where}: missing key(s) {missing} / unknown key(s) {unknown}")
    for k, kind in _KEYS.items():
        v = d[k]
        if isinstance(v, bool) or not isinstance(v, kind):
            raise ValueError(f"{where}.{k} has the wrong type: {v!r}")
    o = d["origin_mm"]
    if len(o) != 2 or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)
                              for v in o):
        raise ValueError(f"{where}.origin_mm must be 2 finite numbers [x, y] in mm, got {o!r}")
    p = Patch(d["name"], d["cols"], d["rows"], float(d["square_mm"]), float(d["marker_mm"]), d["first_id"],
              (float(o[0]), float(o[1])))
    if p.cols < 3 or p.rows < 3 or not 0 < p.marker_mm < p.square_mm or not 1 <= p.square_mm <= 100:
        raise ValueError(f"{where} ({p.name}): board {p.cols}x{p.rows}, square {p.square_mm} mm, "
                         f"marker {p.marker_mm} mm is not a usable ChArUco patch "
                         f"(>= 3x3, 1..100 mm, marker < square)")
    return p


def parse_patches(items: Any, main_markers: int, aruco_dict: str, source: str) -> list[Patch]:
    """Validated patches; marker ids must not overlap the main board's (0..main_markers−1) or each other."""
    if not isinstance(items, list):
        raise ValueError(f"{source}: patches must be a JSON list, got {items!r}")
    out = [_patch(d, f"{source}: patches[{i}]") for i, d in enumerate(items)]
    size = dictionary_size(aruco_dict)
    spans = [(0, main_markers, "the main board")]
    spans += [(p.first_id, p.first_id + p.n_markers, p.name) for p in out]
    for i, (a0, a1, na) in enumerate(spans):
        if a1 > size or a0 < 0:
            raise ValueError(f"{source}: marker ids {a0}..{a1 - 1} of {na} are outside {aruco_dict} "
                             f"(0..{size - 1})")
        for b0, b1, nb in spans[i + 1:]:
            if a0 < b1 and b0 < a1:
                raise ValueError(f"{source}: marker ids of {na} ({a0}..{a1 - 1}) and "
                                 f"{nb} ({b0}..{b1 - 1}) overlap")
    if len({p.name for p in out}) != len(out):
        raise ValueError(f"{source}: patch names must be unique, got {[p.name for p in out]}")
    return out


def default_patches(nests_xy: dict[str, Any], centre_xy: Any, first_id: int, distance_mm: float = 90.0,
                    cols: int = 7, rows: int = 5, square_mm: float = 15.0,
                    marker_mm: float = 11.0) -> list[Patch]:
    """One patch per nest, centred ``distance_mm`` from it toward ``centre_xy`` (docs/operations.md)."""
    out, fid = [], first_id
    c = np.asarray(centre_xy, dtype=float)[:2]
    for name, xy in nests_xy.items():
        n = np.asarray(xy, dtype=float)[:2]
        u = (c - n) / np.linalg.norm(c - n)
        mid = n + distance_mm * u
        origin = mid - 0.5 * np.array([cols * square_mm, rows * square_mm])
        out.append(Patch(f"near-{name}", cols, rows, square_mm, marker_mm, fid,
                         (round(float(origin[0]), 3), round(float(origin[1]), 3))))
        fid += (cols * rows) // 2
    return out
