"""Pixels from a checked PNG's inflated rows (:func:`daemon.bus.png_check.read_png`), not inflated twice.

The dataset check inflates every PNG to verify it; OpenCV would inflate it once more to
decode it (~90 ms for a 4024×3036 image). The rows the check holds are the filtered
scanlines: with filter type None or Sub (Sub: each byte plus the byte one pixel to its left,
a running sum mod 256) numpy restores them in a quarter of that. ``cv2.imwrite``, which
writes the datasets, filters every row Sub. Any other layout (Up, Average or Paeth rows, a
palette, interlacing, transparency, or any chunk OpenCV might act on) gives None, and
OpenCV decodes the file as before.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

from daemon.bus.png_check import Png

#: chunks that carry no pixel information OpenCV applies
_PLAIN = frozenset({b"IHDR", b"IDAT", b"IEND", b"tEXt", b"zTXt", b"iTXt", b"tIME", b"pHYs"})


def _running_sum(lanes: np.ndarray, px: np.ndarray, rows: np.ndarray) -> None:
    """Undo the Sub filter of ``rows`` (ascending indices) into ``px``: a running sum along each row, mod 256."""
    if len(rows) and rows[-1] - rows[0] + 1 == len(rows):  # a contiguous block, as in a cv2.imwrite file
        block = slice(rows[0], rows[-1] + 1)
        np.cumsum(lanes[block], axis=1, dtype=np.uint8, out=px[block])  # uint8 sums wrap as the filter does
    elif len(rows):
        px[rows] = np.cumsum(lanes[rows], axis=1, dtype=np.uint8)


def decode_png(png: Png) -> np.ndarray | None:
    """The array ``cv2.imread(path, IMREAD_UNCHANGED)`` gives, colour in R, G, B(, A) order
    (as :func:`daemon.compute.images.read_image` returns it); None where this does not apply."""
    if png.interlace or png.colour not in (0, 2, 6) or png.depth not in (8, 16) or not png.tags <= _PLAIN:
        return None
    bpp = png.channels * png.depth // 8  # bytes per pixel: the Sub filter's distance
    rows = np.frombuffer(png.rows, np.uint8).reshape(png.height, 1 + png.width * bpp)
    kind = rows[:, 0]
    if kind.max() > 1:
        return None
    lanes = rows[:, 1:].reshape(png.height, png.width, bpp)
    px = np.empty_like(lanes)
    px[kind == 0] = lanes[kind == 0]  # filter None: the bytes as they are
    sub = np.flatnonzero(kind == 1)
    half = len(sub) // 2
    with ThreadPoolExecutor(2) as pool:  # numpy's running sums release the GIL: two halves at once
        list(pool.map(lambda part: _running_sum(lanes, px, part), (sub[:half], sub[half:])))
    if png.depth == 16:
        px = px.view(">u2").astype(np.uint16)  # PNG samples are big-endian
    shape = (png.height, png.width) if png.channels == 1 else (png.height, png.width, png.channels)
    return px.reshape(shape)


__all__ = ["decode_png"]
