"""GenICam pixel formats of the LUCID PHX122S family: raw buffer bytes <-> numpy images (pure numpy).

Byte layouts (PFNC = GenICam Pixel Format Naming Convention 2.x; GEV = GigE Vision 2.0):

* ``Mono8``, ``BayerRG8``: one byte per pixel. ``RGB8``: three bytes R, G, B per pixel.
  ``RGBa8`` (what viky.cti serves): R, G, B, alpha.
* ``Mono16``: two bytes per pixel, little-endian (PFNC).
* ``Mono12p``, ``BayerRG12p`` (PFNC "p", LSB-first bit stream): two pixels a, b in three bytes:
  ``B0 = a[7:0]``, ``B1 = b[3:0] << 4 | a[11:8]``, ``B2 = b[11:4]``.
* ``Mono12Packed`` (GEV "Packed"): ``B0 = a[11:4]``, ``B1 = b[3:0] << 4 | a[3:0]``,
  ``B2 = b[11:4]``. The same bits as ``p`` for the middle byte, but the outer bytes hold the
  *high* bits, so the two packings decode differently.

Lines: every line starts on a byte boundary and is followed by ``padding_x`` bytes (GenTL's
BUFFER_INFO_PADDING_X). A 12-bit line of odd width ends in half a group: its last pixel takes
one byte and the low nibble of the next, the high nibble is padding (our convention for odd
widths; with even widths, which real sensors use, this is the plain PFNC/GEV stream).

Decoded images: uint8 for 8-bit formats, uint16 holding the raw value (0..4095 for 12-bit,
not rescaled) for 12/16-bit ones; ``RGB8`` is (h, w, 3) in R, G, B order, ``RGBa8`` (h, w, 4);
Bayer formats stay a 2-D mosaic (``BayerRG``: row 0 = R G R G ..., row 1 = G B G B ...).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PixelFormat:
    """One PFNC pixel format: its code, buffer layout and decoded shape."""

    name: str
    code: int            #: PFNC 32-bit value, as GenTL reports it (BUFFER_INFO_PIXELFORMAT)
    layout: str          #: "8", "16" (little-endian), "12p" (PFNC LSB-first) or "12Packed" (GEV)
    channels: int = 1    #: samples per pixel in the decoded image
    bayer: str | None = None  #: colour filter pattern starting at pixel (0, 0), e.g. "RGGB"

    @property
    def bits(self) -> int:
        """Significant bits per sample."""
        return {"8": 8, "16": 16}.get(self.layout, 12)

    @property
    def dtype(self) -> np.dtype:
        return np.dtype(np.uint8 if self.bits == 8 else np.uint16)

    @property
    def colour(self) -> bool:
        """A colour image (Bayer mosaic or RGB), as opposed to a mono one."""
        return self.bayer is not None or self.channels >= 3


FORMATS: dict[str, PixelFormat] = {f.name: f for f in (
    PixelFormat("Mono8", 0x01080001, "8"),
    PixelFormat("Mono12p", 0x010C0047, "12p"),
    PixelFormat("Mono12Packed", 0x010C0006, "12Packed"),
    PixelFormat("Mono16", 0x01100007, "16"),
    PixelFormat("BayerRG8", 0x01080009, "8", bayer="RGGB"),
    PixelFormat("BayerRG12p", 0x010C0059, "12p", bayer="RGGB"),
    PixelFormat("RGB8", 0x02180014, "8", channels=3),
    PixelFormat("RGBa8", 0x02200016, "8", channels=4),
)}
BY_CODE: dict[int, PixelFormat] = {f.code: f for f in FORMATS.values()}


def lookup(name: str) -> PixelFormat:
    """The format called ``name`` (ValueError naming it and the supported ones)."""
    try:
        return FORMATS[name]
    except (KeyError, TypeError):
        raise ValueError(f"pixel format {name!r} is not supported "
                         f"(supported: {', '.join(FORMATS)})") from None


def by_code(code: int) -> PixelFormat:
    """The format with PFNC value ``code`` (ValueError naming it in hex)."""
    try:
        return BY_CODE[int(code)]
    except KeyError:
        raise ValueError(f"pixel format code 0x{int(code):08X} is not supported "
                         f"(supported: {', '.join(FORMATS)})") from None


def line_bytes(fmt: PixelFormat, width: int) -> int:
    """Bytes of one line of ``width`` pixels, without padding."""
    if fmt.layout in ("12p", "12Packed"):
        return (width * 3 + 1) // 2
    return width * fmt.channels * (2 if fmt.layout == "16" else 1)


def _check_size(fmt: PixelFormat, width: int, height: int, padding_x: int) -> None:
    if int(width) < 1 or int(height) < 1 or int(padding_x) < 0:
        raise ValueError(f"{fmt.name}: bad image geometry width={width} height={height} "
                         f"padding_x={padding_x} (need width, height >= 1, padding_x >= 0)")


def _unpack12(rows: np.ndarray, width: int, layout: str) -> np.ndarray:
    """(h, line_bytes) uint8 -> (h, width) uint16 for the two 12-bit packings."""
    h, n = rows.shape
    groups = -(-n // 3)
    if groups * 3 != n:  # odd width: complete the last group with a zero byte
        rows = np.concatenate([rows, np.zeros((h, groups * 3 - n), np.uint8)], axis=1)
    b0, b1, b2 = (rows[:, k::3].astype(np.uint16) for k in range(3))
    out = np.empty((h, groups * 2), np.uint16)
    if layout == "12p":
        out[:, 0::2] = b0 | (b1 & 0x0F) << 8
        out[:, 1::2] = b1 >> 4 | b2 << 4
    else:
        out[:, 0::2] = b0 << 4 | (b1 & 0x0F)
        out[:, 1::2] = b2 << 4 | b1 >> 4
    return out[:, :width]


def decode(raw: bytes | bytearray | memoryview | np.ndarray, pixel_format: str, width: int,
           height: int, padding_x: int = 0, offset: int = 0) -> np.ndarray:
    """A new numpy image from a raw buffer of ``pixel_format`` (see the module docstring).

    ``raw`` may be longer than the image (GenTL buffers are announced at the maximum
    payload); a shorter one is a ValueError naming the format and both sizes.
    """
    fmt = lookup(pixel_format)
    _check_size(fmt, width, height, padding_x)
    buf = np.frombuffer(raw, np.uint8) if not isinstance(raw, np.ndarray) else \
        np.ascontiguousarray(raw).reshape(-1).view(np.uint8)
    nbytes = line_bytes(fmt, width)
    stride = nbytes + padding_x
    need = offset + stride * (height - 1) + nbytes
    if offset < 0 or buf.size < need:
        raise ValueError(f"{fmt.name} buffer of {buf.size} bytes is too short for {width}x{height} "
                         f"(needs {need}: {height} lines of {nbytes} bytes + {padding_x} padding, "
                         f"offset {offset})")
    rows = np.lib.stride_tricks.as_strided(buf[offset:], shape=(height, nbytes), strides=(stride, 1),
                                           writeable=False)
    if fmt.layout in ("12p", "12Packed"):
        img = _unpack12(rows, width, fmt.layout)
    elif fmt.layout == "16":
        img = np.ascontiguousarray(rows).view("<u2").astype(np.uint16)
    else:
        img = rows
    img = img.reshape((height, width, fmt.channels) if fmt.channels > 1 else (height, width))
    return img if img.flags.owndata else img.copy()  # never a view of the producer's memory


def _pack12(img: np.ndarray, layout: str) -> np.ndarray:
    """(h, w) values 0..4095 -> (h, line_bytes) uint8, the inverse of :func:`_unpack12`."""
    h, w = img.shape
    v = img.astype(np.uint16)
    if w % 2:
        v = np.concatenate([v, np.zeros((h, 1), np.uint16)], axis=1)
    a, b = v[:, 0::2], v[:, 1::2]
    out = np.empty((h, a.shape[1] * 3), np.uint8)
    if layout == "12p":
        out[:, 0::3] = a & 0xFF
        out[:, 2::3] = b >> 4
    else:
        out[:, 0::3] = a >> 4
        out[:, 2::3] = b >> 4
    a_nibble = a & 0x0F if layout == "12Packed" else a >> 8  # the 4 bits of a that B0 lacks
    out[:, 1::3] = (b & 0x0F) << 4 | a_nibble
    return out[:, :(w * 3 + 1) // 2]


def encode(image: np.ndarray, pixel_format: str, padding_x: int = 0) -> bytes:
    """Raw buffer bytes of ``image`` in ``pixel_format`` (what a camera would send; used by the fakes)."""
    fmt = lookup(pixel_format)
    img = np.asarray(image)
    want = (fmt.channels,) if fmt.channels > 1 else ()
    if img.ndim != 2 + len(want) or img.shape[2:] != want or img.dtype != fmt.dtype:
        shape = f"(h, w, {fmt.channels})" if want else "(h, w)"
        raise ValueError(f"{fmt.name} needs a {fmt.dtype} image of shape {shape}, "
                         f"got {img.dtype} {img.shape}")
    _check_size(fmt, img.shape[1], img.shape[0], padding_x)
    if fmt.bits == 12 and img.size and int(img.max()) > 4095:
        raise ValueError(f"{fmt.name}: value {int(img.max())} does not fit in 12 bits")
    h = img.shape[0]
    if fmt.layout in ("12p", "12Packed"):
        rows = _pack12(img, fmt.layout)
    elif fmt.layout == "16":
        rows = img.astype("<u2").reshape(h, -1).view(np.uint8)
    else:
        rows = img.reshape(h, -1)
    if padding_x:
        rows = np.concatenate([rows, np.zeros((h, padding_x), np.uint8)], axis=1)
    return np.ascontiguousarray(rows).tobytes()
