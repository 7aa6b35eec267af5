"""PNG files checked without an imaging library: complete, uncorrupted, and of the size they claim.

``ritactl validate`` runs on the operator's laptop without OpenCV; this reads the
chunk structure (PNG specification, ISO/IEC 15948) and inflates the image data.
"""
from __future__ import annotations

import struct
import zlib
from pathlib import Path

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}  # colour type -> samples per pixel
#: larger inflated image data is refused before inflating (a 4024x3036 16-bit image is 24 MB)
MAX_IMAGE_BYTES = 512 * 2 ** 20


def _chunks(data: bytes) -> tuple[tuple[int, ...] | None, list[memoryview], bool]:
    """(IHDR fields, IDAT bodies, IEND seen) after checking every chunk's length and CRC."""
    view = memoryview(data)  # chunk bodies as views: a 7 MB file is not copied chunk by chunk
    pos, ihdr, idat, ended = 8, None, [], False
    while pos + 8 <= len(data) and not ended:
        length, tag = struct.unpack_from(">I4s", data, pos)
        body = view[pos + 8:pos + 8 + length]
        crc = data[pos + 8 + length:pos + 12 + length]
        if len(body) < length or len(crc) < 4:
            raise ValueError(f"truncated in chunk {tag!r} at byte {pos} (file has {len(data)} bytes)")
        if struct.unpack(">I", crc)[0] != zlib.crc32(body, zlib.crc32(tag)) & 0xFFFFFFFF:
            raise ValueError(f"chunk {tag!r} at byte {pos} is corrupted (CRC mismatch)")
        if tag == b"IHDR" and length == 13:
            ihdr = struct.unpack(">IIBBBBB", body)
        elif tag == b"IDAT":
            idat.append(body)
        ended = tag == b"IEND"
        pos += 12 + length
    return ihdr, idat, ended


def png_info(path: Path) -> tuple[int, int, int, int]:
    """(width, height, channels, bit depth) of a complete PNG; ValueError says what is wrong.

    Reads every chunk, checks each CRC and inflates the image data to its exact size,
    so a truncated or corrupted file is found without an imaging library.
    """
    data = path.read_bytes()
    if not data.startswith(_PNG_SIGNATURE):
        raise ValueError("not a PNG file (bad signature)")
    ihdr, idat, ended = _chunks(data)
    if ihdr is None or not ended:
        raise ValueError("truncated: " + ("no IHDR header" if ihdr is None else "no IEND chunk"))
    w, h, depth, colour, _, _, interlace = ihdr
    if colour not in _PNG_CHANNELS or w == 0 or h == 0:
        raise ValueError(f"unsupported PNG header (colour type {colour}, {w}x{h})")
    want = h * (1 + (w * _PNG_CHANNELS[colour] * depth + 7) // 8)
    if want > MAX_IMAGE_BYTES:
        raise ValueError(f"implausible size {w}x{h} at {depth} bit ({want} bytes > {MAX_IMAGE_BYTES})")
    inflate = zlib.decompressobj()
    try:  # bounded: a corrupt or hostile stream cannot inflate beyond the size the header states
        raw = inflate.decompress(b"".join(idat), 2 * want + 1024)
    except zlib.error as exc:
        raise ValueError(f"image data is corrupted ({exc})") from None
    if interlace == 0 and (len(raw) != want or not inflate.eof):
        raise ValueError(f"image data has {len(raw)}{'' if inflate.eof else '+'} bytes, "
                         f"a {w}x{h} image needs {want}")
    return w, h, _PNG_CHANNELS[colour], depth
