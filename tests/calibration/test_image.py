"""calibration.image: which OpenCV Bayer code fits which PFNC pattern, proved on synthetic mosaics."""
from __future__ import annotations

import numpy as np
import pytest

from calibration.image import infer_format, to_grey, to_rgb

# PFNC BayerXY: X Y are the first two pixels of row 0; row 1 holds the other two
PATTERNS = {"RG": "RGGB", "GR": "GRBG", "GB": "GBRG", "BG": "BGGR"}


def mosaic(rgb: np.ndarray, pattern: str) -> np.ndarray:
    """Sample an (h, w, 3) RGB scene through a 2x2 colour filter (pattern in row-major order)."""
    out = np.empty(rgb.shape[:2], rgb.dtype)
    for k, colour in enumerate(pattern):
        dy, dx = divmod(k, 2)
        out[dy::2, dx::2] = rgb[dy::2, dx::2, "RGB".index(colour)]
    return out


def scene(colour: tuple[int, int, int], dtype: type = np.uint8) -> np.ndarray:
    return np.broadcast_to(np.array(colour, dtype), (12, 16, 3)).copy()


@pytest.mark.parametrize("xy", sorted(PATTERNS))
@pytest.mark.parametrize("colour", [(200, 0, 0), (0, 200, 0), (0, 0, 200), (180, 90, 30)])
def test_a_coloured_scene_comes_out_in_its_colour(xy: str, colour: tuple[int, int, int]) -> None:
    raw = mosaic(scene(colour), PATTERNS[xy])
    rgb = to_rgb(raw, f"Bayer{xy}8")
    centre = rgb[4:8, 4:12].reshape(-1, 3)  # away from OpenCV's border handling
    assert np.abs(centre.astype(int) - colour).max() <= 1, (xy, colour, centre[0])


def test_pure_red_bayer_rg12p_is_red_and_16_bit_is_scaled() -> None:
    raw = mosaic(scene((4000, 0, 0), np.uint16), "RGGB")
    rgb = to_rgb(raw, "BayerRG12p")
    assert rgb.dtype == np.uint8
    assert rgb[6, 8].tolist() == [255, 0, 0]
    grey = to_grey(raw, "BayerRG12p")
    assert grey.dtype == np.uint8 and grey.shape == (12, 16)


def test_grey_of_a_neutral_mosaic_is_the_scene() -> None:
    ramp = np.tile(np.linspace(20, 220, 16).round().astype(np.uint8), (12, 1))
    raw = mosaic(np.dstack([ramp] * 3), "RGGB")  # a neutral scene: the mosaic is the grey image
    grey = to_grey(raw, "BayerRG8")
    assert np.abs(grey[2:-2, 2:-2].astype(int) - ramp[2:-2, 2:-2]).max() <= 1


def test_mono_and_rgb_and_old_images() -> None:
    mono12 = np.array([[0, 2048], [4095, 1000]], np.uint16)
    assert to_grey(mono12, "Mono12p").tolist() == [[0, 128], [255, 62]]
    assert infer_format(mono12) == "Mono16" and infer_format(mono12.astype(np.uint8)) == "Mono8"
    rgb = scene((255, 0, 0))
    assert to_rgb(rgb, "RGB8")[0, 0].tolist() == [255, 0, 0]
    assert to_grey(rgb, None)[0, 0] == 76  # OpenCV luma: 0.299 R


@pytest.mark.parametrize("image,fmt,needle", [
    (np.zeros((4, 4), np.uint8), "Mono8", "Mono8 carries no colour"),
    (np.zeros((4, 4), np.float32), "Mono8", "expected 8- or 16-bit pixels, got dtype float32"),
    (np.zeros((4, 4), np.uint8), "RGB8", r"shape \(4, 4\) is not \(h, w, 3\|4\)"),
    (np.zeros((4, 4), np.uint8), "YUV422_8", "'YUV422_8' is not a Mono, Bayer or RGB format"),
    (np.zeros((4, 4), np.uint8), "BayerXY8", "unknown Bayer pattern"),
])
def test_bad_input_is_named(image: np.ndarray, fmt: str, needle: str) -> None:
    with pytest.raises(ValueError, match=needle):
        to_rgb(image, fmt)
