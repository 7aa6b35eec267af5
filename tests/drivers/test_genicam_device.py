"""Pixel copying of GenTL image components, on plain numpy data (no producer needed)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from drivers.base import DeviceError
from drivers.genicam_device import describe, to_pixels


@dataclass
class Component:
    width: int
    height: int
    num_components_per_pixel: float
    data: np.ndarray


def test_mono_is_copied_and_reshaped() -> None:
    data = np.arange(12, dtype=np.uint8)
    px = to_pixels(Component(4, 3, 1.0, data))
    assert px.shape == (3, 4)
    assert px[2, 3] == 11
    data[:] = 0  # the producer reuses its buffer
    assert px[2, 3] == 11 and px.flags.owndata


def test_colour_gets_a_channel_axis() -> None:
    data = np.arange(2 * 3 * 4, dtype=np.uint8)
    px = to_pixels(Component(3, 2, 4.0, data))
    assert px.shape == (2, 3, 4)
    assert list(px[1, 2]) == [20, 21, 22, 23]


def test_line_padding_is_stripped() -> None:
    # 3 rows of 4 pixels, each followed by 2 padding bytes (harvesters leaves them in)
    rows = np.arange(12, dtype=np.uint16).reshape(3, 4)
    padded = np.hstack([rows, np.full((3, 2), 999, dtype=np.uint16)]).ravel()
    px = to_pixels(Component(4, 3, 1.0, padded))
    assert np.array_equal(px, rows)


def test_short_buffer_is_an_error() -> None:
    with pytest.raises(DeviceError, match=r"holds 10 values, expected 3x4x1"):
        to_pixels(Component(4, 3, 1.0, np.zeros(10, np.uint8)))


def test_describe_names_serial_model_and_user_name() -> None:
    text = describe({"serial_number": "223600123", "model": "PHX122S-M", "user_defined_name": "nadir",
                     "id_": "x"})
    assert "serial='223600123'" in text and "model='PHX122S-M'" in text and "name='nadir'" in text
