"""The simulated camera's clock and the delivery time of its frames; the truth the tests check against.

The model, all of it:

* The host's clock (``now_ns``, time.time_ns unless a test drives it) is the true time, UTC.
* The camera counts its own time from power-up (the clock's creation): ``offset_s`` plus the host
  time since then, running fast by ``drift_ppm``.
* With its PTP port enabled and in state ``ptp_state`` = ``Slave`` (locked), the camera's clock is
  on the master's time, which is the host's (both follow one grandmaster): PTP counts TAI, so the
  camera reads host UTC + TAI−UTC (daemon/bus/clockmap.py ``TAI_MINUS_UTC_S``) + the servo's
  residual, which wanders as a sine of ``ptp_offset_ns`` amplitude (period 17 s); the port's
  offset from master reports that residual. In ``Listening`` or ``Uncalibrated`` the port is not
  locked and the camera's own clock runs on. ``ptp_state`` None: a camera without PTP.
* A frame's device time is its exposure's start. It arrives ``exposure + wire + latency`` later:
  ``wire`` the link model's time on the wire (fakes/gige_link.py), ``latency`` drawn uniform
  in 0..``latency_ms`` (seeded: one-sided, as real delays are).

URL options of the sim camera (fakes/camera.py): ``clock_offset_s``, ``clock_drift_ppm``,
``ptp`` (none, Slave, Listening, Uncalibrated or Master: the state PtpEnable leads to; default none;
Master: the port won the election, no better clock on the network, and the camera's own clock runs on),
``ptp_offset_ns`` (default 300) and ``latency_ms`` (default 0).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from daemon.bus.clockmap import TAI_MINUS_UTC_S
from drivers.base import DeviceURL

PTP_STATES = ("Slave", "Listening", "Uncalibrated", "Master")
SERVO_PERIOD_S = 17.0
OPTIONS = frozenset({"clock_offset_s", "clock_drift_ppm", "ptp", "ptp_offset_ns", "latency_ms"})


@dataclass
class CameraClock:
    """The camera's clock (module docstring); ``ptp_enabled`` is what PtpEnable was set to."""

    rng: np.random.Generator
    offset_s: float = 0.0
    drift_ppm: float = 0.0
    ptp_state: str | None = None
    ptp_offset_ns: float = 300.0
    latency_ms: float = 0.0
    now_ns: Callable[[], int] = time.time_ns
    ptp_enabled: bool = False
    power_up_ns: int = field(default=0)

    def __post_init__(self) -> None:
        self.power_up_ns = self.now_ns()

    @classmethod
    def from_url(cls, url: DeviceURL, rng: np.random.Generator) -> "CameraClock":
        ptp = url.option("ptp", "none")
        if ptp != "none" and ptp not in PTP_STATES:
            raise ValueError(f"camera URL {url.raw!r}: ptp={ptp!r} is not none or one of "
                             f"{', '.join(PTP_STATES)}")
        latency = url.option("latency_ms", 0.0, float)
        if not 0.0 <= latency < math.inf:
            raise ValueError(f"camera URL {url.raw!r}: latency_ms={latency} must be >= 0")
        return cls(rng, url.option("clock_offset_s", 0.0, float), url.option("clock_drift_ppm", 0.0, float),
                   None if ptp == "none" else ptp, url.option("ptp_offset_ns", 300.0, float), latency)

    @property
    def locked(self) -> bool:
        return self.ptp_enabled and self.ptp_state == "Slave"

    def servo_ns(self, host_ns: int) -> int:
        """The PTP servo's residual (camera − master) at ``host_ns``."""
        return int(round(self.ptp_offset_ns * math.sin(2 * math.pi * host_ns / 1e9 / SERVO_PERIOD_S)))

    def device_ns(self, host_ns: int) -> int:
        """The camera clock's reading at true time ``host_ns``."""
        if self.locked:
            return host_ns + TAI_MINUS_UTC_S * 1_000_000_000 + self.servo_ns(host_ns)
        since = host_ns - self.power_up_ns
        return int(round(self.offset_s * 1e9 + since * (1.0 + self.drift_ppm * 1e-6)))

    def arrival_ns(self, start_ns: int, exposure_us: float, wire_s: float) -> int:
        """When the frame exposed from true time ``start_ns`` has arrived at the host."""
        latency = float(self.rng.uniform(0.0, self.latency_ms)) if self.latency_ms > 0 else 0.0
        return start_ns + int(round(exposure_us * 1e3 + wire_s * 1e9 + latency * 1e6))

    def ptp_status(self) -> dict[str, Any]:
        """As drivers.genicam_transport.ptp_status reports a camera's PTP state."""
        if self.ptp_state is None:
            return {"available": False}
        if not self.ptp_enabled:
            return {"available": True, "enabled": False, "status": "Disabled", "offset_from_master_ns": None}
        offset = self.servo_ns(self.now_ns()) if self.locked else None
        return {"available": True, "enabled": True, "status": self.ptp_state, "offset_from_master_ns": offset}
