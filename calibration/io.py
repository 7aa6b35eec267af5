"""The calibration's only file I/O: reading plate and camera-model files (JSON, OpenCV FileStorage YAML).

Everything else in ``calibration/`` works on arrays and dicts. It writes no files: callers
serialise with ``to_dict()`` and write through the project's one atomic write
(daemon/bus/storage.py), which calibration, importing nothing of ours, cannot use itself.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from calibration.camera_model import CameraModel
from calibration.plate import Plate


def _read_json(path: Path, what: str) -> Any:
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a JSON {what} ({exc})") from None


def load_plate(path: str | Path) -> Plate:
    """Read a plate file (OSError if unreadable, ValueError naming the file and key if bad)."""
    return Plate.from_dict(_read_json(Path(path), "plate definition"), source=str(path))


def load_camera_model(path: str | Path) -> CameraModel:
    """A model from JSON or OpenCV FileStorage YAML (ValueError naming the file when it is not one)."""
    path = Path(path)
    if path.suffix not in (".yaml", ".yml"):
        return CameraModel.from_dict(_read_json(path, "camera model"), source=str(path))
    if not path.is_file():
        raise ValueError(f"{path}: no such camera model file")
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        # FileNode.mat() gives None for a missing node (its stub says a matrix, always)
        K: np.ndarray | None = fs.getNode("camera_matrix").mat()
        dist: np.ndarray | None = fs.getNode("dist_coeffs").mat()
        w, h = fs.getNode("image_width").real(), fs.getNode("image_height").real()
    finally:
        fs.release()
    if K is None or dist is None:
        raise ValueError(f"{path}: camera_matrix or dist_coeffs missing")
    return CameraModel(K, dist.reshape(-1), (int(w), int(h)))


__all__ = ["load_camera_model", "load_plate"]
