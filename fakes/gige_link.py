"""A deliberately simple model of one GigE Vision stream link, for the sim camera and bench/bench_gige.py.

The model, all of it:

* A frame of ``B`` payload bytes travels in ``n = ceil(B / (P - 36))`` packets of packet size
  ``P`` (GevSCPSPacketSize counts the IP and UDP headers and GVSP's 8-byte header: 36 bytes), and
  each packet costs ``P + 38`` bytes on the wire (Ethernet header, FCS, preamble, inter-frame gap).
  With P = 1500 that is 1464 payload bytes per 1538 wire bytes, as in reference/genicam.md §3.
* The camera sends at ``R = min(link, throughput limit)`` bytes/s; the frame takes the wire for
  ``(n + resent) * (P + 38) / R`` seconds.
* A packet larger than the path's MTU (``path_mtu``: 1500 without jumbo frames on the NIC) never
  arrives, so every frame is incomplete.
* Every other packet is lost independently with chance ``loss_at_line_rate`` when the camera
  sends at more than 95 % of the link (back-to-back packets overflow the NIC's receive ring), else
  ``loss_limited``. These two numbers are assumptions of this model, not measurements.
* With resend on, each lost packet is asked for once (a resend request) and arrives with the
  same chance as any packet; a packet still missing makes the frame incomplete. With resend off
  any loss makes the frame incomplete.
* Not modelled: the stream buffer count (it matters only when the host falls behind), the
  resend timeout, inter-packet delay, and other traffic on the link.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.base import DeviceError
from drivers.gige import GIGE_LINE_BYTES_S

IP_UDP_GVSP_HEADERS = 36
ETHERNET_OVERHEAD = 38
LINK_BYTES_S = float(GIGE_LINE_BYTES_S)


@dataclass
class LinkSettings:
    """What the camera and the producer were told (None/0: the device's default, no limit)."""

    packet_size: int = 1500
    throughput_limit_bytes_s: int = 0
    resend: bool = False


@dataclass
class GigELink:
    """Sends frames through the model above and keeps the link counters the status reports."""

    rng: np.random.Generator
    path_mtu: int = 9000
    loss_at_line_rate: float = 0.0
    loss_limited: float = 0.0
    link_bytes_s: float = LINK_BYTES_S
    counters: dict[str, int] = field(default_factory=lambda: {
        "packets": 0, "resend_requests": 0, "lost_packets": 0, "incomplete_frames": 0, "frames": 0})

    def rate(self, s: LinkSettings) -> float:
        """Bytes/s the camera sends at."""
        limit = s.throughput_limit_bytes_s
        return min(self.link_bytes_s, float(limit)) if limit > 0 else self.link_bytes_s

    def send(self, payload_bytes: int, s: LinkSettings) -> tuple[bool, float]:
        """One frame through the link: (complete, seconds on the wire)."""
        c = self.counters
        n = math.ceil(payload_bytes / (s.packet_size - IP_UDP_GVSP_HEADERS))
        rate = self.rate(s)
        c["frames"] += 1
        c["packets"] += n
        if s.packet_size > self.path_mtu:
            c["lost_packets"] += n
            c["incomplete_frames"] += 1
            return False, n * (s.packet_size + ETHERNET_OVERHEAD) / rate
        p = self.loss_at_line_rate if rate > 0.95 * self.link_bytes_s else self.loss_limited
        lost = int(self.rng.binomial(n, p)) if p > 0 else 0
        resent = 0
        if lost and s.resend:
            c["resend_requests"] += lost
            resent = lost
            lost = int(self.rng.binomial(lost, p))
        c["lost_packets"] += lost
        if lost:
            c["incomplete_frames"] += 1
        return lost == 0, (n + resent) * (s.packet_size + ETHERNET_OVERHEAD) / rate

    def stats(self) -> dict[str, Any]:
        """The counters in the shape of a camera's ``status()["link"]``."""
        c = self.counters
        return {"resend_requests": c["resend_requests"], "lost_packets": c["lost_packets"],
                "incomplete_frames": c["incomplete_frames"], "lost_frames": 0,
                "source": {k: "sim" for k in ("resend_requests", "lost_packets", "incomplete_frames",
                                              "lost_frames")}}


#: the sim camera's GevSCPSPacketSize and DeviceLinkThroughputLimit ranges (PHX122S-like, not its own)
PACKET_RANGE = (576, 9000)
THROUGHPUT_RANGE = (31_250_000, 125_000_000)


def sim_transport(s: Any, path_mtu: int, warnings: list[str]) -> tuple[LinkSettings, dict[str, Any]]:
    """The sim camera's reading of a CameraSettings' transport part: link settings and ``applied``.

    Same rules as the GenICam adapter: ``auto`` is negotiated (the largest size the path passes,
    up to the camera's maximum), an explicit size outside the range is refused by name, the
    throughput limit is clamped with a warning.
    """
    link = LinkSettings()
    applied: dict[str, Any] = {}
    lo, hi = PACKET_RANGE
    if s.packet_size == "auto":
        link.packet_size = min(hi, path_mtu) // 4 * 4
    elif s.packet_size is not None:
        if (isinstance(s.packet_size, bool) or not isinstance(s.packet_size, int)
                or not lo <= s.packet_size <= hi):
            raise DeviceError(f"GevSCPSPacketSize={s.packet_size!r} is outside the camera's range {lo}..{hi}",
                              code="bad_setting")
        link.packet_size = s.packet_size
    applied["GevSCPSPacketSize"] = link.packet_size
    limit = s.throughput_limit_bytes_s
    if limit is not None and limit < 0:
        raise DeviceError(f"throughput_limit_bytes_s={limit} must be >= 0 (0 = no limit)", code="bad_setting")
    if limit:
        tlo, thi = THROUGHPUT_RANGE
        if not tlo <= limit <= thi:
            clamped = min(max(limit, tlo), thi)
            warnings.append(f"DeviceLinkThroughputLimit={limit} is outside the camera's range {tlo}..{thi}; "
                            f"using {clamped}")
            limit = clamped
        link.throughput_limit_bytes_s = limit
    applied["DeviceLinkThroughputLimitMode"] = "On" if link.throughput_limit_bytes_s else "Off"
    if link.throughput_limit_bytes_s:
        applied["DeviceLinkThroughputLimit"] = link.throughput_limit_bytes_s
    link.resend = bool(s.packet_resend)
    applied["StreamPacketResendEnable"] = link.resend
    if s.stream_buffers is not None:
        if s.stream_buffers < 1:
            raise DeviceError(f"stream_buffers={s.stream_buffers} must be >= 1", code="bad_setting")
        applied["StreamBufferCount"] = s.stream_buffers
    if s.chunks is not None:
        applied["ChunkModeActive"] = bool(s.chunks)
    return link, applied
