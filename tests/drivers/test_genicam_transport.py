"""Chunks, GigE transport, PTP status and link statistics against the fake GenApi node maps.

The fake (fakes/genicam_nodes.py) logs every write in order, so these tests check the
documented order, that a value already in place is not written again, what is clamped or
refused (by name), and that a missing node is a warning naming it.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np
import pytest

from drivers import genicam_transport
from drivers.base import DeviceError
from drivers.camera_settings import CameraSettings
from drivers.genicam_settings import SettingsWriter
from drivers.genicam_transport import PtpWatch, apply_all, link_rate, link_stats, ptp_status, read_chunks
from fakes.camera_clock import CameraClock
from fakes.genicam_nodes import FakeNodeMap, camera_node_map, stream_node_map

pytestmark = pytest.mark.timeout(30)

RECOMMENDED = CameraSettings(chunks=True, packet_size=9000, throughput_limit_bytes_s=110_000_000,
                             packet_resend=True, stream_buffers=8)
TRANSPORT = ["GevSCPSPacketSize", "DeviceLinkThroughputLimitMode", "DeviceLinkThroughputLimit",
             "StreamPacketResendEnable", "num_buffers"]


class Rig:
    """A camera and a stream node map sharing one write log, plus a buffer-count hook."""

    def __init__(self, cam: FakeNodeMap | None = None, stream: FakeNodeMap | None = None) -> None:
        self.cam = cam or camera_node_map()
        self.stream = stream or stream_node_map()
        self.stream.log = self.cam.log
        self.warnings: list[str] = []
        self.applied: dict[str, Any] = {}
        self.buffers = 4

    def set_buffers(self, n: int) -> int:
        self.cam.log.append(("num_buffers", n))
        self.buffers = n
        return n

    def apply(self, s: CameraSettings) -> bool:
        w = SettingsWriter(self.cam, self.warnings.append, self.applied)
        st = SettingsWriter(self.stream, self.warnings.append, self.applied,
                            owner="the GenTL producer's stream")
        return apply_all(w, st, s, self.set_buffers)

    @property
    def written(self) -> list[str]:
        return [name for name, _ in self.cam.log]


def test_transport_is_written_after_the_imaging_settings_in_the_documented_order() -> None:
    rig = Rig()
    assert rig.apply(replace(RECOMMENDED, ptp=True)) is True  # the fake camera can be software-triggered
    names = rig.written
    assert names.index("ExposureTime") < names.index("TriggerMode") < names.index("PtpEnable")
    assert names.index("PtpEnable") < names.index("ChunkModeActive")
    tail = [n for n in names if n in TRANSPORT]
    assert tail == TRANSPORT
    assert names.index("ChunkModeActive") < names.index("GevSCPSPacketSize")
    assert names[-5:] == TRANSPORT  # nothing after the transport
    assert rig.warnings == []
    assert (rig.cam["GevSCPSPacketSize"], rig.cam["DeviceLinkThroughputLimitMode"],
            rig.cam["DeviceLinkThroughputLimit"], rig.stream["StreamPacketResendEnable"],
            rig.buffers) == (9000, "On", 110_000_000, True, 8)
    assert rig.applied["StreamBufferCount"] == 8
    assert rig.applied["GevSCPSPacketSize"] == 9000


def test_unchanged_transport_values_are_not_written_again() -> None:
    rig = Rig()
    rig.apply(RECOMMENDED)
    rig.cam.log.clear()
    rig.apply(RECOMMENDED)
    # the buffer count is host memory, not a device write: it is set at every apply; the chunk
    # selector must move to reach each chunk's enable (a selector write changes no state)
    assert [n for n in rig.written if n != "ChunkSelector"] == ["num_buffers"]


def test_chunks_enable_each_offered_chunk_and_the_values_are_read() -> None:
    rig = Rig()
    rig.apply(CameraSettings(chunks=True))
    for chunk in ("Timestamp", "ExposureTime", "Gain"):
        assert rig.applied[f"ChunkEnable[{chunk}]"] is True
    w = SettingsWriter(rig.cam, rig.warnings.append)
    assert read_chunks(w) == {"chunk_timestamp_ns": 1_000_000_123, "chunk_exposure_us": 2000.0,
                              "chunk_gain_db": 0.0}
    rig.apply(CameraSettings(chunks=False))
    assert read_chunks(w) == {}  # chunk nodes are not available without chunk mode


def test_a_chunk_the_camera_lacks_is_a_warning_naming_it() -> None:
    cam = camera_node_map()
    cam.nodes["ChunkSelector"].symbolics = ("Timestamp", "Width")
    rig = Rig(cam)
    rig.apply(CameraSettings(chunks=True))
    assert rig.warnings == [
        "camera has no ChunkSelector 'ExposureTime'; the ExposureTime chunk is not enabled",
        "camera has no ChunkSelector 'Gain'; the Gain chunk is not enabled"]
    assert read_chunks(SettingsWriter(cam, rig.warnings.append)) == {"chunk_timestamp_ns": 1_000_000_123}


def test_auto_packet_size_uses_the_producers_negotiation() -> None:
    rig = Rig()
    rig.apply(CameraSettings(packet_size="auto"))
    assert rig.stream["StreamAutoNegotiatePacketSize"] is True
    assert "GevSCPSPacketSize" not in rig.written  # the producer negotiates at stream start
    rig.apply(CameraSettings(packet_size=8192))  # an explicit size switches the negotiation off
    assert rig.stream["StreamAutoNegotiatePacketSize"] is False and rig.cam["GevSCPSPacketSize"] == 8192


def test_auto_packet_size_without_negotiation_takes_the_camera_maximum_and_says_so() -> None:
    rig = Rig(camera_node_map(packet_max=8999), stream_node_map(without=("StreamAutoNegotiatePacketSize",)))
    rig.apply(CameraSettings(packet_size="auto"))
    assert rig.cam["GevSCPSPacketSize"] == 8996  # on the node's 4-byte grid from 576
    assert len(rig.warnings) == 1 and "GevSCPSPacketSize=8996" in rig.warnings[0]
    assert "jumbo frames" in rig.warnings[0]


def test_packet_size_outside_the_range_or_step_is_clamped_with_a_warning_naming_both() -> None:
    rig = Rig()
    rig.apply(CameraSettings(packet_size=16000))
    assert rig.cam["GevSCPSPacketSize"] == 9000
    assert rig.warnings == ["packet_size=16000 is outside the camera's GevSCPSPacketSize range 576..9000 "
                            "(step 4); using 9000"]
    rig = Rig()
    rig.apply(CameraSettings(packet_size=8999))  # off the step of 4: rounded down
    assert rig.cam["GevSCPSPacketSize"] == 8996 and "packet_size=8999" in rig.warnings[0]
    with pytest.raises(DeviceError, match=r"packet_size='big' is not 'auto'"):
        Rig().apply(CameraSettings(packet_size="big"))


def test_throughput_limit_is_clamped_with_a_warning_and_zero_switches_it_off() -> None:
    rig = Rig()
    rig.apply(CameraSettings(throughput_limit_bytes_s=200_000_000))
    assert rig.cam["DeviceLinkThroughputLimit"] == 125_000_000
    assert rig.warnings == ["DeviceLinkThroughputLimit=200000000 is outside the camera's range "
                            "31250000..125000000; using 125000000"]
    rig.apply(CameraSettings(throughput_limit_bytes_s=0))
    assert rig.cam["DeviceLinkThroughputLimitMode"] == "Off"
    with pytest.raises(DeviceError, match="throughput_limit_bytes_s=-5"):
        rig.apply(CameraSettings(throughput_limit_bytes_s=-5))


def test_missing_transport_nodes_are_reported_by_name_and_the_rest_applies() -> None:
    cam = camera_node_map(without=("GevSCPSPacketSize", "DeviceLinkThroughputLimitMode",
                                   "DeviceLinkThroughputLimit"))
    rig = Rig(cam, stream_node_map(without=("StreamPacketResendEnable",)))
    rig.apply(RECOMMENDED)
    assert "camera has no GevSCPSPacketSize; packet_size=9000 not applied" in rig.warnings
    assert ("camera has no DeviceLinkThroughputLimit; throughput_limit_bytes_s=110000000 not applied"
            in rig.warnings)
    assert ("the GenTL producer's stream has no StreamPacketResendEnable; StreamPacketResendEnable=True "
            "not applied" in rig.warnings)
    assert rig.buffers == 8  # the buffer count still applies


def test_sfnc_packet_size_name_is_used_when_the_gev_one_is_absent() -> None:
    from fakes.genicam_nodes import INT, FakeNode
    cam = camera_node_map(without=("GevSCPSPacketSize",))
    cam.add(FakeNode("DeviceStreamChannelPacketSize", INT, 1500, 576, 9000, 4))
    rig = Rig(cam)
    rig.apply(CameraSettings(packet_size=9000))
    assert cam["DeviceStreamChannelPacketSize"] == 9000 and rig.warnings == []


def test_bad_stream_buffer_count_and_tiny_packets_are_refused() -> None:
    with pytest.raises(DeviceError, match="stream_buffers=0 must be >= 1"):
        Rig().apply(CameraSettings(stream_buffers=0))
    with pytest.raises(DeviceError, match="packet_size=500 is below 576 bytes"):
        Rig().apply(CameraSettings(packet_size=500))


def test_stream_buffers_below_the_producers_minimum_are_raised_to_it_with_a_warning() -> None:
    from fakes.genicam_nodes import stream_node_map
    rig = Rig(stream=stream_node_map(buffer_minimum=3))
    rig.apply(CameraSettings(stream_buffers=2))  # harvesters would refuse 2: the camera would go to FAULT
    assert rig.buffers == 3 and rig.applied["StreamBufferCount"] == 3
    assert rig.warnings == ["stream_buffers=2 is below the GenTL producer's minimum of 3 buffers; using 3"]
    rig = Rig(stream=stream_node_map(without=("StreamAnnounceBufferMinimum",)))
    w = SettingsWriter(rig.cam, rig.warnings.append, rig.applied)
    st = SettingsWriter(rig.stream, rig.warnings.append, rig.applied, owner="the GenTL producer's stream")
    # harvesters' own minimum
    apply_all(w, st, CameraSettings(stream_buffers=1), rig.set_buffers, min_buffers=4)
    assert rig.buffers == 4
    assert "stream_buffers=1 is below the GenTL producer's minimum of 4" in rig.warnings[0]
    rig = Rig(stream=stream_node_map(buffer_minimum=3))
    rig.apply(CameraSettings(stream_buffers=3))
    assert rig.buffers == 3 and rig.warnings == []


def test_ptp_status_role_and_offset_or_unavailable() -> None:
    rig = Rig()
    w = SettingsWriter(rig.cam, rig.warnings.append)
    assert ptp_status(w) == {"available": True, "enabled": False, "status": "Disabled",
                             "offset_from_master_ns": None}
    rig.apply(CameraSettings(ptp=True))
    assert ptp_status(w) == {"available": True, "enabled": True, "status": "Slave",
                             "offset_from_master_ns": -42}
    assert rig.cam.log[-1] == ("PtpDataSetLatch", "execute")
    bare = camera_node_map(without=("PtpEnable", "PtpStatus", "PtpOffsetFromMaster", "PtpDataSetLatch"))
    assert ptp_status(SettingsWriter(bare, rig.warnings.append)) == {"available": False}


def test_link_statistics_from_the_stream_else_the_adapters_counts() -> None:
    counts = {"StreamResendRequestCount": 12, "StreamLostPacketCount": 3, "StreamIncompleteFrameCount": 2}
    st = SettingsWriter(stream_node_map(counters=counts), lambda m: None)
    stats = link_stats(st, {"incomplete_frames": 7})
    assert (stats["resend_requests"], stats["lost_packets"], stats["incomplete_frames"],
            stats["lost_frames"]) == (12, 3, 2, 0)
    assert stats["source"]["incomplete_frames"] == "StreamIncompleteFrameCount"
    counts["StreamLostPacketCount"] = 5  # counters are read live
    assert link_stats(st, {})["lost_packets"] == 5
    bare = SettingsWriter(FakeNodeMap(), lambda m: None)
    stats = link_stats(bare, {"incomplete_frames": 7})
    assert stats["incomplete_frames"] == 7 and stats["source"]["incomplete_frames"] == "adapter"
    assert stats["resend_requests"] is None and stats["source"]["resend_requests"] is None


def test_ptp_state_follows_the_cameras_clock_and_is_polled_at_most_once_a_second(
        monkeypatch: pytest.MonkeyPatch) -> None:
    clock = CameraClock(np.random.default_rng(0), ptp_state="Listening", now_ns=lambda: 1_800_000_000 * 10**9)
    rig = Rig(cam=camera_node_map(clock=clock))
    w = SettingsWriter(rig.cam, rig.warnings.append)
    rig.apply(CameraSettings(ptp=True, chunks=True))
    assert ptp_status(w) == {"available": True, "enabled": True, "status": "Listening",
                             "offset_from_master_ns": None}
    assert read_chunks(w)["chunk_timestamp_ns"] == clock.device_ns(clock.now_ns())  # its own clock, not PTP's
    t = [100.0]
    monkeypatch.setattr(genicam_transport.time, "monotonic", lambda: t[0])
    watch = PtpWatch()
    assert watch.poll(lambda: w)["status"] == "Listening"
    clock.ptp_state = "Slave"
    assert watch.poll(lambda: w)["status"] == "Listening"  # within the second: the last reading
    t[0] += genicam_transport.PTP_POLL_S
    state = watch.poll(lambda: w)
    assert state["status"] == "Slave" and abs(state["offset_from_master_ns"]) <= 300
    assert (read_chunks(w)["chunk_timestamp_ns"] - clock.now_ns() - 37 * 10**9
            == state["offset_from_master_ns"])


def test_link_rate_is_the_line_rate_or_the_throughput_limit() -> None:
    rig = Rig()
    w = SettingsWriter(rig.cam, rig.warnings.append)
    assert link_rate(w) == 125_000_000.0  # DeviceLinkSpeed in bytes/s (SFNC), no limit: GigE's line rate
    rig.apply(CameraSettings(throughput_limit_bytes_s=110_000_000))
    assert link_rate(w) == 110_000_000.0


def test_link_speed_given_in_mbps_is_read_as_such_with_a_warning() -> None:
    rig = Rig(camera_node_map(link_speed=1000))  # an SDK that reports Mbps
    w = SettingsWriter(rig.cam, rig.warnings.append)
    assert link_rate(w) == 125_000_000.0
    assert rig.warnings == ["DeviceLinkSpeed=1000 is too small for bytes/s (SFNC's unit); read as Mbps: "
                            "125000000 bytes/s"]
    rig = Rig(camera_node_map(without=("DeviceLinkSpeed",)))
    assert link_rate(SettingsWriter(rig.cam, rig.warnings.append)) == 125_000_000.0 and rig.warnings == []


def test_ptp_is_enabled_slave_only_so_the_camera_cannot_win_the_master_election() -> None:
    rig = Rig(camera_node_map(ptp_wins_election=True))  # no better clock on the network
    rig.apply(CameraSettings(ptp=True))
    assert rig.cam["PtpEnable"] is True and rig.cam["PtpSlaveOnly"] is True
    assert ptp_status(SettingsWriter(rig.cam, rig.warnings.append))["status"] != "Master"


def test_a_camera_left_in_single_frame_and_mirrored_is_set_back_at_open() -> None:
    rig = Rig(camera_node_map(left={"AcquisitionMode": "SingleFrame", "ReverseX": True, "ReverseY": True}))
    rig.apply(CameraSettings())
    assert rig.cam["AcquisitionMode"] == "Continuous"
    assert rig.cam["ReverseX"] is False and rig.cam["ReverseY"] is False
    assert rig.written[:3] == ["AcquisitionMode", "ReverseX", "ReverseY"]  # before the pixel format


def test_a_mirror_the_camera_cannot_switch_off_is_an_error_naming_it() -> None:
    cam = camera_node_map(left={"ReverseY": True})
    cam.nodes["ReverseY"].access = 3  # read-only: a mirror the camera holds
    with pytest.raises(DeviceError, match="camera's ReverseY is on and cannot be switched off"):
        Rig(cam).apply(CameraSettings())


def test_a_clock_whose_port_would_be_master_listens_when_slave_only() -> None:
    clock = CameraClock(np.random.default_rng(1), ptp_state="Master")  # the sim camera's ptp=Master
    rig = Rig(cam=camera_node_map(clock=clock))
    rig.cam.nodes["PtpEnable"].value = True
    assert ptp_status(SettingsWriter(rig.cam, rig.warnings.append))["status"] == "Master"
    rig.apply(CameraSettings(ptp=True))
    assert ptp_status(SettingsWriter(rig.cam, rig.warnings.append))["status"] == "Listening"
