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


class StreamBatcher:
    """Samples read from the line, published per stream in batches."""

    def __init__(self, emit: Emit) -> None:
        self.emit = emit
        self._rows: dict[str, list[tuple[Any, ...]]] = {k: [] for k in TOPICS}
        self._since: float | None = None  # monotonic time of the oldest sample held
        self.counters = {"state_samples": 0, "incl_samples": 0}

    def add(self, msg: rp.Message, host_time_ns: int) -> None:
        """One ``$STATE``/``$INCL`` message (ProtocolError when its fields are bad)."""
        if msg.kind == "STATE":
            s = rp.StateSample.decode(msg)
            row: tuple[Any, ...] = (s.t_us, host_time_ns, s.x_mm, s.y_mm, s.heading_deg, s.v_left_mm_s,
                                    s.v_right_mm_s)
        else:
            i = rp.InclSample.decode(msg)
            row = (i.t_us, host_time_ns, i.roll_deg, i.pitch_deg)
        self._rows[msg.kind].append(row)
        self.counters["state_samples" if msg.kind == "STATE" else "incl_samples"] += 1
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
            payload: dict[str, Any] = {"n": len(rows), "t_us": list(columns[0]), "host_time_ns": list(columns[1])}
            payload.update({name: list(col) for name, col in zip(fields, columns[2:])})
            self._rows[kind] = []
            self.emit(topic, payload)

    def clear(self) -> None:
        self._rows = {k: [] for k in TOPICS}
        self._since = None
