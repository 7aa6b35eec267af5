"""Offline recompute: the stored observations of a dataset → the same result as the live run."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from calibration.worker.compute import COMPUTE

#: result fields that are numbers computed from the observations (compared on recompute)
COMPARED = ("rob_H_cam", "rob_H_scn")


def _load(root: Path):
    import cv2

    def load(file: str) -> np.ndarray:
        img = cv2.imread(str(root / file), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise FileNotFoundError(f"{root / file}: missing or unreadable image")
        return img

    return load


def _max_diff(a: Any, b: Any) -> float:
    if isinstance(a, dict) and isinstance(b, dict):
        return max([_max_diff(a[k], b[k]) for k in a.keys() & b.keys()] or [0.0])
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)) and len(a) == len(b):
        return max([_max_diff(x, y) for x, y in zip(a, b)] or [0.0])
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return abs(float(a) - float(b))
    return 0.0


def recompute(root: Path) -> tuple[dict[str, Any], float | None]:
    """Return (result, largest numeric difference to the stored result.json or None)."""
    root = Path(root)
    state = json.loads((root / "state.json").read_text())
    proc = state["procedure"]
    if proc not in COMPUTE:
        raise ValueError(f"{root}: unknown procedure {proc!r}")
    result = COMPUTE[proc](state["obs"], _load(root))
    result["job"] = state["job"]
    diff = None
    stored_path = root / "result.json"
    if stored_path.exists():
        stored = json.loads(stored_path.read_text())
        keys = [k for k in ("rob_H_cam", "rob_H_scn", "mark", "marks", "metrics", "camera_model") if k in result]
        diff = max([_max_diff(result[k], stored.get(k)) for k in keys] or [0.0])
    return result, diff
