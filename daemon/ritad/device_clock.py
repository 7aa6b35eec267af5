"""A device clock's mapping onto the host's as ritad keeps it for a device's status.

The mapping itself is the bus library's (daemon/bus/clockmap.py, docs/architecture.md "Time").
This holder feeds it from the device's time-stamped telemetry, in the thread that emits it
(the adapter's reader), and hands its status to the command that reads it in another: so
both go through one lock. The tracker's stream packets feed it (each packet's last record's
device time against the host time it arrived); the robot base's sample batches
(``robot.odometry``, ``robot.incl``: every sample's ``t_us`` against the host time its line
was read) feed it and get each sample's host-timeline ``t_ns`` and ``t_sigma_ns`` back, as do
its STATUS polls with a ``t_us`` (``robot.state``); a device without a clock in its telemetry
shows a map with no samples.
"""
from __future__ import annotations

import threading
from typing import Any

from daemon.bus.clockmap import ClockMap

#: the tracker stamps its records in µs (and the robot base its samples)
TRACKER_RESOLUTION_NS = 1000
#: the robot base's telemetry that carries its clock: sample batches, and the STATUS polls
ROBOT_CLOCKED = ("robot.odometry", "robot.incl", "robot.state")


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
        self._add([(device_ns, host_ns)], [])

    def observe_robot(self, topic: str, payload: Any) -> Any:
        """The robot base's telemetry of ``topic`` (one of ROBOT_CLOCKED) fed to the map: a sample batch
        ``{t_us: [...], host_time_ns: [...], ...}`` comes back with each sample's host-timeline ``t_ns``
        and ``t_sigma_ns``; a ``robot.state`` (a STATUS poll) adds its ``t_us`` when the base has a clock.
        A malformed payload adds nothing and is returned unchanged."""
        batch = topic != "robot.state"
        try:
            t_us, host = (payload["t_us"], payload["host_time_ns"]) if batch else \
                ([payload["t_us"]], [payload["host_time_ns"]])
            device_ns, host_ns = [int(t) * 1000 for t in t_us], [int(h) for h in host]
        except (TypeError, KeyError, ValueError, OverflowError):
            return payload
        if not device_ns or len(device_ns) != len(host_ns):
            return payload
        mapped = self._add(sorted(zip(device_ns, host_ns)), device_ns if batch else [])
        return {**payload, "t_ns": mapped[0], "t_sigma_ns": mapped[1]} if batch and mapped else payload

    def _add(self, samples: list[tuple[int, int]], to_map: list[int]) -> tuple[list[int], list[int]] | None:
        """Add (device ns, host ns) samples in the device's order, then map ``to_map``; None when the map
        cannot take them (that must not stop the telemetry's publishing)."""
        with self._lock:
            try:
                for d, h in samples:
                    self._map.add(d, h)
                return self._map.map_many(to_map)
            except (ValueError, OverflowError):
                return None

    def status(self) -> dict[str, Any]:
        """The mapping's offset, drift, sigma, samples and window (ClockMap.status)."""
        with self._lock:
            return self._map.status()


def observe_telemetry(clocks: dict[str, DeviceClock], topic: str, payload: Any) -> Any:
    """Feed a device's time-stamped telemetry to its clock (``clocks`` by device kind): the payload
    to publish, with host-timeline times added to the robot base's sample batches."""
    if topic == "tracker.point" and "tracker" in clocks:
        clocks["tracker"].observe_tracker_packet(payload)
    elif topic in ROBOT_CLOCKED and "robot" in clocks:
        return clocks["robot"].observe_robot(topic, payload)
    return payload
