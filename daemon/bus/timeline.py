"""Samples of one stream on the host's timeline, looked up at any instant: "the pose at this frame's
exposure", not "the latest pose".

Each device's samples arrive with their time on the host's clock (a device clock mapped by
clockmap.py, with its sigma). A :class:`TimeSeries` keeps the last ``span_s`` of them in time
order and answers :meth:`TimeSeries.at` by linear interpolation between the two samples around
the instant, reporting the gap it bridged; outside the samples it refuses unless told how far it
may reach, and then says it extrapolated (the nearest sample, held). Angles in degrees named in
``angles`` are interpolated the short way round. Stdlib only, like clockmap.py, so every program
of the bus library can use it.
"""
from __future__ import annotations

import bisect
import math
import threading
from dataclasses import dataclass
from typing import Sequence

#: how long a stream's samples are kept by default (s): longer than any approach move
DEFAULT_SPAN_S = 120.0


@dataclass(frozen=True)
class At:
    """A stream's value at ``t_ns``: what :meth:`TimeSeries.at` found."""

    values: dict[str, float]
    t_ns: int
    #: the time between the two samples interpolated, or from the instant to the sample held (ns)
    gap_ns: int
    #: the larger time sigma of the samples used (ns; 0 when their times were exact)
    sigma_ns: int
    #: the instant lies outside the samples: the nearest one is held
    extrapolated: bool = False

    def to_dict(self) -> dict[str, object]:
        return {**self.values, "t_ns": self.t_ns, "gap_ns": self.gap_ns, "t_sigma_ns": self.sigma_ns,
                "extrapolated": self.extrapolated}


class TimeSeries:
    """One stream's recent samples (thread-safe: devices add in their threads, commands read in theirs)."""

    def __init__(self, name: str, fields: Sequence[str], *, angles: Sequence[str] = (),
                 span_s: float = DEFAULT_SPAN_S) -> None:
        if not fields or len(set(fields)) != len(fields):
            raise ValueError(f"timeline {name!r}: fields must be distinct names, got {list(fields)}")
        if not set(angles) <= set(fields):
            raise ValueError(f"timeline {name!r}: angles {sorted(set(angles) - set(fields))} are not fields")
        if not span_s > 0:
            raise ValueError(f"timeline {name!r}: span_s={span_s!r} must be > 0")
        self.name, self.fields = name, tuple(fields)
        self._angle = [f in angles for f in self.fields]
        self._span_ns = int(span_s * 1e9)
        self._t: list[int] = []
        self._v: list[tuple[float, ...]] = []
        self._s: list[int] = []
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._t)

    def add(self, t_ns: int, values: Sequence[float], sigma_ns: int = 0) -> None:
        """One sample; out of order is fine (it is put in its place), older than the span is dropped."""
        if len(values) != len(self.fields):
            raise ValueError(f"timeline {self.name!r}: {len(values)} values for fields {list(self.fields)}")
        row = tuple(float(v) for v in values)
        with self._lock:
            i = bisect.bisect_right(self._t, t_ns)
            self._t.insert(i, int(t_ns))
            self._v.insert(i, row)
            self._s.insert(i, int(sigma_ns))
            cut = bisect.bisect_left(self._t, self._t[-1] - self._span_ns)
            if cut > len(self._t) // 2:  # trim in batches: a list's front delete is O(n)
                del self._t[:cut], self._v[:cut], self._s[:cut]

    def at(self, t_ns: int, *, reach_ns: int = 0) -> At:
        """The stream at ``t_ns``; beyond its samples by at most ``reach_ns`` (then held, ``extrapolated``).

        LookupError names the stream and how far its nearest sample is when it cannot answer.
        """
        with self._lock:
            n = len(self._t)
            if n == 0:
                raise LookupError(f"timeline {self.name!r}: no samples yet")
            i = bisect.bisect_left(self._t, t_ns)
            if i < n and self._t[i] == t_ns:
                return At(self._dict(self._v[i]), t_ns, 0, self._s[i])
            if 0 < i < n:
                return self._between(i - 1, i, t_ns)
            j = 0 if i == 0 else n - 1
            gap = abs(self._t[j] - t_ns)
            if gap > reach_ns:
                side = "before the first" if i == 0 else "after the last"
                raise LookupError(f"timeline {self.name!r}: {t_ns} ns is {gap / 1e6:.3f} ms {side} sample "
                                  f"(may reach {reach_ns / 1e6:.3f} ms)")
            return At(self._dict(self._v[j]), t_ns, gap, self._s[j], extrapolated=True)

    def _between(self, a: int, b: int, t_ns: int) -> At:
        ta, tb = self._t[a], self._t[b]
        f = (t_ns - ta) / (tb - ta)
        out = []
        for k, (va, vb) in enumerate(zip(self._v[a], self._v[b])):
            d = vb - va
            if self._angle[k]:
                d = math.remainder(d, 360.0)  # the short way round
            v = va + f * d
            out.append(math.remainder(v, 360.0) if self._angle[k] else v)
        return At(self._dict(tuple(out)), t_ns, tb - ta, max(self._s[a], self._s[b]))

    def _dict(self, row: tuple[float, ...]) -> dict[str, float]:
        return dict(zip(self.fields, row))

    def span(self) -> tuple[int, int] | None:
        """(first, last) sample time, None when empty."""
        with self._lock:
            return (self._t[0], self._t[-1]) if self._t else None
