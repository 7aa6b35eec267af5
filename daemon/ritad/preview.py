"""``camera.preview``: the newest streamed frame, small, for live views over a thin link.

A full frame is 12 MB (4024×3036 Mono8); five of them a second are 480 Mbit/s, more
than a robot's Wi-Fi carries and, over CURVE, several % of a core to encrypt. A live
view needs a picture a few hundred pixels wide, so the robot makes it: a strided slice
(nearest neighbour, no filtering: a view, not a measurement) or a full-resolution
region, JPEG-encoded by OpenCV. Clients pull (``after`` = the last frame id they have),
so a slow client asks less often and costs nothing; the work runs on one thread of its
own, never on the bus or a device thread. The last picture is cached, so two tabs
watching the same view cost one encode.
"""
from __future__ import annotations

import math
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable

import numpy as np

from daemon.bus.protocol import CommandError, ErrorCode
from daemon.ritad.server import Reply, Request
from drivers.base import Frame



def display_grey(frame: Frame) -> np.ndarray:
    """8-bit grey as the sensor exposed it: the top 8 bits of the format's depth (no auto gain, so
    the operator judges the exposure), Bayer demosaiced, RGB as luma."""
    import cv2

    img, fmt = frame.pixels, frame.pixel_format or "Mono8"
    if img.dtype.itemsize == 2:
        img = (img >> (4 if "12" in fmt else 8)).astype(np.uint8)
    if fmt.startswith("Bayer"):
        from calibration.image import OPENCV_BAYER

        code = getattr(cv2, f"COLOR_Bayer{OPENCV_BAYER[fmt[5:7]]}2GRAY")
        return cv2.cvtColor(np.ascontiguousarray(img), code)
    if img.ndim == 3:
        return cv2.cvtColor(np.ascontiguousarray(img[..., :3]), cv2.COLOR_RGB2GRAY)
    if img.ndim != 2:
        raise CommandError(ErrorCode.BAD_ARGS, f"camera.preview: frames of shape {img.shape} are not shown")
    return img

class Previews:
    def __init__(self, latest: Callable[[], Frame | None]) -> None:
        self._latest = latest
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="preview")
        self._lock = threading.Lock()
        self._cache: tuple[tuple[Any, ...], Reply] | None = None

    def handle(self, req: Request) -> Any:
        frame = self._latest()
        if frame is None:
            raise CommandError(ErrorCode.NOT_FOUND, "camera.preview: no streamed frame yet "
                                                    "(camera.stream.start first)")
        if frame.frame_id == req.args["after"]:  # equal, not ≤: a reconnected camera may count from 0 again
            return {"unchanged": True, "frame_id": frame.frame_id}
        return self._pool.submit(self._picture, frame, dict(req.args))

    def _picture(self, frame: Frame, a: dict[str, Any]) -> Reply:
        import cv2

        img = display_grey(frame)
        H, W = img.shape
        x, y = min(max(a["roi_x"] or 0, 0), W - 1), min(max(a["roi_y"] or 0, 0), H - 1)
        w, h = min(a["roi_w"] or W, W - x), min(a["roi_h"] or H, H - y)
        step = max(1, math.ceil(w / a["width"]))
        key = (frame.frame_id, x, y, w, h, step, a["quality"])
        with self._lock:
            if self._cache is not None and self._cache[0] == key:
                return self._cache[1]
        small = img[y:y + h:step, x:x + w:step]
        ok, jpeg = cv2.imencode(".jpg", small, [cv2.IMWRITE_JPEG_QUALITY, a["quality"]])
        if not ok:
            raise CommandError(ErrorCode.INTERNAL, "camera.preview: JPEG encoding failed")
        reply = Reply({"header": frame.header(), "format": "jpeg", "x": x, "y": y, "w": w, "h": h,
                       "step": step, "out_w": small.shape[1], "out_h": small.shape[0],
                       "full_w": W, "full_h": H},
                      [jpeg.tobytes()])
        with self._lock:
            self._cache = (key, reply)
        return reply

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)


def preview_handlers(latest: Callable[[], Frame | None]) -> dict[str, Callable[[Request], Any]]:
    return {"camera.preview": Previews(latest).handle}
