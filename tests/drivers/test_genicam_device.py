"""Raw GenTL buffers decoded on plain data (no producer needed), and device descriptions."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from drivers import pixel_formats
from drivers.base import DeviceError
from drivers.genicam_device import decode_buffer, describe


@dataclass
class RawBuffer:
    """The fields of a genicam.gentl.Buffer that decode_buffer reads (as harvesters' is_raw fetch gives)."""

    pixel_format: int
    width: int
    height: int
    raw_buffer: bytes
    padding_x: int = 0
    image_offset: int = 0
    size_filled: int | None = None

    def __post_init__(self) -> None:
        if self.size_filled is None:
            self.size_filled = len(self.raw_buffer)


def test_mono8_is_copied_and_reshaped() -> None:
    raw = bytearray(range(12))
    px, fmt = decode_buffer(RawBuffer(0x01080001, 4, 3, raw))
    assert fmt == "Mono8" and px.shape == (3, 4) and px[2, 3] == 11
    raw[:] = bytes(12)  # the producer reuses its buffer
    assert px[2, 3] == 11 and px.flags.owndata


def test_rgba_gets_a_channel_axis() -> None:
    px, fmt = decode_buffer(RawBuffer(0x02200016, 3, 2, bytes(range(24))))
    assert fmt == "RGBa8" and px.shape == (2, 3, 4) and list(px[1, 2]) == [20, 21, 22, 23]


@pytest.mark.parametrize("name", ["Mono12p", "Mono12Packed", "BayerRG12p", "Mono16", "RGB8"])
def test_padding_offset_and_announced_size_are_honoured(name: str) -> None:
    fmt = pixel_formats.FORMATS[name]
    rng = np.random.default_rng(7)
    shape = (5, 6, fmt.channels) if fmt.channels > 1 else (5, 6)
    img = rng.integers(0, 2 ** fmt.bits, shape).astype(fmt.dtype)
    body = pixel_formats.encode(img, name, padding_x=3)
    raw = b"\xAA" * 16 + body + b"\xFF" * 4096  # buffers are announced at the maximum payload
    px, got = decode_buffer(RawBuffer(fmt.code, 6, 5, raw, padding_x=3, image_offset=16,
                                      size_filled=16 + len(body)))
    assert got == name and np.array_equal(px, img)


def test_short_or_unknown_buffers_are_errors() -> None:
    with pytest.raises(DeviceError, match=r"Mono8 buffer of 10 bytes is too short for 4x3 \(needs 12"):
        decode_buffer(RawBuffer(0x01080001, 4, 3, bytes(100), size_filled=10))
    with pytest.raises(DeviceError, match=r"pixel format code 0x0110002E is not supported") as info:
        decode_buffer(RawBuffer(0x0110002E, 4, 3, bytes(100)))
    assert info.value.code == "bad_buffer"


def test_describe_names_serial_model_and_user_name() -> None:
    text = describe({"serial_number": "223600123", "model": "PHX122S-M", "user_defined_name": "nadir",
                     "id_": "x"})
    assert "serial='223600123'" in text and "model='PHX122S-M'" in text and "name='nadir'" in text
