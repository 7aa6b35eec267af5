"""The GenICam adapter against a producer and camera with documented variations (fakes/camera_producer.py).

Each test switches one behaviour on: a producer minimum of 8 buffers, another access-status convention,
buffers without timestamps (the chunk has the time), a PTP port that wins the master election, an SDK
that reports the link speed in Mbps, a camera left in SingleFrame mode by another program.
"""
from __future__ import annotations

import logging
import time
from pathlib import Path

import pytest

from drivers import genicam
from drivers.base import DeviceLost, DeviceURL
from drivers.camera_settings import CameraSettings
from drivers.genicam import GenICamCamera
from fakes.camera_producer import READWRITE, FakeHarvester, ProducerSpec

pytestmark = pytest.mark.timeout(30)


@pytest.fixture
def make(tmp_path: Path, monkeypatch: pytest.MonkeyPatch):
    cti = tmp_path / "GenTL_fake.cti"
    cti.write_bytes(b"")
    monkeypatch.setattr(genicam, "Harvester", FakeHarvester)
    made: list[GenICamCamera] = []

    def _make(spec: ProducerSpec, settings: CameraSettings | None = None, query: str = "") -> GenICamCamera:
        monkeypatch.setattr(FakeHarvester, "spec", spec)
        url = DeviceURL.parse(f"genicam://{cti}?{query}")
        cam = GenICamCamera(url, settings=settings or CameraSettings())
        made.append(cam)
        return cam

    yield _make
    for cam in made:
        cam.close()


def test_a_producer_minimum_above_the_buffer_count_raises_it_with_a_warning(make, caplog) -> None:
    cam = make(ProducerSpec(buffer_minimum=8))  # the URL's num_buffers: 4
    with caplog.at_level(logging.WARNING):
        cam.open()
    assert FakeHarvester.made[-1].num_buffers == 8
    want = "stream_buffers=4 is below the GenTL producer's minimum of 8 buffers; using 8"
    assert want in cam.status()["warnings"]


def test_an_open_device_reported_readwrite_is_not_lost_but_a_change_is(make) -> None:
    cam = make(ProducerSpec(access_status=READWRITE), CameraSettings(trigger="free"))
    cam.open()
    cam.start_stream()
    cam.pump(0.05)  # the first pump polls the access status
    cam._check_access(force=True)
    FakeHarvester.made[-1].lose()
    with pytest.raises(DeviceLost, match="access status changed from 1 to 3"):
        cam._check_access(force=True)


def test_without_buffer_timestamps_the_chunk_timestamp_is_the_device_time(make) -> None:
    cam = make(ProducerSpec(buffer_timestamps=False), CameraSettings(chunks=True))
    cam.open()
    frame = cam.trigger(timeout=2.0)
    assert frame.extra["chunk_timestamp_ns"] == 1_000_000_123
    assert frame.device_time_ns == 1_000_000_123


def test_a_camera_that_would_win_the_ptp_election_stays_slave_only(make) -> None:
    cam = make(ProducerSpec(camera={"ptp_wins_election": True}), CameraSettings(ptp=True))
    cam.open()
    assert cam.status()["ptp"]["status"] == "Listening"  # waiting for a master, never master itself


def test_a_link_speed_in_mbps_gives_the_wire_time_of_a_gigabit_link(make) -> None:
    cam = make(ProducerSpec(camera={"link_speed": 1000}))
    cam.open()
    frame = cam.trigger(timeout=2.0)
    w, h = 32, 24
    assert frame.transfer_ns == int(w * h * 1e9 / 125_000_000)
    assert any("DeviceLinkSpeed=1000" in m for m in cam.status()["warnings"])


def test_a_camera_left_in_single_frame_mode_streams_after_open(make) -> None:
    spec = ProducerSpec(camera={"left": {"AcquisitionMode": "SingleFrame"}})
    cam = make(spec, CameraSettings(trigger="free"))
    frames: list = []
    cam.emit = lambda topic, payload: frames.append(payload)
    cam.open()
    cam.start_stream()
    end = time.monotonic() + 5.0
    while len(frames) < 5 and time.monotonic() < end:
        cam.pump(0.05)
    assert len(frames) >= 5, f"{len(frames)} frames: the stream stalled"
