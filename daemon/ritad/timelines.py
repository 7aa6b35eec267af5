"""ritad's streams on the host's timeline, so that a capture says where everything was at the
frame's exposure, not which sample came last (docs/architecture.md, "Time").

Each stream is a :class:`daemon.bus.timeline.TimeSeries` fed from the telemetry the devices
emit, in the emitting thread: the tracker's stream records on their device clock mapped by the
tracker runner's clock map, the robot base's pose and tilt with the time the base gave them (or,
from a base that gives none, the host time its status arrived). A lookup interpolates between
the two samples around the instant and reports the gap; it never reaches further than a stream's
``REACH_NS`` beyond its samples, so a stale sample is refused rather than passed off as current.
"""
from __future__ import annotations

import threading
import time
from typing import Any

from daemon.bus.names import Topic
from daemon.bus.timeline import TimeSeries
from daemon.ritad.device_clock import ROBOT_CLOCKED, DeviceClock

#: stream -> (fields, angle fields): tracker x y z in the tracker's frame (mm), the base's odometry
#: pose (mm, degrees) and its inclinometer (degrees)
STREAMS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "tracker": (("x", "y", "z"), ()),
    "robot": (("x_mm", "y_mm", "heading_deg"), ("heading_deg",)),
    "tilt": (("roll_deg", "pitch_deg"), ()),
}
#: how far beyond a stream's samples a lookup may hold the nearest one (ns): the tracker's records
#: come at >= 10 Hz while it streams and are never held; the base's status comes at a few Hz and
#: holds still between motions (a capture is taken at a standstill)
REACH_NS = {"tracker": 0, "robot": 500_000_000, "tilt": 500_000_000}
#: a status from a base without a clock is timed by its arrival: it left the base one line's
#: transfer earlier (a ~70-byte STATUS at 115200 baud: ~6 ms), so that is its time's sigma
ARRIVAL_SIGMA_NS = 6_000_000
#: a frame is ready before the samples after its exposure have arrived (the tracker sends a packet at
#: >= 8 Hz, the base its status at a few Hz): a lookup waits for them at most this long (s), but only
#: for a live stream, one with a sample less than ``LIVE_NS`` before the instant
COVER_WAIT_S = 0.5
LIVE_NS = 1_000_000_000


class Timelines:
    """The streams a capture looks up, fed by each device's rig (daemon/ritad/rigs.py) with its own clock."""

    def __init__(self) -> None:
        self.streams = {name: TimeSeries(name, fields, angles=angles)
                        for name, (fields, angles) in STREAMS.items()}
        self._arrived = threading.Condition()

    def observe(self, topic: str, payload: Any, clock: DeviceClock) -> Any:
        """One telemetry message of the device whose clock map is ``clock``, fed to that map and to its
        stream; returns the payload to publish (the base's samples gain their host-timeline ``t_ns``).
        Anything malformed adds nothing: publishing must go on."""
        if not isinstance(payload, dict):
            return payload
        if topic in ROBOT_CLOCKED:
            payload = clock.observe_robot(topic, payload)
        try:
            if topic == Topic.TRACKER_POINT:
                payload = self._tracker(payload, clock)
            elif topic == Topic.ROBOT_STATE:
                self._robot(payload)
            elif topic in (Topic.ROBOT_ODOMETRY, Topic.ROBOT_INCL):
                self._samples(topic, payload)
            else:
                return payload
        except (TypeError, KeyError, ValueError, IndexError, OverflowError):
            return payload
        with self._arrived:
            self._arrived.notify_all()
        return payload

    def _tracker(self, p: dict[str, Any], clock: DeviceClock) -> dict[str, Any]:
        """Feeds the clock map and the stream; the packet comes back with each record's host-timeline
        ``t_ns`` and ``t_sigma_ns`` (as the base's samples), unchanged without a device clock."""
        clock.observe_tracker_packet(p)  # the map first: this packet's records are mapped with it
        timed = clock.map_packet(p)
        if timed is None:  # records without a device clock cannot be put on the timeline
            return p
        status = p.get("status") or [0] * int(p["n"])
        for (t, sigma), x, y, z, st in zip(timed, p["x"], p["y"], p["z"], status):
            if st == 0:
                self.streams["tracker"].add(t, (x, y, z), sigma)
        return {**p, "t_ns": [t for t, _ in timed], "t_sigma_ns": [s for _, s in timed]}

    def _robot(self, p: dict[str, Any]) -> None:
        if "t_ns" in p:
            t, sigma = int(p["t_ns"]), int(p.get("t_sigma_ns") or 0)
        else:
            t, sigma = int(p["host_time_ns"]), ARRIVAL_SIGMA_NS
        if p.get("x_mm") is not None and p.get("heading_deg") is not None:
            self.streams["robot"].add(t, (p["x_mm"], p["y_mm"], p["heading_deg"]), sigma)
        if p.get("roll_deg") is not None and p.get("pitch_deg") is not None:
            self.streams["tilt"].add(t, (p["roll_deg"], p["pitch_deg"]), sigma)

    def _samples(self, topic: str, p: dict[str, Any]) -> None:
        """A batch of the base's own samples, timed on its clock (none without that mapping)."""
        name = "robot" if topic == Topic.ROBOT_ODOMETRY else "tilt"
        series = self.streams[name]
        columns = [p[f] for f in series.fields]
        for t, sigma, *values in zip(p["t_ns"], p["t_sigma_ns"], *columns, strict=True):
            series.add(int(t), values, int(sigma))

    def _waiting_for(self, t_ns: int) -> bool:
        """A live stream has no sample at or after ``t_ns`` yet."""
        spans = (series.span() for series in self.streams.values())
        return any(span is not None and t_ns - LIVE_NS <= span[1] < t_ns for span in spans)

    def at(self, t_ns: int, wait_s: float = 0.0) -> dict[str, dict[str, Any]]:
        """Every stream at ``t_ns``: its values with gap and sigma, or why it has none. A live stream
        is first given up to ``wait_s`` for the samples after ``t_ns`` to arrive."""
        deadline = time.monotonic() + wait_s
        with self._arrived:
            while self._waiting_for(t_ns) and (left := deadline - time.monotonic()) > 0:
                self._arrived.wait(left)
        out: dict[str, dict[str, Any]] = {}
        for name, series in self.streams.items():
            try:
                out[name] = series.at(t_ns, reach_ns=REACH_NS[name]).to_dict()
            except LookupError as exc:
                out[name] = {"error": str(exc)}
        return out


def frame_time(header: dict[str, Any]) -> tuple[int, int] | None:
    """A frame's exposure mid-time on the host's timeline and its sigma, None when it has none."""
    t = header.get("t_ns")
    return None if t is None else (int(t), int(header.get("t_sigma_ns") or 0))
