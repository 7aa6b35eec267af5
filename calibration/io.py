"""The calibration's only file I/O: plate and camera-model files (JSON, OpenCV FileStorage YAML).

Everything else in ``calibration/`` works on arrays and dicts; the worker and the tools
read and write files through here. Writes are atomic (temp file + fsync + rename), so a
crash never leaves half a file.
"""
from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

import cv2

from calibration.camera_model import CameraModel
from calibration.plate import Plate


def _write_atomic(path: Path, write: Any, suffix: str) -> None:
    """``write(tmp_path)`` fills a temp file beside ``path``; it is fsynced, then renamed over ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix, dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        with open(tmp, "rb+") as f:
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _write_json(path: Path, obj: Any) -> None:
    _write_atomic(path, lambda tmp: Path(tmp).write_text(json.dumps(obj, indent=2)), ".tmp")


def _read_json(path: Path, what: str) -> Any:
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not a JSON {what} ({exc})") from None


def save_plate(plate: Plate, path: str | Path) -> None:
    _write_json(Path(path), plate.to_dict())


def load_plate(path: str | Path) -> Plate:
    """Read a plate file (OSError if unreadable, ValueError naming the file and key if bad)."""
    return Plate.from_dict(_read_json(Path(path), "plate definition"), source=str(path))


def save_camera_model(model: CameraModel, path: str | Path) -> None:
    """JSON (``.json``) or OpenCV FileStorage YAML (``.yaml``/``.yml``), by the file's suffix."""
    path = Path(path)
    if path.suffix not in (".yaml", ".yml"):
        _write_json(path, model.to_dict())
        return

    def write_yaml(tmp: str) -> None:
        fs = cv2.FileStorage(tmp, cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_FORMAT_YAML)
        try:
            fs.write("image_width", int(model.size[0]))
            fs.write("image_height", int(model.size[1]))
            fs.write("camera_matrix", model.K)
            fs.write("dist_coeffs", model.dist.reshape(1, -1))
        finally:
            fs.release()

    _write_atomic(path, write_yaml, path.suffix)


def load_camera_model(path: str | Path) -> CameraModel:
    """A model from JSON or OpenCV FileStorage YAML (ValueError naming the file when it is not one)."""
    path = Path(path)
    if path.suffix not in (".yaml", ".yml"):
        return CameraModel.from_dict(_read_json(path, "camera model"), source=str(path))
    if not path.is_file():
        raise ValueError(f"{path}: no such camera model file")
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    try:
        K, dist = fs.getNode("camera_matrix").mat(), fs.getNode("dist_coeffs").mat()
        w, h = fs.getNode("image_width").real(), fs.getNode("image_height").real()
    finally:
        fs.release()
    if K is None or dist is None:
        raise ValueError(f"{path}: camera_matrix or dist_coeffs missing")
    return CameraModel(K, dist.reshape(-1), (int(w), int(h)))


__all__ = ["load_camera_model", "load_plate", "save_camera_model", "save_plate"]
