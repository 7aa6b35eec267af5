"""The GigE link model (fakes/gige_link.py) and the sim camera's transport settings, link statistics,
PTP status and chunk data."""
from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from drivers.base import DeviceError, DeviceURL
from drivers.camera_settings import CameraSettings
from fakes.camera import SimCamera
from fakes.gige_link import GigELink, LinkSettings

pytestmark = pytest.mark.timeout(60)

SMALL = "size=200x151&noise=0&prerender=1"
RECOMMENDED = CameraSettings(packet_size=9000, throughput_limit_bytes_s=110_000_000, packet_resend=True,
                             stream_buffers=8, chunks=True)


def make(query: str, settings: CameraSettings | None = None,
         sink: list[tuple[str, Any]] | None = None) -> SimCamera:
    def emit(topic: str, payload: Any) -> None:
        if sink is not None:
            sink.append((topic, payload))

    return SimCamera(DeviceURL.parse(f"sim:?{query}"), emit=emit, settings=settings)


def test_packets_per_frame_and_wire_time_follow_the_packet_size() -> None:
    link = GigELink(np.random.default_rng(0))
    ok, t = link.send(12_216_864, LinkSettings(packet_size=1500))
    assert ok and link.counters["packets"] == 8345  # ceil(12216864 / 1464): the issue's ~8,300
    assert t == pytest.approx(8345 * 1538 / 125e6)
    ok, t9 = link.send(12_216_864, LinkSettings(packet_size=9000, throughput_limit_bytes_s=100_000_000))
    assert ok and link.counters["packets"] == 8345 + 1363
    assert t9 == pytest.approx(1363 * 9038 / 100e6)


def test_loss_resend_and_a_path_without_jumbo_frames() -> None:
    def run(s: LinkSettings, mtu: int = 9000) -> dict[str, int]:
        link = GigELink(np.random.default_rng(1), path_mtu=mtu, loss_at_line_rate=1e-4, loss_limited=1e-5)
        for _ in range(50):
            link.send(1_000_000, s)
        return link.counters

    plain = run(LinkSettings(packet_size=1500))
    assert plain["incomplete_frames"] > 0 and plain["resend_requests"] == 0
    resent = run(LinkSettings(packet_size=1500, resend=True))
    assert resent["resend_requests"] > 0 and resent["incomplete_frames"] < plain["incomplete_frames"]
    limited = run(LinkSettings(packet_size=9000, throughput_limit_bytes_s=110_000_000))
    assert limited["lost_packets"] < plain["lost_packets"]
    blocked = run(LinkSettings(packet_size=9000), mtu=1500)
    assert blocked["incomplete_frames"] == 50


def test_sim_camera_applies_the_transport_and_reports_link_and_ptp() -> None:
    cam = make(SMALL, RECOMMENDED)
    cam.open()
    st = cam.status()
    assert {k: st["applied"][k] for k in ("GevSCPSPacketSize", "DeviceLinkThroughputLimitMode",
                                          "DeviceLinkThroughputLimit", "StreamPacketResendEnable",
                                          "StreamBufferCount", "ChunkModeActive")} == {
        "GevSCPSPacketSize": 9000, "DeviceLinkThroughputLimitMode": "On",
        "DeviceLinkThroughputLimit": 110_000_000, "StreamPacketResendEnable": True,
        "StreamBufferCount": 8, "ChunkModeActive": True}
    assert st["ptp"] == {"available": False}
    assert st["link"]["incomplete_frames"] == 0 and st["link"]["source"]["lost_packets"] == "sim"
    h = cam.trigger().header()
    assert h["chunk_exposure_us"] == 2000.0 and h["chunk_gain_db"] == 0.0
    assert h["chunk_timestamp_ns"] == h["device_time_ns"]


def test_sim_auto_packet_size_is_what_the_path_passes_and_bad_values_are_named() -> None:
    cam = make(f"{SMALL}&path_mtu=1500", CameraSettings(packet_size="auto"))
    cam.open()
    assert cam.status()["applied"]["GevSCPSPacketSize"] == 1500
    cam.configure(CameraSettings(throughput_limit_bytes_s=500_000_000))
    assert cam.status()["warnings"] == ["DeviceLinkThroughputLimit=500000000 is outside the camera's range "
                                        "31250000..125000000; using 125000000"]
    with pytest.raises(DeviceError,
                       match=r"GevSCPSPacketSize=20000 is outside the camera's range 576\.\.9000"):
        cam.configure(CameraSettings(packet_size=20000))
    with pytest.raises(ValueError, match="packet_loss=2.0"):
        make("packet_loss=2")


def test_a_struggling_link_shows_in_status_frames_and_telemetry() -> None:
    sink: list[tuple[str, Any]] = []
    cam = make(f"{SMALL}&fps=200&path_mtu=1500", CameraSettings(packet_size=9000, trigger="free"), sink)
    cam.open()
    cam.start_stream()
    cam.pump(0.1)
    frames = [p for t, p in sink if t == "camera.frame"]
    links = [p for t, p in sink if t == "camera.link"]
    assert frames and all(f.extra.get("incomplete") for f in frames)
    assert cam.status()["link"]["incomplete_frames"] == len(frames)
    assert links and links[0]["incomplete_frames"] >= 1 and links[0]["serial"] == "SIM-0001"
