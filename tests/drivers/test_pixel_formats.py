"""drivers.pixel_formats against deliberately simple bit-by-bit reference packers.

The reference writes every pixel's bits one at a time into the byte positions the
specifications give, so it shares no arithmetic with the vectorised decoder:

* PFNC "p" (Mono12p, BayerRG12p): one LSB-first bit stream; bit i of the stream is bit
  i % 8 of byte i // 8; each line is closed to a byte boundary.
* GigE Vision "Packed" (Mono12Packed): per pixel pair (a, b), B0 = a[11:4],
  B1 = b[3:0] a[3:0], B2 = b[11:4] (table below).
* Mono16: little-endian; 8-bit formats: one byte per sample.
"""
from __future__ import annotations

import numpy as np
import pytest

from drivers import pixel_formats as pf

# GigE Vision Mono12Packed: (byte in group, bit in byte) <- (pixel of the pair, bit of the pixel)
_GEV_PACKED = {(0, k): (0, k + 4) for k in range(8)}
_GEV_PACKED.update({(1, k): (0, k) for k in range(4)})
_GEV_PACKED.update({(1, k): (1, k - 4) for k in range(4, 8)})
_GEV_PACKED.update({(2, k): (1, k + 4) for k in range(8)})


def _bits_to_bytes(bits: list[int]) -> list[int]:
    while len(bits) % 8:
        bits.append(0)
    out = []
    for i in range(0, len(bits), 8):
        byte = 0
        for k in range(8):
            byte += bits[i + k] * (2 ** k)
        out.append(byte)
    return out


def _ref_line(values: list[int], layout: str) -> list[int]:
    if layout == "8":
        return list(values)
    if layout == "16":
        bits = [(v >> k) & 1 for v in values for k in range(16)]
        return _bits_to_bytes(bits)
    if layout == "12p":
        bits = [(v >> k) & 1 for v in values for k in range(12)]
        return _bits_to_bytes(bits)
    out: list[int] = []  # 12Packed
    for g in range(0, len(values), 2):
        pair = values[g:g + 2]
        group = [0, 0, 0]
        for (byte, bit), (px, pbit) in _GEV_PACKED.items():
            if px < len(pair) and (pair[px] >> pbit) & 1:
                group[byte] |= 1 << bit
        out += group if len(pair) == 2 else group[:2]  # odd width: half a group, byte aligned
    return out


def ref_pack(img: np.ndarray, fmt: pf.PixelFormat, padding_x: int) -> bytes:
    out: list[int] = []
    for row in img.reshape(img.shape[0], -1):
        out += _ref_line([int(v) for v in row], fmt.layout) + [0xEE] * padding_x
    return bytes(out)


def ref_unpack(raw: bytes, fmt: pf.PixelFormat, w: int, h: int, padding_x: int) -> np.ndarray:
    """Inverse of ref_pack, again bit by bit."""
    n = w * fmt.channels
    line = len(_ref_line([0] * n, fmt.layout))
    out = np.zeros((h, n), np.int64)
    for r in range(h):
        data = raw[r * (line + padding_x):r * (line + padding_x) + line]
        bits = [(data[i // 8] >> (i % 8)) & 1 for i in range(8 * len(data))]
        for c in range(n):
            if fmt.layout == "8":
                out[r, c] = data[c]
            elif fmt.layout in ("16", "12p"):
                nb = 16 if fmt.layout == "16" else 12
                out[r, c] = sum(bits[c * nb + k] << k for k in range(nb))
            else:
                g, px = divmod(c, 2)
                for (byte, bit), (p, pbit) in _GEV_PACKED.items():
                    if p == px and bits[(3 * g + byte) * 8 + bit]:
                        out[r, c] |= 1 << pbit
    shape = (h, w, fmt.channels) if fmt.channels > 1 else (h, w)
    return out.reshape(shape)


def random_image(fmt: pf.PixelFormat, w: int, h: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    shape = (h, w, fmt.channels) if fmt.channels > 1 else (h, w)
    return rng.integers(0, 2 ** fmt.bits, size=shape).astype(fmt.dtype)


CASES = [(name, w, pad) for name in pf.FORMATS for w, pad in ((8, 0), (7, 0), (13, 5))]


@pytest.mark.parametrize("name,w,pad", CASES)
def test_round_trip_against_reference(name: str, w: int, pad: int) -> None:
    fmt = pf.FORMATS[name]
    h = 5
    img = random_image(fmt, w, h, seed=len(CASES) * w + pad)
    raw = ref_pack(img, fmt, pad)
    out = pf.decode(raw, name, w, h, padding_x=pad)
    assert out.dtype == fmt.dtype and out.shape == img.shape and out.flags.owndata
    assert np.array_equal(out, img)
    mine = pf.encode(img, name, padding_x=pad)
    assert len(mine) == len(raw)
    assert np.array_equal(ref_unpack(mine, fmt, w, h, pad), img)
    if not pad:
        assert mine == raw  # padding content is free; the pixel bytes must agree exactly


def test_decode_from_a_larger_gentl_buffer_with_an_offset() -> None:
    fmt = pf.FORMATS["BayerRG12p"]
    img = random_image(fmt, 10, 4, seed=3)
    raw = b"\x55" * 7 + ref_pack(img, fmt, 2) + b"\x00" * 1000  # announced at the maximum payload
    assert np.array_equal(pf.decode(raw, "BayerRG12p", 10, 4, padding_x=2, offset=7), img)
    arr = np.frombuffer(raw, np.uint8)  # harvesters hands out flat uint8 arrays
    assert np.array_equal(pf.decode(arr, "BayerRG12p", 10, 4, padding_x=2, offset=7), img)


def test_the_two_12_bit_packings_differ_as_the_specs_say() -> None:
    img = np.array([[0x123, 0x456]], np.uint16)
    assert pf.encode(img, "Mono12p") == bytes([0x23, 0x61, 0x45])       # PFNC, LSB first
    assert pf.encode(img, "Mono12Packed") == bytes([0x12, 0x63, 0x45])  # GigE Vision
    assert pf.decode(bytes([0x23, 0x61, 0x45]), "Mono12Packed", 2, 1).tolist() != img.tolist()


def test_rgb8_is_r_g_b_and_bayer_stays_a_mosaic() -> None:
    rgb = pf.decode(bytes([10, 20, 30, 40, 50, 60]), "RGB8", 2, 1)
    assert rgb.shape == (1, 2, 3) and rgb[0, 0].tolist() == [10, 20, 30]
    assert pf.decode(bytes(range(12)), "BayerRG8", 4, 3).shape == (3, 4)


def test_codes_match_the_pfnc_values() -> None:
    assert pf.by_code(0x01080001).name == "Mono8"
    assert pf.by_code(0x010C0047).name == "Mono12p"
    assert pf.by_code(0x010C0059).name == "BayerRG12p"
    with pytest.raises(ValueError, match=r"0x0110002E is not supported"):
        pf.by_code(0x0110002E)


@pytest.mark.parametrize("args,needle", [
    ((b"\0" * 10, "Mono12p", 8, 1), r"Mono12p buffer of 10 bytes is too short for 8x1 \(needs 12"),
    ((b"\0" * 47, "RGB8", 4, 4), r"RGB8 buffer of 47 bytes is too short for 4x4 \(needs 48"),
    ((b"\0" * 99, "Mono16", 5, 10, 1), r"Mono16 buffer of 99 bytes is too short for 5x10 \(needs 109"),
    ((b"\0" * 9, "Mono10", 2, 2), r"pixel format 'Mono10' is not supported \(supported: Mono8, "),
    ((b"\0" * 9, "Mono8", 0, 2), r"Mono8: bad image geometry width=0"),
])
def test_errors_name_the_format_and_the_sizes(args: tuple, needle: str) -> None:
    with pytest.raises(ValueError, match=needle):
        pf.decode(*args)


def test_encode_refuses_values_and_shapes_that_do_not_fit() -> None:
    with pytest.raises(ValueError, match=r"Mono12p: value 4096 does not fit in 12 bits"):
        pf.encode(np.full((2, 2), 4096, np.uint16), "Mono12p")
    with pytest.raises(ValueError, match=r"RGB8 needs a uint8 image of shape \(h, w, 3\)"):
        pf.encode(np.zeros((2, 2), np.uint8), "RGB8")
