"""A Bayer colour sensor for the simulated camera (the paper's camera is an RGB one).

:class:`ColourRenderer` renders the scene once per colour channel with the same rays,
optics and geometry as :class:`fakes.render.Renderer`, blurs each channel by the PSF
(optics act before the colour filter), samples the result through an RGGB filter array
(PFNC ``BayerRG``: row 0 = R G, row 1 = G B, counted from the sensor's pixel (0, 0)),
and only then shades, adds noise per pixel and quantises, through the grey renderer's own
``render`` (so vignetting, black/white levels and the noise model are one code).

Scene colours (everything else stays neutral: the ChArUco target and the plate are
printed black on white, the floor marks too):

* nest rings: the red, green and blue patches (15, 14, 13) of the X-Rite ColorChecker
  Classic, sRGB values as published by X-Rite (post-2009 formulation), linearised by the
  sRGB transfer function. The paper identifies nests by red, green and blue rings.
* floor: the grey renderer's floor times :data:`FLOOR_RGB_GAIN`, a warm grey like bare
  concrete, whose reflectance rises from blue to red [unverified magnitude]. No acceptance
  figure depends on it (the target is neutral); it only makes demosaicing matter.

Differences from a real Bayer sensor: the three channels have equal sensitivity (as if the
camera's white balance, BalanceRatio, equalised them for the site's light; a raw mosaic
usually has unequal gains); no colour cross-talk, no chromatic aberration; the filter
responses are ideal R, G, B, so a channel sees exactly that channel's reflectance.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from calibration.image import to_rgb
from drivers import pixel_formats
from fakes.render import Renderer
from fakes.world import World

#: ColorChecker Classic sRGB (8-bit) of the patches used for the nest rings
COLORCHECKER_SRGB = {"red": (175, 54, 60), "green": (70, 148, 73), "blue": (56, 61, 150)}
#: floor albedo gain per channel (R, G, B) relative to the grey floor [unverified, see above]
FLOOR_RGB_GAIN = (1.06, 1.0, 0.88)
#: colour filter of each pixel of a 2x2 cell, row-major, for PFNC BayerRG: 0 = R, 1 = G, 2 = B
RGGB = ((0, 1), (1, 2))


def srgb_to_linear(value_8bit: float) -> float:
    """The sRGB transfer function inverted (IEC 61966-2-1)."""
    c = value_8bit / 255.0
    return c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4


RING_RGB = {name: tuple(srgb_to_linear(v) for v in rgb) for name, rgb in COLORCHECKER_SRGB.items()}


class ColourRenderer(Renderer):
    """Renders the world through an RGGB Bayer filter; ``render`` returns the raw mosaic."""

    def __init__(self, world: World, size: tuple[int, int], supersampling: int | None = None) -> None:
        super().__init__(world, size, supersampling)
        # the PSF is applied per channel in albedo(); render() must not blur the mosaic again
        self.optics_sigma, self.psf_sigma = self.psf_sigma, 0.0
        self._channel: int | None = None

    def _ring_albedo(self, name: str) -> float:
        return super()._ring_albedo(name) if self._channel is None else RING_RGB[name][self._channel]

    def _floor_texture(self, X: np.ndarray, Y: np.ndarray) -> np.ndarray:
        alb = super()._floor_texture(X, Y)
        return alb if self._channel is None else alb * FLOOR_RGB_GAIN[self._channel]

    def channel_albedo(self, abs_H_cam: np.ndarray, channel: int,
                       roi: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """One channel's albedo seen through the optics (PSF applied), float32 (h, w) of ``roi``."""
        x, y, rw, rh = self._check_roi(roi)
        W, H = self.size
        mg = int(math.ceil(4 * self.optics_sigma)) + 1
        ax, ay = max(0, x - mg), max(0, y - mg)
        bx, by = min(W, x + rw + mg), min(H, y + rh + mg)
        self._channel = channel
        try:
            alb = super().albedo(abs_H_cam, (ax, ay, bx - ax, by - ay))
        finally:
            self._channel = None
        if self.optics_sigma > 0:
            alb = cv2.GaussianBlur(alb, (0, 0), self.optics_sigma, borderType=cv2.BORDER_REFLECT)
        return alb[y - ay:y - ay + rh, x - ax:x - ax + rw]

    def albedo(self, abs_H_cam: np.ndarray, roi: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """The blurred albedo each pixel's colour filter passes (the mosaic before shading)."""
        x, y, rw, rh = self._check_roi(roi)
        cfa = np.asarray(RGGB)[np.ix_((np.arange(y, y + rh) % 2), (np.arange(x, x + rw) % 2))]
        out = np.empty((rh, rw), np.float32)
        for c in range(3):
            here = cfa == c
            out[here] = self.channel_albedo(abs_H_cam, c, (x, y, rw, rh))[here]
        return out


def sensor_image(renderer: Renderer, pixel_format: str, abs_H_cam: np.ndarray,
                 rng: np.random.Generator | None, noise: bool = True) -> np.ndarray:
    """What the camera delivers in ``pixel_format`` (decoded), from the matching renderer.

    Mono8/BayerRG8: 8-bit ADC output. Mono12p/BayerRG12p: 12-bit. Mono16: the 12-bit
    value shifted to the top of 16 bits [unverified how the PHX122S fills Mono16].
    RGB8: the camera demosaics its BayerRG8 mosaic itself (bilinear here).
    """
    fmt = pixel_formats.lookup(pixel_format)
    if fmt.colour != isinstance(renderer, ColourRenderer):
        raise ValueError(f"{pixel_format} needs a {'colour' if fmt.colour else 'grey'} renderer")
    bits = 8 if fmt.bits == 8 else 12
    img = renderer.render(abs_H_cam, rng=rng, noise=noise, bits=bits)
    if fmt.name == "Mono16":
        return (img << 4).astype(np.uint16)
    if fmt.name == "RGB8":
        return to_rgb(img, "BayerRG8")
    return img


__all__ = ["COLORCHECKER_SRGB", "ColourRenderer", "FLOOR_RGB_GAIN", "RING_RGB", "sensor_image",
           "srgb_to_linear"]
