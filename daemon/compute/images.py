"""Dataset images read back for the computation (docs/datasets.md, "Images").

An image is a PNG in the dataset folder; its pixel format is ``camera.pixel_format`` in
the sidecar of the same name (``<stem>.json``). Without a sidecar or that key (datasets
from before pixel formats were recorded, or from other writers) it is read as Mono8,
Mono16 for a 16-bit PNG, RGB8 for a colour one. Every image used for detection goes
through :func:`calibration.image.to_grey` (Bayer demosaiced, 16-bit scaled to 8).
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Callable

import numpy as np

from calibration.image import infer_format, to_grey


def pixel_format_of(root: Path, file: str) -> str | None:
    """The pixel format the image's sidecar records, or None."""
    side = Path(root) / (Path(file).stem + ".json")
    try:
        doc = json.loads(side.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    camera = doc.get("camera") if isinstance(doc, dict) else None
    fmt = camera.get("pixel_format") if isinstance(camera, dict) else None
    return fmt if isinstance(fmt, str) else None


def read_image(root: Path, file: str) -> tuple[np.ndarray, str]:
    """(pixels as stored: mosaic, mono or RGB(A) in R, G, B order; pixel format)."""
    import cv2

    path = Path(root) / file
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise FileNotFoundError(f"{path}: missing or unreadable image")
    if img.ndim == 3:  # OpenCV reads B, G, R(, a); the file and our arrays are RGB(A)
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB if img.shape[2] == 3 else cv2.COLOR_BGRA2RGBA)
    return img, pixel_format_of(root, file) or infer_format(img)


def _grey(root: Path, file: str, img: np.ndarray, fmt: str) -> np.ndarray:
    try:
        return to_grey(img, fmt)
    except ValueError as exc:
        raise ValueError(f"{Path(root) / file}: {exc}") from None


def grey_loader(root: Path) -> Callable[[str], np.ndarray]:
    """file -> 8-bit grey image for the detectors (the LoadImage of daemon.compute.procedures)."""
    def load(file: str) -> np.ndarray:
        return _grey(root, file, *read_image(root, file))

    return load
