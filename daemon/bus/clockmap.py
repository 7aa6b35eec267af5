"""A device clock mapped onto the host's, estimated online: offset, drift and an honest sigma.

Model. A device stamps an event at its own time ``d``; the host sees the message at
``h_rx = T(d) + latency``, where ``T(d) = d + offset + drift·d`` is the event's host time and
the latency is never negative: a delayed message only ever arrives later. So the points
``(d, h_rx − d)`` lie on or above the line ``T(d) − d``, and the least-delayed ones touch it.

Fit (one-way samples, ``add(device_ns, host_rx_ns)``). Samples are reduced to the lowest one
per bin of device time (``bin_s``, a min-filter), the bins older than ``window_s`` dropped. The
line is the lower envelope of the bins (their lower convex hull) chosen as TICSync and the
linear-programming skew estimators do: the line under every point that is highest at the
samples' mean device time, i.e. the hull edge spanning it (the hull is kept as bins come and
go, not rebuilt for each fit). Its slope is the drift; a fit with fewer than ``MIN_DRIFT_BINS``
bins, or whose slope is known no better than the drift prior ``prior_drift_ppm``, takes no drift
(the lowest point's offset) and states the prior in its sigma instead. Delayed packets lie above
the line and move nothing; only a message stamped *early* (a clock fault) could pull it down.

Sigma. The fitted line sits above the truth by about the least latency among the bins near
the hull's contacts. Where the latency's density at its floor is f, the bins' residuals
above the line grow like rank/(n·f), so the k-th smallest residual over k (k =
``K_ORDER``) measures the spacing at the floor; ``ENVELOPE_SIGMA_SCALE`` times that is the
envelope's sigma at the samples' centre. With fewer than 2·``K_ORDER`` bins it is at least
``prior_latency_ns``/n (with fewer than ``MIN_DRIFT_BINS``, exactly that: the latency cannot
be read from so few). Away from the centre the sigma grows with the slope's uncertainty:
the lowest residual of each of ``SEGMENTS`` stretches of the window, fitted by least squares,
gives the slope's error (its slope and standard error) and how far the envelope may sit
above the truth at the window's ends (their RMS per half span), so an extrapolation says
how far it reaches. The device time's resolution adds ``resolution_ns``/√12.

Exchanges (``add(device_ns, host_rx_ns, host_tx_ns)``: the host asked at ``host_tx_ns``) bound
the event from both sides: ``host_tx_ns ≤ T(d) ≤ host_rx_ns``. The receive side's lower
envelope and the send side's upper envelope are fitted alike; the mapping is their middle
and the sigma adds their gap as a uniform spread (gap/√12). A map with exchanges in its
window uses only those.

What one-way samples cannot see: the latency's fixed part (cable, driver, the device's own
delay before sending). ``min_latency_ns`` states it, known from elsewhere, and is subtracted.
A lasting change of that fixed part looks the same as a clock step; the map follows it
within one window. A device clock that steps back by more than ``RESET_BACK_S`` (a restart),
or forward so far that a sample arrives more than ``RESET_BACK_S`` before the lowest offset seen
allows (a clock set to another time scale, e.g. a camera locking onto PTP time; late samples
cannot do this, the latency is never negative), starts the map afresh.

Time scales. PTP (IEEE 1588) clocks count TAI; the host's clock counts UTC. They differ by
``TAI_MINUS_UTC_S`` whole seconds, the leap seconds inserted so far.

Stdlib only: the laptop's client imports the bus library without numpy.
"""
from __future__ import annotations

import heapq
import math
from bisect import bisect_left
from collections import deque
from dataclasses import dataclass
from typing import Any, Sequence

DEFAULT_WINDOW_S = 60.0
DEFAULT_BIN_S = 0.1
#: the residual rank the floor's spacing is read from (the hull's own contacts are 0)
K_ORDER = 10
#: envelope sigma per residual spacing at the floor (tests/daemon/bus/test_clockmap.py checks coverage)
ENVELOPE_SIGMA_SCALE = 3.0
#: bins below which no drift is fitted (and the latency is not read from the data)
MIN_DRIFT_BINS = 5
#: stretches of the window whose lowest samples tell how well the slope is known
SEGMENTS = 12
#: a device clock stepping back by more than this restarted: the map starts afresh
RESET_BACK_S = 1.0
#: a drift beyond this is no crystal's: the fit is clamped to it
MAX_DRIFT_PPM = 1000.0
#: TAI − UTC in seconds since 2017-01-01 (IERS Bulletin C; no leap second announced since): PTP
#: time, which counts TAI, is this far ahead of the host's UTC clock
TAI_MINUS_UTC_S = 37


@dataclass(frozen=True)
class _Line:
    """``y(x) = a + b·(x − x0)``, ``x`` device ns, ``y`` host − device ns (relative to ``y0``)."""
    x0: int
    y0: int
    a: float
    b: float
    sigma: float        # at the samples' centre
    slope_sigma: float  # the slope's (the drift prior when no drift was fitted)
    centre: float       # device ns relative to x0
    drift_fitted: bool
    edge_per_ns: float = 0.0  # the segments' RMS per half span: growth of sigma toward the ends

    def at(self, x: int) -> float:
        return self.y0 + self.a + self.b * (x - self.x0)

    def sigma_at(self, x: int) -> float:
        dx = abs((x - self.x0) - self.centre)
        return math.sqrt(self.sigma ** 2 + (self.slope_sigma * dx) ** 2 + (self.edge_per_ns * dx) ** 2)


class _Bins:
    """The lowest ``y`` per bin of device time over a sliding window, and the lower convex hull of
    all but the newest bin kept as bins come and go (the newest one's minimum still moves)."""

    def __init__(self, bin_ns: int, window_ns: int) -> None:
        self.bin_ns, self.window_ns = bin_ns, window_ns
        self.bins: deque[list[int]] = deque()  # [key, x, y, count]
        self._closed: list[list[int]] | None = []  # hull of bins[:-1]; None: rebuild when read

    def add(self, x: int, y: int) -> bool:
        """One point; whether the bins' minima changed (a sample above its bin's lowest one changes
        nothing a fit reads: the map keeps its fit)."""
        key = x // self.bin_ns
        for i in range(len(self.bins) - 1, -1, -1):  # almost always the last bin or a new one
            b = self.bins[i]
            if b[0] == key:
                b[3] += 1
                if y < b[2]:
                    b[1], b[2] = x, y
                    if i < len(self.bins) - 1:  # a late sample lowered a closed bin: its hull is stale
                        self._closed = None
                    return True
                return False
            if b[0] < key:
                break
        if self.bins and self._closed is not None:  # the newest bin is closed by a later one
            _push(self._closed, self.bins[-1])
        self.bins.append([key, x, y, 1])
        if len(self.bins) > 1 and self.bins[-2][0] > key:  # late and in a bin of its own: keep order
            self.bins, self._closed = deque(sorted(self.bins)), None
        newest = self.bins[-1][0]
        while self.bins and (newest - self.bins[0][0]) * self.bin_ns > self.window_ns:
            self._drop_front()
        return True

    def _drop_front(self) -> None:
        """Drop the oldest bin. The hull's second vertex stays a vertex without the first (an extreme
        point of a set is one of every subset holding it): only the bins before it are chained afresh."""
        front = self.bins.popleft()
        if self._closed is None:
            return
        rest = self._closed[1:] if self._closed and self._closed[0] is front else None
        if not rest:  # the closed hull held the front alone (or was not built from it): rebuild it
            self._closed = None
            return
        prefix: list[list[int]] = []
        for b in self.bins:  # up to the second vertex, which the new start's chain ends on
            prefix.append(b)
            if b is rest[0]:
                break
        self._closed = _chain(prefix) + rest[1:]

    def hull(self) -> list[list[int]]:
        """The bins of the lower convex hull of all the bins, in device time order."""
        if self._closed is None:
            self._closed = _chain(list(self.bins)[:-1])
        hull = list(self._closed)
        _push(hull, self.bins[-1])
        return hull


def _push(hull: list[list[int]], p: list[int]) -> None:
    """One step of Andrew's monotone chain: append bin ``p`` (right of all in ``hull``), first
    dropping the vertices on or above the segment to it. Exact: the bins' times are integers."""
    while len(hull) >= 2:
        j, k = hull[-2], hull[-1]
        if (k[1] - j[1]) * (p[2] - j[2]) - (k[2] - j[2]) * (p[1] - j[1]) > 0:  # a left turn stays
            break
        hull.pop()
    hull.append(p)


def _chain(bins: list[list[int]]) -> list[list[int]]:
    """The lower convex hull of bins sorted by device time (Andrew's monotone chain)."""
    hull: list[list[int]] = []
    for b in bins:
        _push(hull, b)
    return hull


def _slope_sigma(xs: Sequence[float], res: Sequence[float]) -> tuple[float, float] | None:
    """How well the line's slope is known, from the lowest residual of each of up to
    ``SEGMENTS`` stretches of the window: (the slope of a least-squares line through them and
    its standard error from their scatter, in quadrature; their RMS, how far the envelope may
    sit above the truth at the window's ends); None with too few stretches to tell."""
    span = xs[-1] - xs[0]
    m = min(SEGMENTS, len(xs) // 2)
    if m < 4 or span <= 0:
        return None

    def stretch(x: float) -> int:  # non-decreasing in x: each stretch is one run of the sorted xs
        return min(m - 1, int((x - xs[0]) / span * m))
    starts = [bisect_left(xs, j, key=stretch) for j in range(m)] + [len(xs)]
    lowest = [min(range(i, k), key=res.__getitem__) for i, k in zip(starts, starts[1:]) if i < k]
    pts = [(xs[i], res[i]) for i in lowest]
    if len(pts) < 4:
        return None
    mx = sum(p[0] for p in pts) / len(pts)
    my = sum(p[1] for p in pts) / len(pts)
    sxx = sum((p[0] - mx) ** 2 for p in pts)
    slope = sum((p[0] - mx) * (p[1] - my) for p in pts) / sxx
    var = sum((p[1] - my - slope * (p[0] - mx)) ** 2 for p in pts) / (len(pts) - 2)
    rms = math.sqrt(sum(p[1] ** 2 for p in pts) / len(pts))
    return math.hypot(slope, math.sqrt(var / sxx)), rms


def _envelope_sigma(res: list[float], prior_latency_ns: float) -> float:
    """The envelope's sigma from the residuals above it: the floor's spacing, scaled; with fewer
    than 2·``K_ORDER`` bins at least the prior's latency over their number."""
    n = len(res)
    k = min(K_ORDER, n)
    sigma = ENVELOPE_SIGMA_SCALE * heapq.nsmallest(k, res)[-1] / k  # the k-th smallest, no full sort
    return max(sigma, prior_latency_ns / n) if n < 2 * K_ORDER else sigma


def _fit_lower(bins: _Bins, prior_latency_ns: float, prior_drift: float) -> _Line | None:
    """The lower envelope line of the bins' minima and its sigma (module docstring)."""
    if not bins.bins:
        return None
    x0, y0 = bins.bins[0][1], bins.bins[0][2]
    xs = [float(b[1] - x0) for b in bins.bins]
    ys = [float(b[2] - y0) for b in bins.bins]
    n = len(xs)
    centre = sum(xs) / n
    if n < MIN_DRIFT_BINS:
        return _Line(x0, y0, min(ys), 0.0, prior_latency_ns / n, prior_drift, centre, False)
    hull = [(float(h[1] - x0), float(h[2] - y0)) for h in bins.hull()]
    b = 0.0
    for (xj, yj), (xk, yk) in zip(hull, hull[1:]):  # the hull edge spanning the centre
        if xj <= centre <= xk and xk > xj:
            b = (yk - yj) / (xk - xj)
            break
    lim = MAX_DRIFT_PPM * 1e-6
    b = min(lim, max(-lim, b))
    # lowest at a hull vertex, but bins on an edge between two vertices round differently: taken over
    # every bin, the offset does not depend on which of such bins the hull kept
    a = min(y - b * x for x, y in zip(xs, ys))
    res = [y - a - b * x for x, y in zip(xs, ys)]
    slope = _slope_sigma(xs, res)
    if slope is None or slope[0] > prior_drift:  # the window cannot tell the drift yet
        a = min(ys)
        envelope = _envelope_sigma([y - a for y in ys], prior_latency_ns)
        return _Line(x0, y0, a, 0.0, envelope, prior_drift, centre, False)
    half_span = max(xs[-1] - centre, centre - xs[0], 1.0)
    return _Line(x0, y0, a, b, _envelope_sigma(res, prior_latency_ns), slope[0], centre, True,
                 slope[1] / half_span)


class ClockMap:
    """One device clock's mapping onto the host clock (module docstring: the method)."""

    def __init__(self, window_s: float = DEFAULT_WINDOW_S, bin_s: float = DEFAULT_BIN_S,
                 prior_latency_ns: float = 5e6, prior_drift_ppm: float = 100.0,
                 resolution_ns: float = 1.0, min_latency_ns: int = 0) -> None:
        for name, v in (("window_s", window_s), ("bin_s", bin_s), ("prior_latency_ns", prior_latency_ns),
                        ("prior_drift_ppm", prior_drift_ppm), ("resolution_ns", resolution_ns)):
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a positive number, got {v!r}")
        if not bin_s < window_s:
            raise ValueError(f"bin_s ({bin_s!r}) must be below window_s ({window_s!r})")
        self.window_ns, self.bin_ns = int(window_s * 1e9), max(1, int(bin_s * 1e9))
        self.prior_latency_ns, self.prior_drift = float(prior_latency_ns), prior_drift_ppm * 1e-6
        self.floor_ns = resolution_ns / math.sqrt(12.0)
        self.min_latency_ns = int(min_latency_ns)
        self.resets = 0  # restarts of the device clock seen
        self.reset()

    def reset(self) -> None:
        """Forget every sample (a device clock that restarted)."""
        self._rx = _Bins(self.bin_ns, self.window_ns)
        self._tx = _Bins(self.bin_ns, self.window_ns)  # send side of exchanges, y negated
        self._rx_ex = _Bins(self.bin_ns, self.window_ns)  # receive side of exchanges
        self._newest: int | None = None
        self._floor_y: int | None = None  # the lowest received − device time since the reset
        self._fit: tuple[_Line | None, _Line | None] | None = None

    def add(self, device_ns: int, host_rx_ns: int, host_tx_ns: int | None = None) -> None:
        """One sample: the device's time of an event and when the host received it (and, for an
        exchange, when the host asked)."""
        d, rx = int(device_ns), int(host_rx_ns)
        stepped_back = self._newest is not None and d < self._newest - RESET_BACK_S * 1e9
        # received this much before any earlier sample's offset allows: the clock jumped ahead
        stepped_ahead = self._floor_y is not None and rx - d < self._floor_y - RESET_BACK_S * 1e9
        if stepped_back or stepped_ahead:
            self.reset()
            self.resets += 1
        self._floor_y = rx - d if self._floor_y is None else min(self._floor_y, rx - d)
        if host_tx_ns is None:
            changed = self._rx.add(d, rx - d)
        else:
            tx = int(host_tx_ns)
            if tx > rx:
                raise ValueError(f"host_tx_ns {tx} is after host_rx_ns {rx}")
            changed = self._rx_ex.add(d, rx - d) | self._tx.add(d, d - tx)
        self._newest = d if self._newest is None else max(self._newest, d)
        if changed:  # the fit reads only the bins' minima: refitting after every sample cost the most
            self._fit = None

    def _lines(self) -> tuple[_Line | None, _Line | None]:
        """(receive-side line, send-side line negated or None), refitted after new samples."""
        if self._fit is None:
            if self._rx_ex.bins:
                self._fit = (_fit_lower(self._rx_ex, self.prior_latency_ns, self.prior_drift),
                             _fit_lower(self._tx, self.prior_latency_ns, self.prior_drift))
            else:
                self._fit = (_fit_lower(self._rx, self.prior_latency_ns, self.prior_drift), None)
        return self._fit

    def map(self, device_ns: int) -> tuple[int, int]:
        """(t_ns, t_sigma_ns): the host time of the device time ``device_ns`` and its sigma."""
        hi, lo = self._lines()
        if hi is None:
            raise ValueError("the clock map has no samples yet")
        d = int(device_ns)
        s_hi = hi.sigma_at(d)
        if lo is None:
            t = d + hi.at(d) - self.min_latency_ns
            return int(round(t)), int(math.ceil(math.hypot(s_hi, self.floor_ns)))
        y_hi, y_lo = hi.at(d), -lo.at(d)
        s_lo = lo.sigma_at(d)
        gap = max(0.0, y_hi - y_lo)
        sigma = math.sqrt((gap / math.sqrt(12.0)) ** 2 + (s_hi ** 2 + s_lo ** 2) / 4 + self.floor_ns ** 2)
        return int(round(d + (y_hi + y_lo) / 2)), int(math.ceil(sigma))

    def map_many(self, device_ns: Sequence[int]) -> tuple[list[int], list[int]]:
        """:meth:`map` of each device time: (t_ns list, t_sigma_ns list)."""
        out = [self.map(d) for d in device_ns]
        return [t for t, _ in out], [s for _, s in out]

    def status(self) -> dict[str, Any]:
        """The mapping at the newest sample: offset (host − device, ns), drift (ppm), sigma (ns),
        samples in the window, the window's span (s), whether exchanges bound it, restarts seen."""
        hi, lo = self._lines()
        if hi is None or self._newest is None:
            return {"offset_ns": None, "drift_ppm": None, "sigma_ns": None, "samples": 0,
                    "window_s": 0.0, "two_way": False, "resets": self.resets}
        t, s = self.map(self._newest)
        drift = hi.b if lo is None else (hi.b - lo.b) / 2
        bins = self._rx_ex.bins if lo is not None else self._rx.bins
        fitted = hi.drift_fitted and (lo is None or lo.drift_fitted)
        return {"offset_ns": t - self._newest, "drift_ppm": round(drift * 1e6, 3) if fitted else None,
                "sigma_ns": s, "samples": sum(b[3] for b in bins),
                "window_s": round((bins[-1][1] - bins[0][1]) / 1e9, 3), "two_way": lo is not None,
                "resets": self.resets}
