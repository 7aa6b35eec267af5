"""``camera.detect``: the plate target's corners or a floor mark in the newest frame, on demand.

A live view that detects continuously costs the robot much CPU per picture (docs/operations.md,
"Operator console"), so the console asks only when the operator presses "Detect" (or at most
every few seconds).
The product's own detectors run: ``calibration.target.detect_corners`` (its fast marker
path) with a plate definition file from the data dir, or ``calibration.marks.locate_mark``.
One detection runs at a time, on a thread of its own (never the bus or a device thread);
a second request while one runs gets ``busy``. ``width`` makes the detector see a
downscaled copy (area-averaged) to bound the time further; the coordinates answered are
always sensor pixels of the full frame, so the page draws them over any view or zoom.
"""
from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from daemon.bus.protocol import CommandError, ErrorCode
from daemon.ritad.files import PRIVATE_DIRS, confine
from daemon.ritad.server import Request
from drivers.base import Frame

if TYPE_CHECKING:  # imported where used: OpenCV loads at the first camera.detect
    from calibration.plate import Plate

CMD = "camera.detect"


def _gray8(frame: Frame) -> np.ndarray:
    """8-bit grey for the detectors, whatever the pixel format (demosaiced, 12/16-bit scaled)."""
    from calibration.image import to_grey

    try:
        return to_grey(frame.pixels, frame.pixel_format)
    except ValueError as exc:
        raise CommandError(ErrorCode.BAD_ARGS, f"{CMD}: {exc}") from None


def _downscaled(img: np.ndarray, width: int | None) -> tuple[np.ndarray, float]:
    """``img`` at most ``width`` wide and the factor back to sensor pixels."""
    import cv2

    if not width or width >= img.shape[1]:
        return img, 1.0
    scale = img.shape[1] / width
    small = cv2.resize(img, (width, max(1, round(img.shape[0] / scale))), interpolation=cv2.INTER_AREA)
    return small, img.shape[1] / small.shape[1]


def _to_sensor(uv: np.ndarray, scale: float) -> list[list[float]]:
    # pixel centres are integers (docs/datasets.md): scale about the half-pixel edge
    uv_s = (np.asarray(uv).reshape(-1, 2) + 0.5) * scale - 0.5
    return [[round(float(u), 2), round(float(v), 2)] for u, v in uv_s]


class Detections:
    def __init__(self, latest: Callable[[], Frame | None], data_dir: Path,
                 private: tuple[str, ...] = PRIVATE_DIRS) -> None:
        self._latest = latest
        self._root = Path(data_dir)
        self._private = private
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="detect")
        self._running = threading.Lock()

    def _plate(self, path: str) -> Plate:
        from calibration.io import load_plate

        target = confine(self._root, path, CMD, self._private)  # not_found names the file
        try:
            return load_plate(target)
        except (OSError, ValueError) as exc:
            raise CommandError(ErrorCode.BAD_ARGS, f"{CMD}: plate_file {path!r}: {exc}") from None

    def handle(self, req: Request) -> Any:
        a = dict(req.args)
        plate = self._plate(a["plate_file"]) if a["target"] == "plate" else None  # a bad file first: named
        frame = self._latest()
        if frame is None:
            raise CommandError(ErrorCode.NOT_FOUND,
                               f"{CMD}: no streamed frame yet (camera.stream.start first)")
        if not self._running.acquire(blocking=False):
            raise CommandError(ErrorCode.BUSY, f"{CMD}: a detection is already running (one at a time)")
        try:
            return self._pool.submit(self._run, frame, plate, a)
        except BaseException:
            self._running.release()
            raise

    def _run(self, frame: Frame, plate: Plate | None, a: dict[str, Any]) -> dict[str, Any]:
        try:
            t0 = time.perf_counter()
            img = _gray8(frame)
            small, scale = _downscaled(img, a["width"])
            out: dict[str, Any] = {"target": a["target"], "frame_id": frame.frame_id,
                                   "full_w": img.shape[1], "full_h": img.shape[0],
                                   "searched_w": small.shape[1], "searched_h": small.shape[0]}
            out.update(self._corners(small, plate, scale) if plate is not None
                       else self._mark(small, a["target"], a["size_px"], scale))
            out["took_s"] = round(time.perf_counter() - t0, 3)
            return out
        finally:
            self._running.release()

    @staticmethod
    def _corners(img: np.ndarray, plate: Plate, scale: float) -> dict[str, Any]:
        from calibration.target import detect_corners

        ids, uv = detect_corners(img, plate, fast=True)
        return {"found": len(ids) > 0, "n": int(len(ids)), "ids": [int(i) for i in ids],
                "uv": _to_sensor(uv, scale), "plate_id": plate.plate_id}

    @staticmethod
    def _mark(img: np.ndarray, kind: str, size_px: float | None, scale: float) -> dict[str, Any]:
        from calibration.errors import CalibrationError
        from calibration.marks import locate_mark

        try:
            obs = locate_mark(img, kind, size_px=None if size_px is None else size_px / scale)
        except ValueError as exc:
            raise CommandError(ErrorCode.BAD_ARGS, f"{CMD}: {exc}") from None
        except CalibrationError as exc:
            return {"found": False, "n": 0, "message": str(exc)}
        return {"found": True, "n": 1, "uv": _to_sensor(obs.uv, scale)[0]}  # one [u, v] (docs/protocol.md)

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)


def detect_handlers(latest: Callable[[], Frame | None], data_dir: Path,
                    private: tuple[str, ...] = PRIVATE_DIRS) -> dict[str, Callable[[Request], Any]]:
    return {CMD: Detections(latest, data_dir, private).handle}
