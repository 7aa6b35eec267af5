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
from daemon.bus.png_check import png_info, read_png
from daemon.compute.png_decode import decode_png


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
    """A :func:`grey_loader` whose first image is checked and decoded once, in a background thread.

    ``ritactl recompute`` validates the folder before it computes, and the validation
    inflates every PNG in pure Python to check it (:func:`daemon.bus.png_check.read_png`).
    For the first image the computation reads, that check starts here, in a thread, at once:
    the validation takes its result (:meth:`png_info`) instead of inflating the file again,
    and the pixels come from the rows it inflated (:func:`daemon.compute.png_decode.decode_png`;
    OpenCV decodes what that does not cover). The pixels are handed out only when the
    computation asks for that file, which it does after the validation passed.
    """

    def __init__(self, root: Path, file: str | None) -> None:
        self._root, self._load = Path(root), grey_loader(root)
        self._file = file if file and "/" not in file and "\\" not in file else None
        self._checked = threading.Event()
        self._check: Any = None  # the image's png_info, or what the check raised
        self._out: tuple[np.ndarray | None, Exception | None] | None = None
        self._thread: threading.Thread | None = None
        if self._file is not None:
            self._thread = threading.Thread(target=self._run, name="prefetch-image", daemon=True)
            self._thread.start()

    def _run(self) -> None:
        file = self._file
        if file is None:  # started only with a file
            return
        try:
            png = read_png(self._root / file)
            self._check = png.info
        except Exception as exc:  # noqa: BLE001 - the validation raises or reports it, as png_info would
            self._check = exc
            return
        finally:
            self._checked.set()
        try:
            img = decode_png(png)
            del png  # the inflated rows: 12 MB for a full-size image
            if img is None:
                self._out = (self._load(file), None)
            else:
                fmt = pixel_format_of(self._root, file) or infer_format(img)
                self._out = (_grey(self._root, file, img, fmt), None)
        except Exception as exc:  # noqa: BLE001 - raised in the caller's thread when it asks for the file
            self._out = (None, exc)

    def png_info(self, path: Path) -> tuple[int, int, int, int]:
        """:func:`daemon.bus.png_check.png_info` for the validation: the prefetched file's comes from the thread."""
        if self._thread is None or self._file is None or Path(path) != self._root / self._file:
            return png_info(path)
        self._checked.wait()
        if isinstance(self._check, Exception):
            raise self._check
        return self._check

    def __call__(self, file: str) -> np.ndarray:
        if file != self._file or self._thread is None:
            return self._load(file)
        self._thread.join()
        self._thread = None
        out, self._out = self._out, None  # handed out once
        if out is None:
            raise RuntimeError(f"prefetch of {file}: the image thread ended without a result")
        img, exc = out
        if exc is not None:
            raise exc
        if img is None:
            raise RuntimeError(f"prefetch of {file}: no image and no error")
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
