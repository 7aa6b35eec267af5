"""The simulated base's own clock and its STATE/INCL sample streams (protocol version 2).

The base stamps its samples on its own clock (µs since its own origin), which runs apart from
the host's: :class:`BaseClock` is a fixed offset plus a drift (a crystal's ppm) over the fake's
clock (the host's monotonic clock, or a test's simulated one). :class:`SampleStreams` produces
the samples at their *true* times, on a grid of the base's clock: each sample's pose and tilt
are read from the base's continuous motion at that instant (``FakeBase.state_at``), not when a
message happens to be sent, so a late tick sends late samples of the right instants.

Rates: STATE at the rate the host asked (on the base's clock, like a real base's timer); INCL at
the inclinometer's output rate, ``incl_rate_hz`` per *simulated* second (so every
``time_scale / incl_rate_hz`` of the clock): the fake's motions run ``1 / time_scale`` faster
than real, and so does its inclinometer, so a move holds as many tilt samples as on a real base.
The rate is an assumption (docs/robot-protocol.md, "Sample streams").
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np

from drivers import robot_protocol as rp

#: the inclinometer's output rate (Hz of simulated time): one reading per 1/bandwidth of the
#: SCA100T class's 10 Hz bandwidth (fakes/errors.py), whose noise is taken as 1σ per reading
INCL_RATE_HZ = 10.0
#: the shortest sample period on the base's clock (s): bounds the line rate at tiny time scales
MIN_PERIOD_S = 0.002
#: a stream further behind than this (a stalled thread) skips ahead instead of catching up
MAX_BACKLOG_S = 1.0
#: the base's default clock drift against the host's (a ±50 ppm crystal at its limit)
DEFAULT_DRIFT_PPM = 50.0


@dataclass(frozen=True)
class BaseClock:
    """The base's clock: ``offset_s + (1 + drift)·(t − origin)`` seconds at the fake's clock time ``t``."""

    origin: float
    offset_s: float
    drift_ppm: float = DEFAULT_DRIFT_PPM

    @property
    def rate(self) -> float:
        return 1.0 + self.drift_ppm * 1e-6

    def device_s(self, t: float) -> float:
        return self.offset_s + self.rate * (t - self.origin)

    def device_us(self, t: float) -> int:
        return int(math.floor(self.device_s(t) * 1e6))

    def true_time(self, device_s: float) -> float:
        """The fake's clock time at which the base's clock reads ``device_s``."""
        return self.origin + (device_s - self.offset_s) / self.rate


class StateSource(Protocol):
    """What the streams read from the base: the state at a clock time (the base's lock held)."""

    def state_at(self, t: float
                 ) -> tuple[tuple[float, float, float], tuple[float, float], tuple[float, float]]:
        """(odometry x, y, heading; wheel speeds left, right; true roll, pitch in rad) at clock time ``t``."""
        ...


class SampleStreams:
    """STATE and INCL samples due on the base's clock, generated at their true times."""

    def __init__(self, clock: BaseClock, inclinometer: Callable[[float, float], tuple[float, float]] | None,
                 time_scale: float, incl_rate_hz: float = INCL_RATE_HZ) -> None:
        if not incl_rate_hz > 0:
            raise ValueError(f"incl_rate_hz={incl_rate_hz!r} must be > 0")
        self.clock = clock
        self.inclinometer = inclinometer  # None: the base has none, so no INCL stream
        self.incl_period_s = max(MIN_PERIOD_S, time_scale / incl_rate_hz)
        self.state_hz = 0.0
        self._next_state: float | None = None  # device seconds of the next sample
        self._next_incl: float | None = None
        self.counters = {"state_samples": 0, "incl_samples": 0, "skipped": 0}

    def set_rate(self, rate_hz: float, now: float) -> None:
        """Start (or stop, 0) the streams; the next samples fall on the grid of their periods."""
        self.state_hz = rate_hz
        if rate_hz <= 0:
            self._next_state = self._next_incl = None
            return
        d = self.clock.device_s(now)
        period = max(MIN_PERIOD_S, 1.0 / rate_hz)
        self._next_state = (math.floor(d / period) + 1) * period
        self._next_incl = None if self.inclinometer is None else \
            (math.floor(d / self.incl_period_s) + 1) * self.incl_period_s

    def next_due(self, state_only: bool = False) -> float | None:
        """The fake's clock time of the next sample, or of the next STATE sample (None while the
        streams are off): the server wakes then rather than at its next tick."""
        nxt = [d for d in (self._next_state, None if state_only else self._next_incl) if d is not None]
        return self.clock.true_time(min(nxt)) if nxt else None

    def due(self, now: float, source: StateSource) -> list[bytes]:
        """The lines of every sample due by ``now`` (clock time), oldest first."""
        if self._next_state is None:
            return []
        d_now = self.clock.device_s(now)
        out: list[tuple[float, bytes]] = []
        period = max(MIN_PERIOD_S, 1.0 / self.state_hz)
        self._next_state = self._skip(self._next_state, d_now, period)
        while self._next_state <= d_now:
            d, self._next_state = self._next_state, self._next_state + period
            (x, y, h), (vl, vr), _ = source.state_at(self.clock.true_time(d))
            sample = rp.StateSample(int(round(d * 1e6)), x, y, math.remainder(h, 360.0), vl, vr)
            out.append((d, sample.encode()))
            self.counters["state_samples"] += 1
        if self._next_incl is not None and self.inclinometer is not None:
            self._next_incl = self._skip(self._next_incl, d_now, self.incl_period_s)
            while self._next_incl <= d_now:
                d, self._next_incl = self._next_incl, self._next_incl + self.incl_period_s
                _, _, (roll, pitch) = source.state_at(self.clock.true_time(d))
                r, p = self.inclinometer(roll, pitch)
                out.append((d, rp.InclSample(int(round(d * 1e6)), math.degrees(r), math.degrees(p)).encode()))
                self.counters["incl_samples"] += 1
        out.sort(key=lambda item: item[0])
        return [line for _, line in out]

    def _skip(self, nxt: float, d_now: float, period: float) -> float:
        """A stream far behind (the thread was stalled) resumes at now instead of flooding the line."""
        if d_now - nxt <= MAX_BACKLOG_S:
            return nxt
        skipped = math.floor((d_now - nxt) / period)
        self.counters["skipped"] += int(skipped)
        return nxt + skipped * period


def seeded_offset_s(rng: np.random.Generator) -> float:
    """The base's clock at the fake's start: it was powered on a while ago (seconds)."""
    return float(rng.uniform(10.0, 10_000.0))
