"""SimCamera: rendered frames of the simulated world, free run, fault knobs, reconnects.

Only the first tests render at the reduced size (1000x750, ~1 s per frame); the
rest use a small image with the same field of view to stay fast.
"""
from __future__ import annotations

import threading
import time
from typing import Any

import numpy as np
import pytest

from daemon.ritad.registry import adapter_class, build_device
from drivers.base import DeviceError, DeviceLost, DeviceTimeout, DeviceURL, Frame
from drivers.camera_settings import CameraSettings
from fakes.camera import Pacing, SimCamera, renderer_for
from fakes.world import RobotPose, World, WorldParams
from fakes.worlds import sim_url

pytestmark = pytest.mark.timeout(120)

SMALL = "size=200x151"


def make(query: str, world: World | None = None, settings: CameraSettings | None = None,
         sink: list[Frame] | None = None, pacing: Pacing = time) -> SimCamera:
    def emit(topic: str, payload: Any) -> None:
        assert topic == "camera.frame"
        if sink is not None:
            sink.append(payload)

    url = sim_url(world, query) if world is not None else DeviceURL.parse(f"sim:?{query}")
    return SimCamera(url, emit=emit, settings=settings, pacing=pacing)


@pytest.fixture(scope="module")
def world() -> World:
    return World(WorldParams(seed=3))


def moved(world: World, dx_mm: float) -> RobotPose:
    r = world.robot
    return RobotPose(r.x_mm + dx_mm, r.y_mm, r.heading_deg)


# ------------------------------------------------------------------ rendering


def test_registry_and_default_world() -> None:
    assert adapter_class("camera", DeviceURL.parse("sim:")) is SimCamera
    cam = build_device("camera", f"sim:?{SMALL}", emit=lambda t, p: None)
    assert isinstance(cam.world, World)
    assert cam.size == (200, 151)


def test_reduced_trigger_is_the_rendered_view_at_the_current_pose(world: World) -> None:
    cam = make("noise=1", world)
    cam.open()
    start = world.robot
    try:
        f1 = cam.trigger()
        assert f1.pixels.shape == (750, 1000) and f1.pixels.dtype == np.uint8
        assert f1.header()["sim"] is True and f1.frame_id == 1
        # exactly the renderer's image with noise from world.rng("camera.noise")
        expect = renderer_for(world, (1000, 750)).render(world.abs_H_cam(), rng=world.rng("camera.noise"))
        assert np.array_equal(f1.pixels, expect)
        # the same pose again differs only by noise; a 3 mm move changes the content
        f2 = cam.trigger()
        world.set_robot(moved(world, 3.0))
        f3 = cam.trigger()
        noise = np.abs(f2.pixels.astype(int) - f1.pixels).mean()
        motion = np.abs(f3.pixels.astype(int) - f1.pixels).mean()
        assert 0.5 < noise < 5.0
        assert motion > 3 * noise
        assert f3.header()["sim_abs_H_cam"] != f1.header()["sim_abs_H_cam"]
    finally:
        world.set_robot(start)
        cam.close()


def test_same_seed_and_pose_give_identical_frames() -> None:
    a = make(SMALL, World(WorldParams(seed=11)))
    b = make(SMALL, World(WorldParams(seed=11)))
    c = make(SMALL, World(WorldParams(seed=12)))
    for cam in (a, b, c):
        cam.open()
    fa, fb, fc = a.trigger(), b.trigger(), c.trigger()
    assert np.array_equal(fa.pixels, fb.pixels)
    assert not np.array_equal(fa.pixels, fc.pixels)
    b.world.set_robot(moved(b.world, 2.0))
    assert not np.array_equal(a.trigger().pixels, b.trigger().pixels)


def test_exposure_gain_and_roi(world: World) -> None:
    base = make(f"{SMALL}&noise=0", world)
    base.open()
    ref = base.trigger().pixels.astype(float)
    dim = make(f"{SMALL}&noise=0", world, CameraSettings(exposure_us=1000.0))
    dim.open()
    assert np.allclose(dim.trigger().pixels, ref * 0.5, atol=1.0)  # half the exposure
    bright = make(f"{SMALL}&noise=0", world, CameraSettings(gain_db=20 * np.log10(2)))
    bright.open()
    assert np.allclose(bright.trigger().pixels, np.minimum(ref * 2.0, 255), atol=1.0)  # +6 dB
    roi = make(f"{SMALL}&noise=0", world, CameraSettings(width=64, height=40, offset_x=100, offset_y=30))
    roi.open()
    crop = roi.trigger().pixels
    assert crop.shape == (40, 64)
    assert np.array_equal(crop, ref[30:70, 100:164])
    assert roi.status()["applied"]["OffsetX"] == 100


@pytest.mark.parametrize("settings, needle", [
    (CameraSettings(pixel_format="Mono12"), "no PixelFormat 'Mono12'"),
    (CameraSettings(width=150, offset_x=100), "OffsetX=100 with Width=150 does not fit"),
    (CameraSettings(trigger="line0"), "trigger setting 'line0'"),
    (CameraSettings(exposure_us=0.0), "ExposureTime=0.0"),
])
def test_bad_settings_are_named(settings: CameraSettings, needle: str) -> None:
    cam = make(SMALL, settings=settings)
    with pytest.raises(DeviceError) as err:
        cam.open()
    assert needle in str(err.value)


@pytest.mark.parametrize("query, needle", [
    ("size=huge", "size='huge'"),
    ("fps=-2", "fps=-2"),
    ("noise=yes", "noise='yes'"),
    ("drop_every=-1", "drop_every=-1"),
    ("shutter=1", "unknown option 'shutter'"),
])
def test_bad_url_options_are_named(query: str, needle: str) -> None:
    with pytest.raises(ValueError) as err:
        make(query)
    assert needle in str(err.value)


def test_ptp_request_is_a_warning() -> None:
    cam = make(SMALL, settings=CameraSettings(ptp=True))
    cam.open()
    assert cam.status()["warnings"] == ["camera has no PtpEnable; PtpEnable=True not applied"]


# ------------------------------------------------------------------ free run


def pump_for(cam: SimCamera, seconds: float, clock: Any = time) -> None:
    end = clock.monotonic() + seconds
    while clock.monotonic() < end:
        cam.pump(min(0.05, max(0.0, end - clock.monotonic())))


class VirtualTime:
    """A camera's free-run pacing (``SimCamera(pacing=...)``): ``monotonic()`` moves only when its pump
    sleeps, so the rate it keeps is counted exactly, however busy the machine is (a render takes no
    virtual time; with the wall clock a loaded machine's late wake-ups cost frames, by design: the
    camera does not catch up). The frames' own stamps still come from the real clocks. Given to one
    camera, not patched into fakes.camera's ``time``: that reached every camera of the process, and an
    idle one pumped by a thread an earlier test left (a ritad's camera runner) slept its timeouts in no
    real time, racing this clock a second ahead between two frames (1 frame counted where 20 were due)."""

    def __init__(self) -> None:
        self.now = 1000.0

    def monotonic(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += max(0.0, seconds)


@pytest.fixture
def vtime() -> VirtualTime:
    return VirtualTime()


def test_free_run_rate(world: World, vtime: VirtualTime) -> None:
    frames: list[Frame] = []
    cam = make(f"{SMALL}&fps=20", world, sink=frames, pacing=vtime)
    cam.open()
    cam.pump(0.1)
    assert frames == []  # nothing before start_stream
    cam.start_stream()
    pump_for(cam, 1.0, vtime)
    assert 20 <= len(frames) <= 21  # one a period from the start (the last may fall on the end)
    ids = [f.frame_id for f in frames]
    assert ids == list(range(1, len(frames) + 1))
    cam.stop_stream()
    n = len(frames)
    cam.pump(0.1)
    assert len(frames) == n


def test_virtual_rate_holds_beside_another_camera_pumped_in_a_thread(world: World,
                                                                     vtime: VirtualTime) -> None:
    """The flake's mechanism, made certain: an idle camera pumped by another thread of the process on
    the real clock (as a ritad's camera runner an earlier test left) leaves this camera's count exact."""
    idle = make(SMALL, world)
    idle.open()
    stop = threading.Event()

    def runner() -> None:
        while not stop.is_set():
            idle.pump(0.2)  # not streaming: pump sleeps its whole timeout

    thread = threading.Thread(target=runner, daemon=True)
    thread.start()
    try:
        frames: list[Frame] = []
        cam = make(f"{SMALL}&fps=20", world, sink=frames, pacing=vtime)
        cam.open()
        cam.start_stream()
        pump_for(cam, 1.0, vtime)
        assert 20 <= len(frames) <= 21
        assert vtime.now == pytest.approx(1001.0, abs=0.06)  # only this camera's sleeps moved its clock
    finally:
        stop.set()
        thread.join(timeout=5)
    assert not thread.is_alive()


def test_settings_frame_rate_used_without_fps_option(vtime: VirtualTime) -> None:
    frames: list[Frame] = []
    cam = make(SMALL, settings=CameraSettings(frame_rate_hz=8.0), sink=frames, pacing=vtime)
    cam.open()
    cam.start_stream()
    pump_for(cam, 1.0, vtime)
    assert 8 <= len(frames) <= 9


def test_prerender_cycles_frames(world: World, vtime: VirtualTime) -> None:
    frames: list[Frame] = []
    cam = make(f"{SMALL}&prerender=2&fps=200", world, sink=frames, pacing=vtime)
    cam.open()
    assert cam.status()["renders"] == 2
    cam.start_stream()
    pump_for(cam, 0.2, vtime)
    assert len(frames) >= 40
    assert cam.status()["renders"] == 2
    assert np.array_equal(frames[0].pixels, frames[2].pixels)
    assert not np.array_equal(frames[0].pixels, frames[1].pixels)  # different noise
    frames[0].pixels[:] = 0  # each frame is the daemon's own copy
    assert frames[2].pixels.any()


# ------------------------------------------------------------------ fault knobs


def test_drop_every(world: World) -> None:
    cam = make(f"{SMALL}&drop_every=3", world)
    cam.open()
    got = []
    for _ in range(6):
        try:
            got.append(cam.trigger().frame_id)
        except DeviceTimeout as exc:
            assert "dropped" in str(exc)
    assert got == [1, 2, 4, 5]
    assert cam.status()["dropped"] == 2
    frames: list[Frame] = []
    cam.emit = lambda topic, f: frames.append(f)
    cam.start_stream()
    while len(frames) < 4:
        cam.pump(0.05)
    assert [f.frame_id for f in frames[:4]] == [7, 8, 10, 11]


def test_incomplete_every(world: World) -> None:
    cam = make(f"{SMALL}&incomplete_every=2", world)
    cam.open()
    frames = [cam.trigger() for _ in range(4)]
    assert [f.incomplete_count for f in frames] == [0, 1, 1, 2]
    for f in frames:
        zero_rows = int((f.pixels == 0).all(axis=1).sum())
        if f.frame_id % 2:
            assert zero_rows == 0 and "incomplete" not in f.extra
        else:
            assert 0 < zero_rows < f.pixels.shape[0]
            assert (f.pixels[-1] == 0).all() and f.extra["incomplete"] is True
    assert cam.status()["incomplete_count"] == 2


def test_disconnect_and_reopen_reapplies_settings(world: World) -> None:
    frames: list[Frame] = []
    cam = make(f"{SMALL}&disconnect_after=3&fps=100", world, CameraSettings(width=100, height=80),
               sink=frames)
    cam.open()
    for _ in range(3):
        assert cam.trigger().pixels.shape == (80, 100)
    with pytest.raises(DeviceLost, match="after 3 frames"):
        cam.trigger()
    with pytest.raises(DeviceLost):
        cam.pump(0.01)
    with pytest.raises(DeviceLost):
        cam.start_stream()
    s = cam.status()
    assert s["lost"] and s["disconnects"] == 1
    # the daemon changes its desired settings while the camera is away
    cam.settings = CameraSettings(width=60, height=40)
    cam.close()
    cam.open()
    s = cam.status()
    assert (s["opens"], s["applies"], s["lost"]) == (2, 2, False)
    cam.start_stream()
    with pytest.raises(DeviceLost):
        for _ in range(100):
            cam.pump(0.05)
    assert all(f.pixels.shape == (40, 60) for f in frames)
    assert [f.frame_id for f in frames] == [4, 5, 6]  # ids run on across reconnects
    assert cam.status()["disconnects"] == 2


def test_stream_resumes_after_reopen() -> None:
    frames: list[Frame] = []
    cam = make(f"{SMALL}&fps=50", sink=frames)
    cam.open()
    cam.start_stream()
    cam.close()
    with pytest.raises(DeviceError, match="not open"):
        cam.trigger()
    cam.open()
    assert cam.status()["streaming"]
    while len(frames) < 2:
        cam.pump(0.05)
