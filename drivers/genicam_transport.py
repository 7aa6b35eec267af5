"""The GigE side of a GenICam camera: chunk data, transport settings, PTP status, link statistics.

:func:`apply_all` applies the imaging settings (:func:`drivers.genicam_settings.apply_settings`),
then :func:`apply_chunks` and :func:`apply_transport`, in this order:

1. ChunkModeActive, then ChunkSelector/ChunkEnable for Timestamp, ExposureTime, Gain;
2. packet size: GevSCPSPacketSize (GigE Vision name) or DeviceStreamChannelPacketSize (SFNC);
   ``"auto"`` turns on the producer's StreamAutoNegotiatePacketSize when its stream offers it
   (the producer then finds the largest size the path passes), else writes the camera's maximum
   and says so (the NIC and switch must then pass that size: jumbo frames);
3. DeviceLinkThroughputLimitMode / DeviceLinkThroughputLimit (clamped into the camera's range
   with a warning: the range moves with the link speed);
4. the stream's StreamPacketResendEnable;
5. the stream buffer count (harvesters' ``num_buffers``, set before acquisition starts); a count
   below the producer's minimum (its ``StreamAnnounceBufferMinimum`` node or harvesters'
   ``min_num_buffers``, the larger) is raised to that minimum with a warning naming both: harvesters
   refuses a smaller count, which would leave the camera in FAULT over a tuning value.

The chunks come first because they change the payload size the buffers are sized for. Packet
size, throughput and resend are features of two node maps: the camera's and the GenTL data
stream's (host side, only where the producer exposes them). A feature either lacks is a
warning naming it, never an error; an explicit packet size outside the camera's range or off its
step is clamped into it (rounded down to the step) with a warning naming both values, so a camera
whose limits differ from the configuration still streams.
"""
from __future__ import annotations

import time
from typing import Any, Callable

from genicam import genapi
from harvesters.core import Callback

from drivers.base import DeviceError
from drivers.camera_settings import CameraSettings
from drivers.gige import GIGE_LINE_BYTES_S, MIN_PACKET_BYTES
from drivers.genicam_settings import SettingsWriter, apply_settings, find_node

#: chunks enabled by ``chunks = true`` -> the frame header key each one fills
CHUNKS = {"Timestamp": "chunk_timestamp_ns", "ExposureTime": "chunk_exposure_us", "Gain": "chunk_gain_db"}
PACKET_SIZE_NODES = ("GevSCPSPacketSize", "DeviceStreamChannelPacketSize")
PTP_STATUS_NODES = ("PtpStatus", "GevIEEE1588Status")
PTP_OFFSET_NODES = ("PtpOffsetFromMaster", "GevIEEE1588OffsetFromMaster")
#: how often frames' PTP state is refreshed (each reading costs GigE round trips)
PTP_POLL_S = 1.0
#: link statistic -> data-stream counters that may hold it (GenTL SFNC names first, then vendors')
LINK_STATS = {
    "resend_requests": ("StreamResendRequestCount", "StreamPacketResendRequestCount",
                        "GevResendRequestCount"),
    "lost_packets": ("StreamLostPacketCount", "StreamMissedPacketCount", "GevFailedPacketCount"),
    "incomplete_frames": ("StreamIncompleteFrameCount",),
    "lost_frames": ("StreamLostFrameCount",),
}

SetBuffers = Callable[[int], int]
#: DeviceLinkSpeed is bytes/s in SFNC (GigE: 125 000 000); below this no Ethernet link's bytes/s can lie,
#: so a smaller reading is in Mbps, as some SDKs give it (10 .. 100 000 Mbps: 10BASE-T .. 100GbE)
MIN_LINK_BYTES_S = 100_000
BYTES_S_PER_MBPS = 125_000


class IncompleteCounter(Callback):
    """harvesters callback counting INCOMPLETE_BUFFER events (the adapter's own link counter)."""

    def __init__(self) -> None:
        super().__init__()
        self.count = 0

    def emit(self, context: Any = None) -> None:
        self.count += 1


def _first(w: SettingsWriter, names: tuple[str, ...]) -> str | None:
    return next((n for n in names if w.has(n)), None)


def apply_chunks(w: SettingsWriter, on: bool) -> None:
    """Chunk mode plus the three chunks the frame header reports; a missing one is a warning."""
    if not w.write("ChunkModeActive", on):
        return
    if not on:
        return
    selector = find_node(w.nm, "ChunkSelector")
    offered = tuple(selector.symbolics) if selector is not None else ()
    for chunk in CHUNKS:
        if chunk not in offered:
            w.warn(f"camera has no ChunkSelector {chunk!r}; the {chunk} chunk is not enabled")
            continue
        w.write("ChunkSelector", chunk)
        w.write("ChunkEnable", True)
        w.applied[f"ChunkEnable[{chunk}]"] = w.applied.pop("ChunkEnable", True)
    w.applied.pop("ChunkSelector", None)


def _packet_size(w: SettingsWriter, stream: SettingsWriter, want: int | str) -> None:
    name = _first(w, PACKET_SIZE_NODES)
    if want == "auto":
        if stream.has("StreamAutoNegotiatePacketSize"):
            stream.write("StreamAutoNegotiatePacketSize", True)
            return
        if name is None:
            w.warn("camera has no GevSCPSPacketSize; packet_size='auto' not applied")
            return
        node = find_node(w.nm, name)
        assert node is not None
        lo, hi, inc = int(node.min), int(node.max), max(1, int(node.inc))
        best = lo + (hi - lo) // inc * inc
        w.warn(f"packet_size='auto': the GenTL stream offers no StreamAutoNegotiatePacketSize; using the "
               f"camera's maximum {name}={best} "
               "(every NIC and switch on the path must pass it: jumbo frames)")
        w.write(name, best)
        return
    if isinstance(want, bool) or not isinstance(want, int):
        raise DeviceError(f"packet_size={want!r} is not 'auto' or a number of bytes", code="bad_setting")
    if name is None:
        w.warn(f"camera has no GevSCPSPacketSize; packet_size={want} not applied")
        return
    if want < MIN_PACKET_BYTES:
        raise DeviceError(f"packet_size={want} is below {MIN_PACKET_BYTES} bytes", code="bad_setting")
    if stream.has("StreamAutoNegotiatePacketSize"):
        stream.write("StreamAutoNegotiatePacketSize", False)  # else the producer overrides our value
    w.write(name, _packet_in_range(w, name, want))


def _packet_in_range(w: SettingsWriter, name: str, want: int) -> int:
    """``want`` clamped into the camera's range and rounded down to its step, with a warning naming both."""
    node = find_node(w.nm, name)
    if node is None:
        return want
    lo, hi, inc = int(node.min), int(node.max), max(1, int(node.inc))
    got = lo + (min(max(want, lo), hi) - lo) // inc * inc
    if got != want:
        w.warn(f"packet_size={want} is outside the camera's {name} range {lo}..{hi} (step {inc}); "
               f"using {got}")
    return got


def _throughput(w: SettingsWriter, limit: int) -> None:
    if limit < 0:
        raise DeviceError(f"throughput_limit_bytes_s={limit} must be >= 0 (0 = no limit)", code="bad_setting")
    has_mode = w.has("DeviceLinkThroughputLimitMode")
    if limit == 0:
        if has_mode:
            w.write("DeviceLinkThroughputLimitMode", "Off")
        else:
            w.warn("camera has no DeviceLinkThroughputLimitMode; throughput_limit_bytes_s=0 not applied")
        return
    if has_mode:
        w.write("DeviceLinkThroughputLimitMode", "On")
    node = find_node(w.nm, "DeviceLinkThroughputLimit")
    if node is None:
        w.warn(f"camera has no DeviceLinkThroughputLimit; throughput_limit_bytes_s={limit} not applied")
        return
    lo, hi = int(node.min), int(node.max)
    if not lo <= limit <= hi:
        clamped = min(max(limit, lo), hi)
        w.warn(f"DeviceLinkThroughputLimit={limit} is outside the camera's range {lo}..{hi}; using {clamped}")
        limit = clamped
    inc = max(1, int(node.inc))
    w.write("DeviceLinkThroughputLimit", lo + (limit - lo) // inc * inc)


def _buffers(w: SettingsWriter, stream: SettingsWriter, want: int, set_buffers: SetBuffers | None,
             min_buffers: int) -> None:
    if want < 1:
        raise DeviceError(f"stream_buffers={want} must be >= 1", code="bad_setting")
    if set_buffers is None:
        w.warn(f"no stream to size; stream_buffers={want} not applied")
        return
    node_min = stream.read("StreamAnnounceBufferMinimum")
    lo = max(min_buffers, int(node_min) if isinstance(node_min, (int, float)) else 1)
    if want < lo:
        stream.warn(f"stream_buffers={want} is below the GenTL producer's minimum of {lo} buffers; "
                    f"using {lo}")
        want = lo
    stream.applied["StreamBufferCount"] = set_buffers(want)


def apply_transport(w: SettingsWriter, stream: SettingsWriter, s: CameraSettings,
                    set_buffers: SetBuffers | None, min_buffers: int = 1) -> None:
    """Packet size, throughput limit, packet resend and buffer count, in that order (module docstring)."""
    if s.packet_size is not None:
        _packet_size(w, stream, s.packet_size)
    if s.throughput_limit_bytes_s is not None:
        _throughput(w, s.throughput_limit_bytes_s)
    if s.packet_resend is not None:
        stream.write("StreamPacketResendEnable", bool(s.packet_resend))
    if s.stream_buffers is not None:
        _buffers(w, stream, s.stream_buffers, set_buffers, min_buffers)


def ptp_status(w: SettingsWriter) -> dict[str, Any]:
    """PTP enable, role and offset from master; ``available: False`` on a camera without PTP."""
    enabled = w.read("PtpEnable")
    if enabled is None:
        return {"available": False}
    if enabled:
        try:  # cameras that latch their PTP data set report it only after this
            w.execute("PtpDataSetLatch")
        except genapi.GenericException as exc:  # status must answer: the latch's failure is reported
            return {"available": True, "enabled": True, "error": f"PtpDataSetLatch: {exc}"}
    role = next((v for v in (w.read(n) for n in PTP_STATUS_NODES) if v is not None), None)
    offset = next((v for v in (w.read(n) for n in PTP_OFFSET_NODES) if v is not None), None)
    return {"available": True, "enabled": bool(enabled), "status": role,
            "offset_from_master_ns": None if offset is None else int(offset)}


class PtpWatch:
    """The camera's PTP state (:func:`ptp_status`) for its frames, read at most every ``PTP_POLL_S``."""

    def __init__(self) -> None:
        self.state: dict[str, Any] | None = None
        self._next = 0.0

    def poll(self, writer: Callable[[], SettingsWriter]) -> dict[str, Any] | None:
        now = time.monotonic()
        if now >= self._next:
            self._next = now + PTP_POLL_S
            self.state = ptp_status(writer())
        return self.state


def link_speed(w: SettingsWriter) -> float:
    """The camera's link speed in bytes/s: SFNC DeviceLinkSpeed, read as Mbps (with a warning) when it is
    too small to be bytes/s; GigE's line rate without the node."""
    speed = w.read("DeviceLinkSpeed")
    if not (isinstance(speed, (int, float)) and speed > 0):
        return float(GIGE_LINE_BYTES_S)
    if speed < MIN_LINK_BYTES_S:
        rate = float(speed) * BYTES_S_PER_MBPS
        w.warn(f"DeviceLinkSpeed={speed:g} is too small for bytes/s (SFNC's unit); read as Mbps: "
               f"{rate:.0f} bytes/s")
        return rate
    return float(speed)


def link_rate(w: SettingsWriter) -> float:
    """Bytes/s the camera sends at: its link speed (:func:`link_speed`), capped by its throughput limit
    when that is on. A frame's payload over it is the least time the frame spends on the wire."""
    rate = link_speed(w)
    limit = w.read("DeviceLinkThroughputLimit")
    if w.read("DeviceLinkThroughputLimitMode") == "On" and isinstance(limit, (int, float)) and limit > 0:
        rate = min(rate, float(limit))
    return rate


def link_stats(stream: SettingsWriter, counted: dict[str, int]) -> dict[str, Any]:
    """Each statistic from the data stream's counter where the producer has one, else ``counted``.

    ``source`` names, per statistic, the node it came from, ``adapter`` (the adapter's own
    count) or None (neither exists: the value is None).
    """
    out: dict[str, Any] = {}
    source: dict[str, str | None] = {}
    for key, names in LINK_STATS.items():
        name = _first(stream, names)
        value = stream.read(name) if name is not None else None
        if value is not None:
            out[key], source[key] = int(value), name
        elif key in counted:
            out[key], source[key] = counted[key], "adapter"
        else:
            out[key], source[key] = None, None
    out["source"] = source
    return out


def read_chunks(w: SettingsWriter) -> dict[str, Any]:
    """The chunk values of the buffer being held, by frame header key (absent chunks left out)."""
    out: dict[str, Any] = {}
    for chunk, key in CHUNKS.items():
        value = w.read(f"Chunk{chunk}")
        if value is not None:
            out[key] = int(value) if chunk == "Timestamp" else float(value)
    return out


def apply_all(w: SettingsWriter, stream: SettingsWriter, s: CameraSettings,
              set_buffers: SetBuffers | None, min_buffers: int = 1) -> bool:
    """Imaging settings, then chunks, then transport; returns whether software triggering works.

    ``min_buffers`` is the producer's buffer minimum as the acquirer knows it (harvesters'
    ``min_num_buffers``); the stream's own ``StreamAnnounceBufferMinimum`` raises it further.
    """
    software = apply_settings(w, s)
    if s.chunks is not None:
        apply_chunks(w, bool(s.chunks))
    apply_transport(w, stream, s, set_buffers, min_buffers)
    return software
