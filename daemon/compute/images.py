"""Dataset images read back for the computation (docs/datasets.md, "Images").

An image is a PNG in the dataset folder; its pixel format is ``camera.pixel_format`` in
the sidecar of the same name (``<stem>.json``). Without a sidecar or that key (datasets
from before pixel formats were recorded, or from other writers) it is read as Mono8,
Mono16 for a 16-bit PNG, RGB8 for a colour one. Every image used for detection goes
through :func:`calibration.image.to_grey` (Bayer demosaiced, 16-bit scaled to 8).
"""
from __future__ import annotations

import json
import threading
from pathlib import Path
from typing import Any, Callable

import numpy as np

from calibration.image import infer_format, to_grey
from daemon.bus.png_check import MAX_IMAGE_BYTES, png_header


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


def grey_loader(root: Path) -> Callable[[str], np.ndarray]:
    """file -> 8-bit grey image for the detectors (the LoadImage of daemon.compute.procedures)."""
    def load(file: str) -> np.ndarray:
        img, fmt = read_image(root, file)
        try:
            return to_grey(img, fmt)
        except ValueError as exc:
            raise ValueError(f"{Path(root) / file}: {exc}") from None

    return load


def first_image(root: Path) -> str | None:
    """The first image a procedure's computation reads (runs, stops, views, stop), from state.json; or None."""
    try:
        obs = json.loads((Path(root) / "state.json").read_text(encoding="utf-8")).get("obs")
        for key in ("runs", "stops", "views"):
            for item in obs.get(key) or []:
                if isinstance(item.get("image"), str):
                    return item["image"]
        file = (obs.get("stop") or {}).get("image")
        return file if isinstance(file, str) else None
    except (OSError, ValueError, AttributeError, TypeError, RecursionError):
        return None  # the validation says what is wrong with state.json


class PrefetchedLoader:
    """A :func:`grey_loader` that starts decoding one image in a background thread at once.

    ``ritactl recompute`` validates the folder before it computes, and the validation
    inflates every PNG in pure Python; OpenCV decoding the same file meanwhile costs no
    wall time on a second core (both release the GIL). Only the decoded pixels are
    kept, and only used when the computation asks for that file after the validation
    passed. A file without a plausible PNG header (size within :data:`MAX_IMAGE_BYTES`)
    is not prefetched: the validation reports it before anything decodes it.
    """

    def __init__(self, root: Path, file: str | None) -> None:
        self._load = grey_loader(root)
        self._file, self._out, self._thread = file, None, None
        info = png_header(Path(root) / file) if file and "/" not in file and "\\" not in file else None
        if info is not None and info[1] * (1 + (info[0] * info[2] * info[3] + 7) // 8) <= MAX_IMAGE_BYTES:
            self._thread = threading.Thread(target=self._run, name="prefetch-image", daemon=True)
            self._thread.start()

    def _run(self) -> None:
        try:
            self._out = (self._load(self._file), None)
        except Exception as exc:  # noqa: BLE001 - raised in the caller's thread when it asks for the file
            self._out = (None, exc)

    def __call__(self, file: str) -> np.ndarray:
        if file != self._file or self._thread is None:
            return self._load(file)
        self._thread.join()
        self._thread = None
        (img, exc), self._out = self._out, None  # handed out once
        if exc is not None:
            raise exc
        return img

    def __enter__(self) -> "PrefetchedLoader":
        return self

    def __exit__(self, *exc: Any) -> None:
        """Wait for a decode still running (a recompute leaves no thread behind) and drop its pixels."""
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        self._out = None


__all__ = ["PrefetchedLoader", "first_image", "grey_loader", "pixel_format_of", "read_image"]
