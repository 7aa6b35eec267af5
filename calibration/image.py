"""Camera images as the detectors need them: grey 8-bit for corners and marks, RGB for ring colours.

Input is a decoded frame as stored in a dataset (docs/datasets.md, "Images"): a 2-D array
for mono formats and Bayer mosaics, (h, w, 3|4) in R, G, B(, a) order for RGB formats;
uint8 or uint16 (12/16-bit raw values). The format is known by its GenICam (PFNC) name,
whose naming rules are all that is used here (``Mono*``, ``Bayer<XY>*`` with X Y the
first two pixels of row 0, ``RGB*``), so this leaf does not depend on the driver's table.

OpenCV names its Bayer codes after the 2nd and 3rd pixels of the *second* row, not after
the first two pixels of the first row as PFNC does: PFNC ``BayerRG`` (row 0 = R G, row 1 =
G B) is OpenCV's ``BayerBG``. ``tests/calibration/test_image.py`` proves the mapping on
synthetic mosaics (a red scene must come out red).

16-bit images are brought to 8 bits by one gain, 255 / peak: corner and mark positions do not
depend on a gain, and a 12-bit image (0..4095 in 16 bits) keeps its full contrast.
"""
from __future__ import annotations

import cv2
import numpy as np

#: PFNC Bayer pattern (first two pixels of row 0) -> OpenCV's name for the same mosaic
OPENCV_BAYER = {"RG": "BG", "GR": "GB", "GB": "GR", "BG": "RG"}


def infer_format(image: np.ndarray) -> str:
    """The format an image without one is read as (old datasets): Mono8/Mono16 or RGB8/RGBa8."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] in (3, 4):
        return "RGB8" if img.shape[2] == 3 else "RGBa8"
    return "Mono16" if img.dtype == np.uint16 else "Mono8"


def _check(image: np.ndarray, pixel_format: str | None) -> tuple[np.ndarray, str]:
    img = np.asarray(image)
    fmt = pixel_format or infer_format(img)
    if img.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"image ({fmt}): expected 8- or 16-bit pixels, got dtype {img.dtype}")
    colour = fmt.startswith(("RGB", "BGR"))
    if not (fmt.startswith(("Mono", "Bayer")) or colour):
        raise ValueError(f"image: pixel format {fmt!r} is not a Mono, Bayer or RGB format")
    want_ndim = 3 if colour else 2
    if img.ndim != want_ndim or (colour and img.shape[2] not in (3, 4)):
        raise ValueError(f"image ({fmt}): shape {img.shape} is not "
                         f"{'(h, w, 3|4)' if colour else '(h, w)'}")
    if fmt.startswith("Bayer") and fmt[5:7] not in OPENCV_BAYER:
        raise ValueError(f"image: unknown Bayer pattern in pixel format {fmt!r}")
    return img, fmt


def to_8bit(image: np.ndarray) -> np.ndarray:
    """uint8 unchanged; uint16 times 255 / its peak, rounded (a pure gain)."""
    img = np.asarray(image)
    if img.dtype == np.uint8:
        return img
    peak = max(int(img.max()), 1)
    return np.round(img.astype(np.float32) * (255.0 / peak)).astype(np.uint8)


def _bayer_code(fmt: str, target: str) -> int:
    return getattr(cv2, f"COLOR_Bayer{OPENCV_BAYER[fmt[5:7]]}2{target}")


def _rgb_full(img: np.ndarray, fmt: str) -> np.ndarray:
    """(h, w, 3) RGB at the image's own depth (demosaiced for Bayer)."""
    if fmt.startswith("Bayer"):
        return cv2.cvtColor(np.ascontiguousarray(img), _bayer_code(fmt, "RGB"))
    rgb = img[:, :, :3]
    return rgb[:, :, ::-1] if fmt.startswith("BGR") else rgb


def to_grey(image: np.ndarray, pixel_format: str | None = None) -> np.ndarray:
    """uint8 (h, w) grey for corner and mark detection; ``None`` = :func:`infer_format`.

    Bayer mosaics are demosaiced (OpenCV bilinear) to grey at their own depth, then
    scaled; RGB uses OpenCV's luma weights.
    """
    img, fmt = _check(image, pixel_format)
    if fmt.startswith("Mono"):
        return to_8bit(img)
    if fmt.startswith("Bayer"):
        return to_8bit(cv2.cvtColor(np.ascontiguousarray(img), _bayer_code(fmt, "GRAY")))
    return to_8bit(cv2.cvtColor(np.ascontiguousarray(_rgb_full(img, fmt)), cv2.COLOR_RGB2GRAY))


def to_rgb(image: np.ndarray, pixel_format: str | None = None) -> np.ndarray:
    """uint8 (h, w, 3) in R, G, B order, for colour identification (ValueError for mono formats)."""
    img, fmt = _check(image, pixel_format)
    if fmt.startswith("Mono"):
        raise ValueError(f"image: pixel format {fmt} carries no colour; colour identification "
                         "needs a Bayer or RGB image")
    return to_8bit(np.ascontiguousarray(_rgb_full(img, fmt)))
