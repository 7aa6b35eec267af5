"""Camera frames on the host's timeline: PTP when the camera's port is locked, else the clock map.

The sim camera (fakes/camera.py) runs its own clock (fakes/camera_clock.py: an offset, a drift,
PTP time when locked) and knows each exposure's true mid-time (``sim_t_mid_ns``). Here the true
time is simulated, so nothing depends on the machine's speed: each frame starts a frame period
after the last, its latency is a seeded draw.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from daemon.bus.clockmap import TAI_MINUS_UTC_S
from daemon.ritad import config
from daemon.ritad.device_clock import PTP_FLOOR_NS, DeviceClock
from drivers.base import DeviceURL, Frame
from drivers.camera_settings import CameraSettings
from fakes.camera import SimCamera
from tests.ritad_up import SMALL_CAMERA, ritad_in_process

pytestmark = pytest.mark.timeout(120)

T0 = 1_795_000_000_000_000_000  # UTC ns, late 2026
DRIFTING = "clock_offset_s=1234.5&clock_drift_ppm=50"


class SimTime:
    def __init__(self) -> None:
        self.t = T0

    def __call__(self) -> int:
        return self.t


def sim_camera(query: str, settings: CameraSettings | None = None) -> tuple[SimCamera, SimTime]:
    now = SimTime()
    cam = SimCamera(DeviceURL.parse(f"sim:?size=32x24&prerender=1&noise=0&{query}"), settings=settings)
    cam.clock.now_ns, cam.clock.power_up_ns = now, now.t
    cam.open()
    return cam, now


def run(cam: SimCamera, now: SimTime, clock: DeviceClock, n: int, fps: float = 9.0,
        exposures: tuple[float, ...] = (2000.0,)) -> tuple[np.ndarray, np.ndarray, list[Frame]]:
    """``n`` triggered frames a frame period apart (the exposure switching every 50 frames):
    each frame's error against the truth and its stated sigma."""
    errors, sigmas, frames = [], [], []
    for i in range(n):
        if i % 50 == 0 and len(exposures) > 1:
            cam.configure(CameraSettings(ptp=cam.settings.ptp if cam.settings else None,
                                         exposure_us=exposures[(i // 50) % len(exposures)]))
        now.t += int(1e9 / fps)
        frame = clock.stamp_frame(cam.trigger())
        assert frame.t_ns is not None and frame.t_sigma_ns is not None
        errors.append(frame.t_ns - frame.extra["sim_t_mid_ns"])
        sigmas.append(frame.t_sigma_ns)
        frames.append(frame)
    return np.array(errors, dtype=float), np.array(sigmas, dtype=float), frames


def test_ptp_locked_frames_are_within_10_us_of_the_exposure_mid_time() -> None:
    cam, now = sim_camera(f"{DRIFTING}&ptp=Slave&ptp_offset_ns=400&latency_ms=5", CameraSettings(ptp=True))
    clock = DeviceClock()
    errors, sigmas, frames = run(cam, now, clock, 300, exposures=(2000.0, 8000.0))
    assert {f.t_source for f in frames} == {"ptp"}
    assert frames[0].device_time_ns - frames[0].extra["sim_t_mid_ns"] > (TAI_MINUS_UTC_S - 1) * 10**9  # TAI
    assert np.abs(errors).max() <= 10_000, np.abs(errors).max()
    assert np.all(np.abs(errors) <= sigmas) and sigmas.min() >= PTP_FLOOR_NS
    st = clock.status()
    assert st["source"] == "ptp" and st["offset_ns"] == -TAI_MINUS_UTC_S * 10**9 and st["note"] is None, st
    assert st["ptp"]["status"] == "Slave" and st["samples"] == 300, st  # the map is fed all the same


def test_without_ptp_the_clock_map_is_within_half_a_millisecond_and_covered() -> None:
    cam, now = sim_camera(f"{DRIFTING}&latency_ms=5")
    clock = DeviceClock()
    errors, sigmas, frames = run(cam, now, clock, 9 * 600, exposures=(2000.0, 8000.0))  # 10 minutes at 9 fps
    assert {f.t_source for f in frames} == {"clockmap"}
    p99 = float(np.percentile(np.abs(errors), 99))
    covered = float(np.mean(np.abs(errors) <= 3 * sigmas))
    print(f"clockmap: p50 {np.median(np.abs(errors)) / 1e3:.1f} us, p99 {p99 / 1e3:.1f} us, "
          f"max {np.abs(errors).max() / 1e3:.1f} us, 3 sigma covers {covered:.2%}, median sigma "
          f"{np.median(sigmas) / 1e3:.1f} us")
    assert p99 <= 500_000, p99
    assert covered >= 0.99, covered
    st = clock.status()
    assert st["source"] == "clockmap" and st["ptp"] == {"available": False} and st["note"] is None, st
    assert st["drift_ppm"] is not None and abs(st["drift_ppm"] + 50) < 1.0, st  # the device runs fast


@pytest.mark.parametrize("state", ["Listening", "Uncalibrated"])
def test_ptp_enabled_but_not_locked_falls_back_to_the_clock_map_and_says_so(state: str) -> None:
    cam, now = sim_camera(f"{DRIFTING}&ptp={state}&latency_ms=5", CameraSettings(ptp=True))
    clock = DeviceClock()
    errors, sigmas, frames = run(cam, now, clock, 9 * 60)
    assert {f.t_source for f in frames} == {"clockmap"}
    assert float(np.mean(np.abs(errors) <= 3 * sigmas)) >= 0.99
    assert float(np.percentile(np.abs(errors[9 * 10:]), 99)) <= 500_000  # after the map's first 10 s
    st = clock.status()
    assert st["source"] == "clockmap" and st["ptp"]["status"] == state, st
    assert f"PTP enabled but {state}" in st["note"], st


def test_a_camera_locking_onto_ptp_switches_source_and_restarts_the_map() -> None:
    cam, now = sim_camera(f"{DRIFTING}&ptp=Listening", CameraSettings(ptp=True))
    clock = DeviceClock()
    run(cam, now, clock, 50)
    cam.clock.ptp_state = "Slave"  # the port locks: the camera's clock jumps to PTP time
    errors, _, frames = run(cam, now, clock, 50)
    assert {f.t_source for f in frames} == {"ptp"} and np.abs(errors).max() <= 10_000
    st = clock.status()
    assert st["resets"] == 1 and st["samples"] == 50, st


def test_a_camera_without_timestamps_is_timed_by_arrival() -> None:
    from tests.drivers.test_genicam_viky import SMALL, make  # viky: no Timestamp, no PTP nodes

    frames: list[Frame] = []
    cam = make(settings=SMALL, sink=frames)
    cam.open()
    try:
        clock = DeviceClock()
        got = [clock.stamp_frame(cam.trigger()) for _ in range(3)]
    finally:
        cam.close()
    for f in got:
        assert f.device_time_ns is None and f.t_source == "host" and f.ptp == {"available": False}
        assert f.t_ns is not None and 0 < f.host_time_ns - f.t_ns < 10**9  # arrival less transfer
        assert {"t_ns", "t_sigma_ns", "t_source"} <= set(f.header())
    st = clock.status()
    assert st["source"] == "host" and st["samples"] == 0 and st["sigma_ns"] > 0, st


def test_ritad_frames_and_camera_status_carry_the_time(tmp_path: Path) -> None:
    def configure(cfg: config.Config) -> None:
        cfg.camera.ptp = True

    with ritad_in_process(tmp_path / "rt", tmp_path / "data", configure=configure,
                          camera=f"{SMALL_CAMERA}&{DRIFTING}&ptp=Slave") as (d, c):
        headers: list[dict[str, Any]] = [c.call("camera.capture", save=False)["header"] for _ in range(3)]
        st = c.call("camera.status")
        c.call("camera.stream.start")
        try:
            end = time.monotonic() + 20
            while d.frames.last_frame is None:  # streamed frames are stamped as they are published
                assert time.monotonic() < end, "no streamed frame within 20 s"
                time.sleep(0.05)
        finally:
            c.call("camera.stream.stop")
        headers.append(d.frames.last_frame.header())
    for h in headers:
        assert h["t_source"] == "ptp" and abs(h["t_ns"] - h["sim_t_mid_ns"]) <= 10_000, h
        assert PTP_FLOOR_NS <= h["t_sigma_ns"] < 10_000, h
    assert st["ptp"]["status"] == "Slave" and st["applied"]["PtpEnable"] is True
    clock = st["clock"]
    assert clock["source"] == "ptp" and clock["samples"] == 3 and clock["offset_ns"] == -TAI_MINUS_UTC_S * 10**9, clock


def test_a_host_off_the_cameras_ptp_time_is_named_in_status() -> None:
    cam, now = sim_camera(f"{DRIFTING}&ptp=Slave", CameraSettings(ptp=True))
    clock = DeviceClock()
    real_device_ns = cam.clock.device_ns
    cam.clock.device_ns = lambda h: real_device_ns(h) - TAI_MINUS_UTC_S * 10**9  # a master on UTC, not TAI
    run(cam, now, clock, 20)
    st = clock.status()
    assert st["source"] == "ptp" and "disagree by +37.0" in st["note"], st


def test_a_nan_exposure_does_not_stop_the_frame():
    """A bad chunk (NaN exposure) must not raise out of emit: the frame is stamped as if exposed instantly."""
    from daemon.ritad.device_clock import DeviceClock

    clock = DeviceClock()
    frame = Frame(np.zeros((2, 2), np.uint8), 1, "x", "Mono8", exposure_us=float("nan"),
                  device_time_ns=5_000_000_000, host_time_ns=1_800_000_000_000_000_000)
    out = clock.stamp_frame(frame)
    assert out.t_source == "clockmap" and out.t_ns is not None
