"""Camera frames to small PNGs for the page, with the standard library only.

The laptop's client install has no numpy or OpenCV, so the downscale is a strided
byte slice per kept row (nearest neighbour: C-speed in CPython, no extra package)
and the encoder is zlib at level 1 (fast; a live view needs speed, not ratio).
Mono16 frames keep their high byte, which is what an 8-bit display can show.
"""
from __future__ import annotations

import math
import struct
import zlib
from typing import Any

#: the largest side the page may ask for; a full-resolution look goes through a region of interest
MAX_SIDE = 4096


def _chunk(kind: bytes, data: bytes) -> bytes:
    body = kind + data
    return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body) & 0xFFFFFFFF)


def png_gray8(rows: list[bytes], width: int) -> bytes:
    """An 8-bit grey PNG of equally long ``rows`` (filter type 0 on every row)."""
    raw = b"".join(b"\x00" + r for r in rows)
    ihdr = struct.pack(">IIBBBBB", width, len(rows), 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(raw, 1)) \
        + _chunk(b"IEND", b"")


def _mono8(header: dict[str, Any], pixels: memoryview | bytes) -> tuple[memoryview, int, int]:
    """The frame as 8-bit bytes, with its height and width."""
    h, w = int(header["shape"][0]), int(header["shape"][1])
    buf = memoryview(pixels).cast("B")
    dtype = str(header.get("dtype", "|u1"))
    if dtype in ("|u1", "u1", "uint8"):
        size = 1
    elif dtype in ("<u2", "uint16"):
        size = 2
        buf = buf[1::2]  # the high byte of little-endian 16-bit pixels
    else:
        raise ValueError(f"frame dtype {dtype!r} is not shown by the console (Mono8 or Mono16 only)")
    if len(buf) < h * w:
        raise ValueError(f"frame of {len(buf) * size} bytes is shorter than its shape {h}×{w}")
    return buf, h, w


def view(header: dict[str, Any], pixels: memoryview | bytes, width: int,
         roi: tuple[int, int, int, int] | None = None) -> tuple[bytes, dict[str, Any]]:
    """PNG of the frame (or of ``roi`` = x, y, w, h in full-resolution pixels) at most ``width`` wide.

    Returns the PNG and where it lies in the full frame: ``{x, y, w, h, step, out_w, out_h}``,
    so the page maps clicks and overlays back to sensor pixels.
    """
    buf, H, W = _mono8(header, pixels)
    x, y, w, h = (0, 0, W, H) if roi is None else roi
    x, y = max(0, min(int(x), W - 1)), max(0, min(int(y), H - 1))
    w, h = max(1, min(int(w), W - x)), max(1, min(int(h), H - y))
    width = max(16, min(int(width), MAX_SIDE))
    step = max(1, math.ceil(w / width))
    rows = [bytes(buf[r * W + x: r * W + x + w: step]) for r in range(y, y + h, step)]
    out_w = len(rows[0])
    return png_gray8(rows, out_w), {"x": x, "y": y, "w": w, "h": h, "step": step, "out_w": out_w,
                                    "out_h": len(rows), "full_w": W, "full_h": H}


__all__ = ["MAX_SIDE", "png_gray8", "view"]
