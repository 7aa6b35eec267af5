"""What ritad asks of a camera ("the daemon is master"): the settings every camera adapter applies on open."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass
class CameraSettings:
    """Desired camera settings ("daemon is master"); ``None`` leaves a feature alone."""

    pixel_format: str = "Mono8"
    width: int | None = None
    height: int | None = None
    offset_x: int | None = None
    offset_y: int | None = None
    exposure_us: float | None = 2000.0
    gain_db: float | None = 0.0
    frame_rate_hz: float | None = 5.0
    trigger: str = "software"  # "software" or "free"
    ptp: bool | None = None
    #: ChunkModeActive plus the Timestamp, ExposureTime and Gain chunks (frame header: chunk_*)
    chunks: bool | None = None
    #: GigE transport, applied after the above in this order (docs/operations.md, "GigE link"):
    #: GevSCPSPacketSize in bytes, or "auto" (the producer's negotiation, else the camera's maximum)
    packet_size: int | str | None = None
    #: DeviceLinkThroughputLimit in bytes/s; 0 switches the limit off
    throughput_limit_bytes_s: int | None = None
    #: the GenTL stream's StreamPacketResendEnable (a host-side feature of the producer)
    packet_resend: bool | None = None
    #: host buffers the GenTL stream announces (harvesters' num_buffers); None: the URL's num_buffers
    stream_buffers: int | None = None


def desired(settings: Any) -> CameraSettings:
    """The camera settings ritad handed a camera adapter (its defaults when it handed none)."""
    return settings if isinstance(settings, CameraSettings) else CameraSettings()
