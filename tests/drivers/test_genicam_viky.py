"""GenICamCamera against viky.cti, the simulated GenTL producer shipped in the genicam wheel.

viky offers three devices (serials '0', '1', '2'), Width/Height 100..800,
PixelFormat Mono8/RGBa8 and AcquisitionFrameRate 1..200, but no exposure, gain,
trigger, PTP or timestamps. harvesters allows one Harvester per producer per
process, so every test closes its camera (the fixture does) before the next opens.
"""
from __future__ import annotations

import glob
import os
import time
from typing import Any, Iterator

import numpy as np
import pytest

from daemon.ritad.registry import adapter_class
from drivers.base import DeviceError, DeviceLost, DeviceURL, Frame
from drivers.camera_settings import CameraSettings
from drivers.genicam import GenICamCamera, select_device
from tools.harness.load import hang_s


def configure(cam: GenICamCamera, settings: CameraSettings) -> None:
    """New desired settings applied to the open camera now, as a reconnect would apply them (ritad never
    changes them while running: they come from its config)."""
    cam.settings = settings
    streaming = cam._streaming
    cam._stop_acquisition()
    cam._streaming = False
    cam._apply()
    if streaming:
        cam.start_stream()
    elif cam._software:
        cam._start_acquisition()


pytestmark = pytest.mark.timeout(60)


def _viky() -> str:
    import genicam

    root = os.path.dirname(genicam.__file__)
    found = sorted(glob.glob(os.path.join(root, "**", "viky.cti"), recursive=True))
    if not found:
        pytest.fail(f"viky.cti not found under {root}: the genicam wheel is a required dependency "
                    "(pip install genicam>=1.6)")
    return found[0]


VIKY = _viky()


LINK: list[dict[str, Any]] = []  # camera.link messages of the camera under test


def make(query: str = "serial=1", settings: CameraSettings | None = None,
         sink: list[Frame] | None = None) -> GenICamCamera:
    def emit(topic: str, payload: Any) -> None:
        if topic == "camera.link":
            LINK.append(payload)  # type: ignore[arg-type]
            return
        assert topic == "camera.frame"
        if sink is not None:
            sink.append(payload)

    url = DeviceURL.parse(f"genicam://{VIKY}?{query}" if query else f"genicam://{VIKY}")
    return GenICamCamera(url, emit=emit, settings=settings)


SMALL = CameraSettings(pixel_format="Mono8", width=320, height=240, frame_rate_hz=200.0)


@pytest.fixture
def frames() -> list[Frame]:
    return []


@pytest.fixture
def cam(frames: list[Frame]) -> Iterator[GenICamCamera]:
    c = make(settings=SMALL, sink=frames)
    c.open()
    try:
        yield c
    finally:
        c.close()


def pump_until(cam: GenICamCamera, frames: list[Frame], n: int, limit_s: float = hang_s(5.0)) -> None:
    end = time.monotonic() + limit_s  # only catches a hang (tools/harness/load.py)
    while len(frames) < n:
        assert time.monotonic() < end, f"only {len(frames)} of {n} frames within {limit_s} s"
        cam.pump(0.05)


# ------------------------------------------------------------------ selection


def test_registry_resolves_genicam_scheme() -> None:
    assert adapter_class("camera", DeviceURL.parse(f"genicam://{VIKY}")) is GenICamCamera


def test_select_by_serial() -> None:
    c = make("serial=1")
    try:
        c.open()
        assert c.status()["serial"] == "1"
        assert c.info()["model"] == "Viky"
        assert c.info()["id_"] == "VikyTL_DEV_green"
    finally:
        c.close()


def test_select_by_index() -> None:
    c = make("index=2")
    try:
        c.open()
        assert c.status()["serial"] == "2"
    finally:
        c.close()


def test_missing_serial_lists_the_three_devices_and_releases_the_producer() -> None:
    c = make("serial=9")
    with pytest.raises(DeviceLost) as err:
        c.open()
    msg = str(err.value)
    assert "serial='9'" in msg
    for s in ("0", "1", "2"):
        assert f"serial={s!r} model='Viky'" in msg
    assert err.value.code == "no_device"
    # the failed open reset its Harvester, so the producer can be loaded again
    ok = make("serial=0")
    try:
        ok.open()
        assert ok.status()["serial"] == "0"
    finally:
        ok.close()


def test_name_that_viky_cannot_report_is_not_silently_ignored() -> None:
    # harvesters' own dict filter skips keys a producer cannot answer; ours must not
    c = make("name=left")
    with pytest.raises(DeviceLost, match=r"no camera with name='left'.*serial='2'"):
        c.open()


def test_no_selection_with_three_devices_is_ambiguous() -> None:
    c = make("")
    with pytest.raises(DeviceError, match=r"3 cameras found.*serial='0'.*serial='1'.*serial='2'") as err:
        c.open()
    assert err.value.code == "ambiguous_device"


def test_duplicate_serials_are_ambiguous() -> None:
    infos = [{"serial_number": "7", "model": "A"}, {"serial_number": "7", "model": "B"}]
    with pytest.raises(DeviceError, match="2 cameras match serial='7'"):
        select_device(infos, "7", None, None)
    assert select_device(infos, None, None, 1) == 1
    with pytest.raises(DeviceLost, match="index=5 does not exist"):
        select_device(infos, None, None, 5)


@pytest.mark.parametrize("query, needle", [
    ("serial=1&colour=red", "unknown option 'colour'"),
    ("num_buffers=0", "num_buffers=0"),
    ("timeout=abc", "timeout='abc'"),
    ("index=-1", "index=-1"),
])
def test_bad_url_options_are_named(query: str, needle: str) -> None:
    with pytest.raises(ValueError) as err:
        make(query)
    assert needle in str(err.value)


def test_url_must_name_a_cti_and_it_must_exist() -> None:
    with pytest.raises(ValueError, match=r"\.cti"):
        GenICamCamera(DeviceURL.parse("genicam:///opt/nothing"))
    c = GenICamCamera(DeviceURL.parse("genicam:///opt/nowhere/GenTL_LUCID.cti?serial=1"))
    with pytest.raises(DeviceError, match="GenTL_LUCID.cti' not found") as err:
        c.open()
    assert err.value.code == "no_producer"


# ------------------------------------------------------------------ settings


def test_settings_viky_has_are_applied(cam: GenICamCamera) -> None:
    applied = cam.status()["applied"]
    assert applied["PixelFormat"] == "Mono8"
    assert (applied["Width"], applied["Height"]) == (320, 240)
    assert applied["AcquisitionFrameRate"] == pytest.approx(200.0)
    frame = cam.trigger(timeout=2.0)
    assert frame.pixels.shape == (240, 320) and frame.pixels.dtype == np.uint8
    assert frame.pixel_format == "Mono8"


def test_warnings_for_features_viky_lacks(cam: GenICamCamera) -> None:
    warnings = "\n".join(cam.status()["warnings"])
    for feature in ("ExposureTime", "Gain", "TriggerSelector", "TriggerMode", "TriggerSource",
                    "TriggerSoftware"):
        assert f"camera has no {feature}" in warnings
    assert "trigger() takes the next free-run frame" in warnings
    assert "PtpEnable" not in warnings  # ptp=None: left alone
    assert cam.status()["software_trigger"] is False
    configure(cam, CameraSettings(pixel_format="Mono8", ptp=True, exposure_us=None, gain_db=None,
                                 frame_rate_hz=None, trigger="free"))
    warnings = cam.status()["warnings"]
    assert warnings == ["camera has no PtpEnable; PtpEnable=True not applied"]


def test_unchanged_settings_are_not_rewritten(cam: GenICamCamera) -> None:
    before = cam.status()
    configure(cam, SMALL)
    after = cam.status()
    assert after["applies"] == before["applies"] + 1
    assert after["writes"] == before["writes"]
    configure(cam, CameraSettings(pixel_format="Mono8", width=300, height=240, frame_rate_hz=200.0))
    assert cam.status()["writes"] == after["writes"] + 1
    assert cam.trigger(timeout=2.0).pixels.shape == (240, 300)


def test_rgba_frames_have_a_channel_axis(cam: GenICamCamera) -> None:
    configure(cam, CameraSettings(pixel_format="RGBa8", width=200, height=100, frame_rate_hz=200.0))
    frame = cam.trigger(timeout=2.0)
    assert frame.pixels.shape == (100, 200, 4)
    assert frame.pixel_format == "RGBa8"


def test_bad_settings_raise_clear_errors(cam: GenICamCamera) -> None:
    with pytest.raises(DeviceError, match=r"Width=5000 is outside the camera's range 100\.\.800"):
        configure(cam, CameraSettings(width=5000))
    with pytest.raises(DeviceError, match=r"no PixelFormat 'Mono16' \(it offers RGBa8, Mono8\)"):
        configure(cam, CameraSettings(pixel_format="Mono16"))
    with pytest.raises(DeviceError, match=r"PixelFormat 'BayerRG10' cannot be decoded \(supported: Mono8, "):
        configure(cam, CameraSettings(pixel_format="BayerRG10"))
    with pytest.raises(DeviceError, match="trigger setting 'hardware'"):
        configure(cam, CameraSettings(trigger="hardware"))
    configure(cam, CameraSettings(frame_rate_hz=500.0))
    assert cam.status()["applied"]["AcquisitionFrameRate"] == pytest.approx(200.0)
    assert any("AcquisitionFrameRate=500" in w and "using 200" in w for w in cam.status()["warnings"])


# ------------------------------------------------------------------ acquisition


def test_fallback_trigger_returns_fresh_frames(cam: GenICamCamera) -> None:
    a = cam.trigger(timeout=2.0)
    b = cam.trigger(timeout=2.0)
    assert b.host_monotonic_ns > a.host_monotonic_ns
    assert a.camera_serial == "1"
    assert a.device_time_ns is None  # viky has no timestamps
    assert a.exposure_us is None  # nor ExposureTime
    assert cam.status()["acquiring"] is False  # the fallback stops after its frame
    with pytest.raises(DeviceError, match="not open"):
        make().trigger()


def test_free_run_streaming(cam: GenICamCamera, frames: list[Frame]) -> None:
    cam.start_stream()
    assert cam.status()["streaming"]
    pump_until(cam, frames, 20)
    ids = [f.frame_id for f in frames]
    assert all(b > a for a, b in zip(ids, ids[1:])), ids
    assert all(f.pixels.shape == (240, 320) for f in frames)
    assert all(f.incomplete_count == 0 for f in frames)
    times = [f.host_monotonic_ns for f in frames]
    assert times == sorted(times)
    # a trigger while streaming takes the next streamed frame
    assert cam.trigger(timeout=2.0).frame_id > ids[-1]
    cam.stop_stream()
    assert not cam.status()["streaming"]
    n = len(frames)
    cam.pump(0.1)
    assert len(frames) == n


def test_frames_are_copies_that_survive_requeue(cam: GenICamCamera, frames: list[Frame]) -> None:
    configure(cam, CameraSettings(pixel_format="Mono8", width=400, height=400, frame_rate_hz=200.0))
    cam.start_stream()
    pump_until(cam, frames, 3)
    kept = frames[:3]
    snapshots = [f.pixels.copy() for f in kept]
    # many more frames than the 4 GenTL buffers: each buffer is rewritten several times
    pump_until(cam, frames, 3 + 5 * cam.num_buffers)
    for f, snap in zip(kept, snapshots):
        assert f.pixels.flags.owndata
        assert np.array_equal(f.pixels, snap)
    # the content moves (bouncing ball), so equality above is not trivially true
    assert any(not np.array_equal(frames[0].pixels, f.pixels) for f in frames[1:])


def test_stop_start_cycles(cam: GenICamCamera, frames: list[Frame]) -> None:
    for cycle in range(5):
        frames.clear()
        cam.start_stream()
        pump_until(cam, frames, 2)
        cam.stop_stream()
        assert frames[0].frame_id < frames[1].frame_id, f"cycle {cycle}"
    cam.stop_stream()  # no error when already stopped


def test_close_and_open_again_reapplies(cam: GenICamCamera) -> None:
    cam.close()
    cam.close()  # safe twice
    assert cam.status()["open"] is False
    with pytest.raises(DeviceError, match="not open"):
        cam.trigger()
    cam.open()
    s = cam.status()
    assert (s["opens"], s["applies"]) == (2, 2)
    assert s["applied"]["Width"] == 320
    assert cam.trigger(timeout=2.0).pixels.shape == (240, 320)


def test_stream_resumes_after_reopen(cam: GenICamCamera, frames: list[Frame]) -> None:
    cam.start_stream()
    cam.close()
    cam.open()
    assert cam.status()["streaming"]
    pump_until(cam, frames, 2)


def test_fetch_error_is_device_lost_and_reopen_recovers(cam: GenICamCamera,
                                                        frames: list[Frame]) -> None:
    from genicam import gentl

    cam.start_stream()
    pump_until(cam, frames, 1)

    def broken(**kwargs: Any) -> None:
        raise gentl.IoException("link down")

    cam._ia.try_fetch = broken  # type: ignore[union-attr,method-assign]
    with pytest.raises(DeviceLost, match="lost during fetch"):
        cam.pump(0.1)
    cam.close()
    cam.open()
    frames.clear()
    pump_until(cam, frames, 2)


def test_stalled_stream_is_device_lost() -> None:
    c = make("serial=1&timeout=0.3", settings=SMALL)
    try:
        c.open()
        c.start_stream()
        c._ia.try_fetch = lambda timeout, **kw: time.sleep(timeout)  # type: ignore[union-attr,method-assign]
        t0 = time.monotonic()
        with pytest.raises(DeviceLost, match="no frame for"):
            while time.monotonic() - t0 < 3.0:
                c.pump(0.05)
        assert time.monotonic() - t0 >= 0.3
    finally:
        c.close()


def test_incomplete_buffer_callback_is_counted(cam: GenICamCamera, frames: list[Frame]) -> None:
    # viky never delivers incomplete buffers; fire the event harvesters raises for one
    from harvesters.core import ImageAcquirer

    cam._ia._emit_callbacks(ImageAcquirer.Events.INCOMPLETE_BUFFER)  # type: ignore[union-attr]
    assert cam.status()["incomplete_count"] == 1
    # viky's stream has no link counters: the incomplete frames are the adapter's count
    link = cam.status()["link"]
    assert link["incomplete_frames"] == 1 and link["source"]["incomplete_frames"] == "adapter"
    assert link["resend_requests"] is None and link["source"]["resend_requests"] is None
    cam.start_stream()
    pump_until(cam, frames, 1)
    assert frames[0].incomplete_count == 1
    LINK.clear()
    cam._next_status_poll = 0.0  # the link is read at the access poll's once-a-second pace
    cam.pump(0.05)
    cam._ia._emit_callbacks(ImageAcquirer.Events.INCOMPLETE_BUFFER)  # type: ignore[union-attr]
    cam._next_status_poll = 0.0
    cam.pump(0.05)
    assert [m["incomplete_frames"] for m in LINK] == [2]


def test_viky_reports_ptp_unavailable_and_missing_transport_nodes(cam: GenICamCamera) -> None:
    assert cam.status()["ptp"] == {"available": False}
    configure(cam, CameraSettings(pixel_format="Mono8", exposure_us=None, gain_db=None, frame_rate_hz=None,
                                 trigger="free", packet_size=9000, throughput_limit_bytes_s=100_000_000,
                                 packet_resend=True, stream_buffers=6, chunks=False))
    warnings = cam.status()["warnings"]
    assert "camera has no GevSCPSPacketSize; packet_size=9000 not applied" in warnings
    assert ("camera has no DeviceLinkThroughputLimit; throughput_limit_bytes_s=100000000 not applied"
            in warnings)
    assert ("the GenTL producer's stream has no StreamPacketResendEnable; StreamPacketResendEnable=True "
            "not applied") in warnings
    assert cam.status()["applied"]["StreamBufferCount"] == 6
    assert cam.status()["applied"]["ChunkModeActive"] is False  # viky has chunk mode on by default


def test_access_status_change_is_device_lost(cam: GenICamCamera) -> None:
    assert cam._ia.device.module.access_status == 5  # type: ignore[union-attr]  # OPEN_READWRITE
    cam._access = 1  # pretend the status recorded at open differed from what the device says now
    with pytest.raises(DeviceLost, match="access status changed from 1 to 5"):
        cam._check_access(force=True)
