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
        times = _device_times(payload)
        if not times:
            return
        try:
            host_ns = int(payload["host_time_ns"])
        except (TypeError, KeyError, ValueError, OverflowError):
            return
        with self._lock:
            try:
                self._map.add(times[-1], host_ns)
            except (ValueError, OverflowError):  # a packet the map cannot take must not stop its publishing
                return

    def map_packet(self, payload: Any) -> list[tuple[int, int]] | None:
        """Each record of a ``tracker.point`` packet on the host's timeline: (t_ns, t_sigma_ns);
        None without device times or before the map has a sample."""
        times = _device_times(payload)
        if not times:
            return None
        with self._lock:
            try:
                return [self._map.map(d) for d in times]
            except (ValueError, OverflowError):
                return None

    def status(self) -> dict[str, Any]:
        """The mapping's offset, drift, sigma, samples and window (ClockMap.status)."""
        with self._lock:
            return self._map.status()


def _device_times(payload: Any) -> list[int] | None:
    """A packet's records' device times (ns; the tracker stamps s + µs), None when it has none."""
    dt = payload.get("device_time") if isinstance(payload, dict) else None
    try:
        return [int(s) * 1_000_000_000 + int(us) * 1000 for s, us in zip(dt[0], dt[1], strict=True)]  # type: ignore[index]
    except (TypeError, IndexError, KeyError, ValueError, OverflowError):
        return None
