"""The console's live time series: the robot's pose, its wheel speeds and the tracker's distance.

The page plots them; the console keeps them, so a tab opened late (or reconnected) starts with
the last ``KEEP`` points instead of an empty plot, and a tab that reads slowly misses none of the
kept points (the telemetry it shows as numbers is coalesced to the newest value instead).

Each point is ``{no, s, t, v}``: its number (a tab asks for those after the last it has), the
series' name (``SERIES``), ``t`` the sample's time in ms on the console's clock and ``v`` the
values. ``t`` is when the console received the message less how old the sample already was when
ritad published it (the message's own time minus the sample's, both on the robot's clock), so a
page's ``Date.now() - t`` is the sample's age even where the robot's and the laptop's clocks
disagree (only the console and the page, on one computer, share a clock).
"""
from __future__ import annotations

import collections
import math
import threading
from typing import Any, Iterator, Sequence

from daemon.bus.names import Topic

#: series -> value names and units, in the order of ``v`` (the page labels its plots with them)
SERIES: dict[str, tuple[tuple[str, str], ...]] = {
    "pose": (("x", "mm"), ("y", "mm"), ("heading", "°")),
    "wheels": (("left", "mm/s"), ("right", "mm/s")),
    "tracker": (("distance", "mm"),),
}
#: fewest ms between two kept points of one series: 10 points/s draw a smooth line over a minute
MIN_STEP_MS = 100.0
#: points kept for all series together: two minutes of the three series at 10 points/s
KEEP = 3600
#: odometry newer than this (ms) makes robot.state's pose redundant: one source per value at a time
ODOMETRY_FRESH_MS = 2000.0


def _column(data: dict[str, Any], name: str, n: int) -> list[float]:
    """A columnar field as n floats (NaN where it is missing or not a number)."""
    col = data.get(name)
    if not isinstance(col, (list, tuple)) or len(col) < n:
        return [math.nan] * n
    return [float(v) if isinstance(v, (int, float)) else math.nan for v in col[:n]]


def _sample_ns(data: dict[str, Any], n: int) -> list[float]:
    """Each record's time on the robot's timeline: its mapped ``t_ns``, else when the host read it."""
    for name in ("t_ns", "host_time_ns"):
        col = _column(data, name, n)
        if all(math.isfinite(v) for v in col):
            return col
    one = data.get("host_time_ns")
    return [float(one)] * n if isinstance(one, (int, float)) else [math.nan] * n


def rows(topic: str, data: Any) -> Iterator[tuple[str, float, list[float]]]:
    """(series, sample time ns on the robot's clock, values) of one telemetry message."""
    if not isinstance(data, dict):
        return
    n = data.get("n", 1)
    n = n if isinstance(n, int) and n > 0 else 0
    if topic == Topic.ROBOT_ODOMETRY:
        t = _sample_ns(data, n)
        pose = [_column(data, k, n) for k in ("x_mm", "y_mm", "heading_deg")]
        wheels = [_column(data, k, n) for k in ("v_left_mm_s", "v_right_mm_s")]
        for i in range(n):
            yield "pose", t[i], [c[i] for c in pose]
            yield "wheels", t[i], [c[i] for c in wheels]
    elif topic == Topic.TRACKER_POINT:
        t = _sample_ns(data, n)
        xyz = [_column(data, k, n) for k in ("x", "y", "z")]
        for i in range(n):
            yield "tracker", t[i], [math.sqrt(sum(c[i] ** 2 for c in xyz))]   # from the tracker's origin
    elif topic == Topic.ROBOT_STATE:
        when = data.get("t_ns")   # a base without a clock has none: the message's own time stands in
        status = [v for k in ("x_mm", "y_mm", "heading_deg") if isinstance(v := data.get(k), (int, float))]
        if len(status) == 3:
            t_ns = float(when) if isinstance(when, (int, float)) else math.nan
            yield "pose", t_ns, [float(v) for v in status]


def finite(values: Sequence[float]) -> list[float | None]:
    """JSON has no NaN: a missing value is null (the page leaves a gap)."""
    return [v if math.isfinite(v) else None for v in values]


class Series:
    """The kept points of every series; ``add`` from the bus reader, ``since`` from the web side."""

    def __init__(self, keep: int = KEEP, min_step_ms: float = MIN_STEP_MS) -> None:
        self._points: collections.deque[dict[str, Any]] = collections.deque(maxlen=keep)
        self._lock = threading.Lock()
        self._no = 0
        self._last: dict[str, float] = {}   # series -> t of its last kept point
        self._odometry_at = -math.inf       # console ms of the newest odometry
        self.min_step_ms = min_step_ms

    def add(self, topic: str, published_ns: Any, data: Any, recv_ms: float) -> int:
        """Keep the points of one message (received at ``recv_ms``, console clock); how many were kept."""
        if topic == Topic.ROBOT_ODOMETRY:
            self._odometry_at = recv_ms
        elif topic == Topic.ROBOT_STATE and recv_ms - self._odometry_at < ODOMETRY_FRESH_MS:
            return 0   # the base streams its pose: its polled status would only repeat it, later
        kept = 0
        with self._lock:
            for name, sample_ns, values in rows(topic, data):
                lag_ms = (published_ns - sample_ns) / 1e6 if isinstance(published_ns, (int, float)) else 0.0
                t = recv_ms - (lag_ms if math.isfinite(lag_ms) and lag_ms >= 0 else 0.0)
                if t - self._last.get(name, -math.inf) < self.min_step_ms:
                    continue
                self._last[name] = t
                self._no += 1
                self._points.append({"no": self._no, "s": name, "t": round(t, 1), "v": finite(values)})
                kept += 1
        return kept

    def since(self, no: int) -> list[dict[str, Any]]:
        """Kept points numbered after ``no``, oldest first."""
        with self._lock:
            return [p for p in self._points if p["no"] > no]
