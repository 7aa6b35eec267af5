"""A device clock's mapping onto the host's as ritad keeps it for a device's status.

The mapping itself is the bus library's (daemon/bus/clockmap.py, docs/architecture.md "Time").
This holder feeds it from the device's time-stamped telemetry, in the thread that emits it
(the adapter's reader), and hands its status to the command that reads it in another: so
both go through one lock. Today the tracker's stream packets feed it (each packet's last
record's device time against the host time it arrived); a device without a clock in its
telemetry shows a map with no samples.
"""
from __future__ import annotations

import threading
from typing import Any

from daemon.bus.clockmap import ClockMap

#: the tracker stamps its records in µs
TRACKER_RESOLUTION_NS = 1000


class DeviceClock:
    """A :class:`ClockMap` shared between the emitting thread and the status reader."""

    def __init__(self, resolution_ns: float = TRACKER_RESOLUTION_NS) -> None:
        self._map = ClockMap(resolution_ns=resolution_ns)
        self._lock = threading.Lock()

    def observe_tracker_packet(self, payload: Any) -> None:
        """A ``tracker.point`` packet; one without device time (or malformed) adds nothing."""
        dt = payload.get("device_time") if isinstance(payload, dict) else None
        try:
            device_ns = int(dt[0][-1]) * 1_000_000_000 + int(dt[1][-1]) * 1000  # type: ignore[index]
            host_ns = int(payload["host_time_ns"])
        except (TypeError, IndexError, KeyError, ValueError, OverflowError):
            return
        with self._lock:
            try:
                self._map.add(device_ns, host_ns)
            except (ValueError, OverflowError):  # a packet the map cannot take must not stop its publishing
                return

    def status(self) -> dict[str, Any]:
        """The mapping's offset, drift, sigma, samples and window (ClockMap.status)."""
        with self._lock:
            return self._map.status()
