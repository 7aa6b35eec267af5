"""The clock map's lower-envelope fit against the algorithm it replaced (kept here as the reference).

The product keeps the lower hull as bins come and go and reads only the hull's vertices for the
line; the reference rebuilt the hull over the whole window in floats and took the line's lowest
point over every bin. Both are fed the same seeded streams, bin by bin, and every fit is compared:
random windows (late and duplicated device times, gaps, window drops), exactly collinear bins, a
drift beyond the clamp, and the first bins (fewer than ``MIN_DRIFT_BINS``).
"""
from __future__ import annotations

import math
import random
from collections import deque
from typing import Sequence

import pytest

from daemon.bus import clockmap as cm
from daemon.bus.clockmap import _Bins, _fit_lower, _Line

MS = 1_000_000


def ref_lower_hull(xs: Sequence[float], ys: Sequence[float]) -> list[int]:
    hull: list[int] = []
    for i in range(len(xs)):
        while len(hull) >= 2:
            j, k = hull[-2], hull[-1]
            cross = (xs[k] - xs[j]) * (ys[i] - ys[j]) - (ys[k] - ys[j]) * (xs[i] - xs[j])
            if cross > 0:
                break
            hull.pop()
        hull.append(i)
    return hull


def ref_slope_sigma(xs: Sequence[float], res: Sequence[float]) -> tuple[float, float] | None:
    span = xs[-1] - xs[0]
    m = min(cm.SEGMENTS, len(xs) // 2)
    if m < 4 or span <= 0:
        return None
    low: dict[int, tuple[float, float]] = {}
    for x, r in zip(xs, res):
        j = min(m - 1, int((x - xs[0]) / span * m))
        if j not in low or r < low[j][1]:
            low[j] = (x, r)
    pts = list(low.values())
    if len(pts) < 4:
        return None
    mx = sum(p[0] for p in pts) / len(pts)
    my = sum(p[1] for p in pts) / len(pts)
    sxx = sum((p[0] - mx) ** 2 for p in pts)
    slope = sum((p[0] - mx) * (p[1] - my) for p in pts) / sxx
    var = sum((p[1] - my - slope * (p[0] - mx)) ** 2 for p in pts) / (len(pts) - 2)
    rms = math.sqrt(sum(p[1] ** 2 for p in pts) / len(pts))
    return math.hypot(slope, math.sqrt(var / sxx)), rms


def ref_envelope_sigma(res: list[float], prior_latency_ns: float) -> float:
    res = sorted(res)
    n = len(res)
    k = min(cm.K_ORDER, n)
    sigma = cm.ENVELOPE_SIGMA_SCALE * res[k - 1] / k
    return max(sigma, prior_latency_ns / n) if n < 2 * cm.K_ORDER else sigma


def ref_fit_lower(bins: deque[list[int]], prior_latency_ns: float, prior_drift: float) -> _Line | None:
    """The fit as it was before the hull was kept (daemon/bus/clockmap.py at c8c9215)."""
    if not bins:
        return None
    x0, y0 = bins[0][1], bins[0][2]
    xs = [float(b[1] - x0) for b in bins]
    ys = [float(b[2] - y0) for b in bins]
    n = len(xs)
    centre = sum(xs) / n
    if n < cm.MIN_DRIFT_BINS:
        return _Line(x0, y0, min(ys), 0.0, prior_latency_ns / n, prior_drift, centre, False)
    hull = ref_lower_hull(xs, ys)
    b = 0.0
    for j, k in zip(hull, hull[1:]):
        if xs[j] <= centre <= xs[k] and xs[k] > xs[j]:
            b = (ys[k] - ys[j]) / (xs[k] - xs[j])
            break
    lim = cm.MAX_DRIFT_PPM * 1e-6
    b = min(lim, max(-lim, b))
    a = min(y - b * x for x, y in zip(xs, ys))
    res = [y - a - b * x for x, y in zip(xs, ys)]
    slope = ref_slope_sigma(xs, res)
    if slope is None or slope[0] > prior_drift:
        a = min(ys)
        envelope = ref_envelope_sigma([y - a for y in ys], prior_latency_ns)
        return _Line(x0, y0, a, 0.0, envelope, prior_drift, centre, False)
    half_span = max(xs[-1] - centre, centre - xs[0], 1.0)
    return _Line(x0, y0, a, b, ref_envelope_sigma(res, prior_latency_ns), slope[0], centre, True,
                 slope[1] / half_span)


FIELDS = ("a", "b", "sigma", "slope_sigma", "centre", "edge_per_ns")


def compare(samples: list[tuple[int, int]], bin_ns: int, window_ns: int, prior_drift: float = 100e-6) -> int:
    """Feed ``samples`` (device ns, host − device ns) one by one; after each, the product's fit must
    equal the reference's. Returns the number of fits compared."""
    bins, fits = _Bins(bin_ns, window_ns), 0
    for x, y in samples:
        bins.add(x, y)
        new, ref = _fit_lower(bins, 5e6, prior_drift), ref_fit_lower(bins.bins, 5e6, prior_drift)
        assert new is not None and ref is not None
        assert (new.x0, new.y0, new.drift_fitted) == (ref.x0, ref.y0, ref.drift_fitted), (new, ref)
        for f in FIELDS:
            assert getattr(new, f) == getattr(ref, f), (f, new, ref, fits)
        fits += 1
    return fits


def stream(rng: random.Random, n: int, bin_ns: int, drift: float, late: float, dup: float,
           gap: float) -> list[tuple[int, int]]:
    """A device clock with ``drift`` stamped at 1 µs, samples a random fraction of a bin apart, the
    latency exponential (mean 1 ms, capped 5 ms); some late (stamped up to 3 bins back), some at an
    earlier sample's device time, some after a gap of up to 300 bins (most windows are shorter)."""
    out: list[tuple[int, int]] = []
    t = rng.randrange(10**12)
    for _ in range(n):
        step = rng.uniform(0.05, 1.5) + (rng.uniform(0, 300) if rng.random() < gap else 0.0)  # in bins
        t += int(step * bin_ns)
        d = t - int(rng.uniform(0, 3) * bin_ns) if rng.random() < late else t
        if out and rng.random() < dup:
            d = out[rng.randrange(max(0, len(out) - 20), len(out))][0]
        y = 1_000_000_007 + int(drift * d) + int(min(rng.expovariate(1e3), 5e-3) * 1e9)
        out.append((d // 1000 * 1000, y))
    return out


@pytest.mark.parametrize("seed", range(12))
def test_random_windows_equal_the_reference(seed):
    rng = random.Random(seed)
    bin_ns = rng.choice([10 * MS, 100 * MS, 250 * MS])
    window_ns = bin_ns * rng.choice([3, 8, 40, 150])
    drift = rng.choice([0.0, 50e-6, -80e-6, 900e-6, 2500e-6, -4000e-6])  # the last two beyond the clamp
    samples = stream(rng, 700, bin_ns, drift, late=rng.choice([0.0, 0.05]), dup=rng.choice([0.0, 0.1]),
                     gap=rng.choice([0.0, 0.01]))
    assert compare(samples, bin_ns, window_ns, prior_drift=rng.choice([100e-6, 5000e-6])) == 700


def test_collinear_bins_equal_the_reference():
    """Bins exactly on lines (integer slopes per bin): the hull drops the points between, in both."""
    rng = random.Random(4)
    samples = [(k * 100 * MS, 7 * k) for k in range(60)]  # one line
    samples += [(k * 100 * MS, 7 * k + rng.choice([0, 0, 3, 50])) for k in range(60, 200)]  # on it or above
    samples += [(k * 100 * MS + 5, 7 * k - 1) for k in range(200, 260)]  # a parallel line, 1 ns lower
    assert compare(samples, 100 * MS, 3000 * MS, prior_drift=5e-6) == 260


def test_clamped_drift_and_the_first_bins_equal_the_reference():
    lim = cm.MAX_DRIFT_PPM * 1e-6
    for slope in (3 * lim, -3 * lim):  # a drift no crystal has: the line's slope is clamped
        samples = [(k * 100 * MS, 10**9 + int(slope * k * 100 * MS) + 37 * (k % 3)) for k in range(80)]
        fit = ref_fit_lower(deque([[k, x, y, 1] for k, (x, y) in enumerate(samples)]), 5e6, 1.0)
        assert fit is not None and fit.b == math.copysign(lim, slope)  # the case is the clamp's
        assert compare(samples, 100 * MS, 10**10, prior_drift=1.0) == 80
    few = compare([(k * 100 * MS, 5000 - k) for k in range(cm.MIN_DRIFT_BINS - 1)], 100 * MS, 10**10)
    assert few == cm.MIN_DRIFT_BINS - 1
