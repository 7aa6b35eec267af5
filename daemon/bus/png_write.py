"""A minimal lossless PNG writer (grey, RGB, RGBA; 8 or 16 bit), so a laptop needs no imaging library.

One writer for ``ritactl camera capture --out`` and the console's Capture: a frame is saved at
its own depth and channel count (12-bit formats arrive decoded as 16-bit samples).
"""
from __future__ import annotations

import array
import struct
import zlib
from typing import Any


def _chunk(tag: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)


def png_bytes(pixels: bytes, width: int, height: int, channels: int = 1, bit_depth: int = 8,
              level: int = 6) -> bytes:
    """PNG of ``height`` rows of ``width`` × ``channels`` samples (16-bit samples big-endian, as
    PNG stores them)."""
    colour = {1: 0, 3: 2, 4: 6}[channels]
    stride = width * channels * bit_depth // 8
    raw = b"".join(b"\x00" + pixels[y * stride:(y + 1) * stride] for y in range(height))
    header = struct.pack(">IIBBBBB", width, height, bit_depth, colour, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + _chunk(b"IHDR", header)
            + _chunk(b"IDAT", zlib.compress(raw, level)) + _chunk(b"IEND", b""))


def frame_png(header: dict[str, Any], data: bytes) -> bytes:
    """A frame (its bus header: ``shape``, ``dtype``) as PNG at its own depth and channel count."""
    shape = header["shape"]
    depth = 16 if str(header["dtype"]).endswith("2") else 8
    data = bytes(data)
    if depth == 16 and str(header["dtype"]).startswith("<"):  # PNG stores 16-bit samples big-endian
        words = array.array("H", data)
        words.byteswap()
        data = words.tobytes()
    return png_bytes(data, int(shape[1]), int(shape[0]), int(shape[2]) if len(shape) == 3 else 1, depth)
