"""Where the tracker stands: ``abs_H_trk``, the ACS pose of the tracker frame.

Set once per tracker station by whoever surveyed it: ``[tracker] abs_H_trk`` in the config,
else the station file an installer left in the data dir (``calibration/tracker_station.json``,
``{"abs_H_trk": 4x4 row-major, "source": text}``; the simulator's installer writes one for its
world), else identity (the tracker frame is the ACS). Read once at start: a new station needs a restart.
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

STATION_FILE = "calibration/tracker_station.json"
IDENTITY = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
_RIGID_TOL = 1e-6  # |RᵀR − I| and |det R − 1|: a surveyed pose written with full precision


class StationError(ValueError):
    """The station file or matrix is unusable; the message names the file and what is wrong."""


def _det3(r: list[list[float]]) -> float:
    return (r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1])
            - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
            + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]))


def checked(m: Any, where: str) -> list[list[float]]:
    """``m`` as a 4×4 rigid transform with det(R) = +1, else :class:`StationError` naming ``where``."""
    if not (isinstance(m, list) and len(m) == 4 and all(isinstance(r, list) and len(r) == 4 for r in m)):
        raise StationError(f"{where}: abs_H_trk must be a 4x4 matrix (list of 4 rows of 4), got {m!r}")
    if not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
               for r in m for v in r):
        raise StationError(f"{where}: abs_H_trk must hold finite numbers")
    h = [[float(v) for v in r] for r in m]
    rot = [r[:3] for r in h[:3]]
    gram = max(abs(sum(rot[k][i] * rot[k][j] for k in range(3)) - (i == j))
               for i in range(3) for j in range(3))
    if h[3] != [0.0, 0.0, 0.0, 1.0] or gram > _RIGID_TOL or abs(_det3(rot) - 1.0) > _RIGID_TOL:
        raise StationError(f"{where}: abs_H_trk is not a rigid transform with det(R) = +1 "
                           f"(|RᵀR − I| = {gram:.2g}, det R = {_det3(rot):.6f}, last row {h[3]})")
    return h


def abs_H_trk(configured: list[list[float]] | None, data_dir: Path) -> tuple[list[list[float]], str]:
    """The tracker's pose and where it came from (for the log)."""
    if configured is not None:
        return checked(configured, "config [tracker]"), "config [tracker] abs_H_trk"
    path = Path(data_dir) / STATION_FILE
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return [r[:] for r in IDENTITY], "identity (no [tracker] abs_H_trk, no station file)"
    except OSError as exc:
        raise StationError(f"{path}: cannot read the station file: {exc}") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise StationError(f"{path}: not valid JSON: {exc}") from None
    if not isinstance(data, dict) or "abs_H_trk" not in data:
        raise StationError(f"{path}: expected an object with abs_H_trk")
    said = data.get("source")  # who surveyed it, as the writer put it: shown wherever the pose is reported
    return checked(data["abs_H_trk"], str(path)), f"{path}" + (f" ({said})" if isinstance(said, str) else "")
