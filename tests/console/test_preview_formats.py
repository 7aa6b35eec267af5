"""The live view and the detector see every pixel format the camera may stream."""
from __future__ import annotations

import numpy as np
import pytest

from daemon.bus.protocol import CommandError
from daemon.ritad.detect import _gray8
from daemon.ritad.preview import display_grey
from drivers.base import Frame


def frame(pixels: np.ndarray, fmt: str) -> Frame:
    return Frame(pixels=pixels, frame_id=1, camera_serial="S", pixel_format=fmt)


@pytest.mark.parametrize("fmt, level, shown",
                         [("Mono8", 200, 200), ("Mono12p", 3200, 200), ("Mono16", 51200, 200)])
def test_live_view_shows_the_exposure_of_each_depth(fmt, level, shown):
    img = np.full((8, 10), level, np.uint8 if fmt == "Mono8" else np.uint16)
    out = display_grey(frame(img, fmt))
    assert out.dtype == np.uint8 and out.shape == (8, 10) and int(out[4, 5]) == shown


def test_bayer_and_rgb_are_shown_as_grey_not_as_a_mosaic():
    mosaic = np.zeros((8, 10), np.uint16)
    mosaic[0::2, 0::2] = 4000  # red sites of an RGGB mosaic: a red scene
    grey = display_grey(frame(mosaic, "BayerRG12p"))
    assert grey.shape == (8, 10) and np.ptp(grey[2:-2, 2:-2]) <= 2  # uniform, no checkerboard
    rgb = np.zeros((8, 10, 3), np.uint8)
    rgb[..., 1] = 200
    assert display_grey(frame(rgb, "RGB8")).shape == (8, 10)


def test_detector_input_is_scaled_grey_for_12_bit_frames():
    img = np.full((8, 10), 1000, np.uint16)
    img[2:4, 2:4] = 4000
    g = _gray8(frame(img, "Mono12p"))
    assert g.dtype == np.uint8 and g.max() == 255 and g.min() > 0  # not the near-black high byte


def test_a_frame_the_view_cannot_show_is_a_clear_refusal():
    with pytest.raises(CommandError, match="camera.preview: frames of shape"):
        display_grey(frame(np.zeros((2, 3, 4, 5), np.uint8), "Mono8"))
