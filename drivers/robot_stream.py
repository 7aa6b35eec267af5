"""The base's STATE/INCL sample streams on the host side: collected and published in batches.

A base of protocol version 2 with the STATE capability sends ``$STATE`` and ``$INCL`` lines
after the host's ``STATE`` command (docs/robot-protocol.md). Each sample is kept with the host
time the line was read (``host_time_ns``, the host's wall clock like every ``host_time_ns``) and
published as one message per batch (:data:`BATCH_S`) on ``robot.odometry`` and ``robot.incl``:
arrays per field, one entry per sample. The driver does not map the base's clock onto the host's
(drivers sit below the bus library): ritad does it from these same messages
(daemon/ritad/device_clock.py) and adds ``t_ns`` and ``t_sigma_ns`` before it publishes them.
"""
from __future__ import annotations

import math
import time
from typing import Any

from drivers import robot_protocol as rp
from drivers.base import Emit

#: a batch is published once its oldest sample is this old (s), or at MAX_BATCH samples
BATCH_S = 0.05
MAX_BATCH = 256

#: topic and fields (besides t_us and host_time_ns) of each stream
TOPICS = {"STATE": ("robot.odometry", ("x_mm", "y_mm", "heading_deg", "v_left_mm_s", "v_right_mm_s")),
          "INCL": ("robot.incl", ("roll_deg", "pitch_deg"))}


#: the sample lines' starts and how many fields each takes (t_us first): read by :func:`parse_sample`
_SAMPLE_START = {"$STATE,": ("STATE", 6), "$INCL,": ("INCL", 3)}
#: printable ASCII, what rp.decode accepts in a line: deleted, nothing else may remain
_PRINTABLE = bytes(range(0x20, 0x7F))


def parse_sample(raw: bytes) -> tuple[str, tuple[Any, ...]] | None:
    """A well-formed ``$STATE``/``$INCL`` line (terminator removed) as its kind and its values
    ``(t_us, field, ...)``: the same checks and the same numbers as ``rp.decode`` followed by
    ``StateSample``/``InclSample.decode``, without the objects between them (the base sends 500
    such lines a second at the simulator's speed). None for any other line, and for any fault:
    the general path then reads it and counts what is wrong."""
    if len(raw) > rp.MAX_LINE or raw[-3:-2] != b"*" or raw.translate(None, _PRINTABLE):
        return None
    text = raw.decode("ascii")
    start = _SAMPLE_START.get(text[:7] if text[1] == "S" else text[:6])
    body = text[1:-3]
    if start is None or "$" in body or "*" in body:
        return None
    value = 0
    for byte in raw[1:-3]:
        value ^= byte
    if text[-2:].upper() != f"{value:02X}":
        return None
    kind, n = start
    fields = body.split(",", n + 1)[1:n + 1]
    t = fields[0] if len(fields) == n else ""
    if not t.isdigit() or len(t) > 19:
        return None
    try:
        values = [float(f) for f in fields[1:]]
    except ValueError:
        return None
    if not all(map(math.isfinite, values)):
        return None
    return kind, (int(t), *values)


class StreamBatcher:
    """Samples read from the line, published per stream in batches."""

    def __init__(self, emit: Emit) -> None:
        self.emit = emit
        self._rows: dict[str, list[tuple[Any, ...]]] = {k: [] for k in TOPICS}
        self._since: float | None = None  # monotonic time of the oldest sample held
        self.counters = {"state_samples": 0, "incl_samples": 0}

    def take(self, raw: bytes, host_time_ns: int) -> bool:
        """A line read: kept when it is a well-formed sample (:func:`parse_sample`), else False."""
        got = parse_sample(raw)
        if got is None:
            return False
        kind, (t_us, *values) = got
        self._keep(kind, (t_us, host_time_ns, *values))
        return True

    def add(self, msg: rp.Message, host_time_ns: int) -> None:
        """One ``$STATE``/``$INCL`` message (ProtocolError when its fields are bad)."""
        if msg.kind == "STATE":
            s = rp.StateSample.decode(msg)
            row: tuple[Any, ...] = (s.t_us, host_time_ns, s.x_mm, s.y_mm, s.heading_deg, s.v_left_mm_s,
                                    s.v_right_mm_s)
        else:
            i = rp.InclSample.decode(msg)
            row = (i.t_us, host_time_ns, i.roll_deg, i.pitch_deg)
        self._keep(msg.kind, row)

    def _keep(self, kind: str, row: tuple[Any, ...]) -> None:
        self._rows[kind].append(row)
        self.counters["state_samples" if kind == "STATE" else "incl_samples"] += 1
        if self._since is None:
            self._since = time.monotonic()

    def flush(self, force: bool = False) -> None:
        """Publish the batches held when the oldest sample is BATCH_S old (or ``force``)."""
        if self._since is None:
            return
        if not force and time.monotonic() - self._since < BATCH_S and \
                max(len(r) for r in self._rows.values()) < MAX_BATCH:
            return
        self._since = None
        for kind, rows in self._rows.items():
            if not rows:
                continue
            topic, fields = TOPICS[kind]
            columns = list(zip(*rows))
            payload: dict[str, Any] = {"n": len(rows), "t_us": list(columns[0]),
                                       "host_time_ns": list(columns[1])}
            payload.update({name: list(col) for name, col in zip(fields, columns[2:])})
            self._rows[kind] = []
            self.emit(topic, payload)

    def clear(self) -> None:
        self._rows = {k: [] for k in TOPICS}
        self._since = None
