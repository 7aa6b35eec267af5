"""The simulated camera's colour (RGGB Bayer) sensor and its pixel formats.

Small images (same field of view) keep this fast: one ray cache per size, shared.
"""
from __future__ import annotations

import numpy as np
import pytest

from calibration.frames import apply_H, inv_H
from calibration.image import to_rgb
from drivers.base import DeviceError, DeviceURL
from drivers.camera_settings import CameraSettings
from fakes.camera import PIXEL_FORMATS, SimCamera
from fakes.colour import RING_RGB, ColourRenderer
from fakes.render import Renderer, world_camera_model
from fakes.world import World, WorldParams
from fakes.worlds import sim_url

pytestmark = pytest.mark.timeout(120)
SIZE = (400, 300)


@pytest.fixture(scope="module")
def world() -> World:
    return World(WorldParams(seed=5))


def frames(world: World, formats: tuple[str, ...], query: str = "size=200x151&noise=0",
           **settings) -> dict[str, np.ndarray]:
    """One frame per pixel format at the same pose (noise off, so they are comparable)."""
    cam = SimCamera(sim_url(world, query), settings=CameraSettings(**settings))
    cam.open()
    out = {}
    for fmt in formats:
        cam.configure(CameraSettings(pixel_format=fmt, **settings))
        f = cam.trigger()
        assert f.pixel_format == fmt and f.header()["pixel_format"] == fmt
        out[fmt] = f.pixels
    return out


def test_formats_quantise_the_same_signal(world: World) -> None:
    f = frames(world, PIXEL_FORMATS)
    mono8, mono12 = f["Mono8"].astype(float), f["Mono12p"].astype(float)
    assert f["Mono12p"].dtype == np.uint16 and f["Mono12p"].max() <= 4095
    assert np.abs(mono12 / 16 - mono8).max() <= 0.5 + 1e-9
    assert np.array_equal(f["Mono12Packed"], f["Mono12p"])
    assert np.array_equal(f["Mono16"], f["Mono12p"] << 4)
    assert f["BayerRG8"].shape == (151, 200) and f["BayerRG12p"].dtype == np.uint16
    assert np.abs(f["BayerRG12p"] / 16 - f["BayerRG8"]).max() <= 0.5 + 1e-9
    assert f["RGB8"].shape == (151, 200, 3)
    assert np.array_equal(f["RGB8"], to_rgb(f["BayerRG8"], "BayerRG8"))  # the camera demosaics


def test_exposure_scales_16_bit_formats_without_wrapping(world: World) -> None:
    f = frames(world, ("Mono12p", "Mono16"), exposure_us=20000.0)  # 10x: saturates
    assert f["Mono12p"].max() == 4095 and f["Mono16"].max() == 65535


def test_neutral_target_looks_the_same_through_the_bayer_filter(world: World) -> None:
    """On the black/white target the colour filter changes nothing: same optics, same shading."""
    grey, colour = Renderer(world, SIZE), ColourRenderer(world, SIZE)
    pose = world.abs_H_rob(world.pose_with_target_in_view(20.0)) @ world.rob_H_cam
    assert np.array_equal(grey.render(pose, noise=False), colour.render(pose, noise=False))


def test_rings_come_out_in_their_colour(world: World) -> None:
    r = ColourRenderer(world, SIZE)
    model = world_camera_model(world, SIZE)
    ang = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    for name, seat in world.nests_ref_true().items():
        foot = apply_H(world.abs_H_ref, seat)
        pose = world.abs_H_rob(world.pose_with_footprint_at(foot[0], foot[1], 0.0)) @ world.rob_H_cam
        rgb = to_rgb(r.render(pose, rng=np.random.default_rng(1)), "BayerRG8").astype(float)
        ring = np.column_stack([seat[0] + 11.5 * np.cos(ang), seat[1] + 11.5 * np.sin(ang), np.zeros(24)])
        uv = np.rint(model.project(apply_H(inv_H(pose) @ world.abs_H_ref, ring))).astype(int)
        mean = rgb[uv[:, 1], uv[:, 0]].mean(axis=0)
        k = int(np.argmax(RING_RGB[name]))
        others = [c for c in range(3) if c != k]
        assert mean[k] > 2 * mean[others].max(), (name, mean)


@pytest.mark.parametrize("settings,needle", [
    (CameraSettings(pixel_format="BayerRG10"), r"no PixelFormat 'BayerRG10' \(it offers Mono8, Mono12p, "),
    (CameraSettings(pixel_format="BayerRG8", offset_x=3, width=100), r"OffsetX=3 must be even for BayerRG8"),
])
def test_bad_colour_settings_are_named(settings: CameraSettings, needle: str) -> None:
    cam = SimCamera(DeviceURL.parse("sim:?size=200x151"), settings=settings)
    with pytest.raises(DeviceError, match=needle):
        cam.open()


def test_info_lists_the_offered_formats() -> None:
    cam = SimCamera(DeviceURL.parse("sim:?size=200x151"))
    assert cam.info()["pixel_formats"] == list(PIXEL_FORMATS)


def test_every_nest_has_a_ring_colour() -> None:
    from fakes.render import NEST_GREY

    assert set(RING_RGB) == set(NEST_GREY)
    assert all(max(rgb) == rgb[i]
               for i, rgb in zip((0, 1, 2), (RING_RGB[n] for n in ("red", "green", "blue"))))
