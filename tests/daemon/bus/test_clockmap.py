"""The clock map's acceptance in simulation (docs/architecture.md, "Time").

Synthetic streams, no daemon: a device clock with an offset and 50 ppm of drift, stamped at the
tracker's resolution (1 µs), seen by the host after a latency of 0-5 ms (heavier on the receive
path than on the send path). Each sample's record times are mapped online, as they arrive, and
compared with the true host time at which the device stamped them.
"""
from __future__ import annotations

import random
from typing import Callable

import pytest

from daemon.bus.clockmap import ClockMap

HOST0 = 1_760_000_000_000_000_000
DEV0 = 123_456_789_000
Latency = Callable[[random.Random], float]


def rx_latency(r: random.Random) -> float:
    """Receive path: exponential, mean 1 ms, capped at 5 ms (s)."""
    return min(r.expovariate(1e3), 5e-3)


def uniform5(r: random.Random) -> float:
    return r.uniform(0.0, 5e-3)


def tx_latency(r: random.Random) -> float:
    """Send path of an exchange: lighter, 0-1 ms (s)."""
    return r.uniform(0.0, 1e-3)


class Run:
    """A simulated stream: packets at ``rate_hz`` of ``per_packet`` records each, the packet
    stamped with its last record's device time."""

    def __init__(self, rate_hz: float, per_packet: int = 1, drift_ppm: float = 50.0, seed: int = 0,
                 two_way: bool = False, **kw: float) -> None:
        self.rate_hz, self.per_packet, self.drift = rate_hz, per_packet, drift_ppm * 1e-6
        self.rng, self.two_way = random.Random(seed), two_way
        self.cm = ClockMap(resolution_ns=1000, **kw)
        self.errors: list[float] = []
        self.sigmas: list[int] = []

    def dev(self, t: float) -> int:
        return (DEV0 + round(t * 1e9 * (1 - self.drift))) // 1000 * 1000

    def run(self, t0: float, t1: float, latency: Latency = rx_latency) -> None:
        """Packets whose last record falls in [t0, t1) s, mapped as they arrive: each 0.1 s of
        packets (one at 10 Hz) right after it was added."""
        period, rec = 1.0 / self.rate_hz, 1.0 / (self.rate_hz * self.per_packet)
        i = int(round(t0 / period))
        batch: list[float] = []
        while (i + 1) * period < t1:
            t = (i + 1) * period
            rx = HOST0 + round((t + latency(self.rng)) * 1e9)
            tx = HOST0 + round((t - tx_latency(self.rng)) * 1e9) if self.two_way else None
            self.cm.add(self.dev(t), rx, tx)
            batch += [t - (self.per_packet - 1) * rec, t]  # the packet's first and last record
            i += 1
            if len(batch) >= 2 * max(1, round(self.rate_hz / 10)) or (i + 1) * period >= t1:
                for tr in batch:
                    m, s = self.cm.map(self.dev(tr))
                    self.errors.append(m - (HOST0 + tr * 1e9))
                    self.sigmas.append(s)
                batch = []

    def p(self, q: float) -> float:
        e = sorted(abs(x) for x in self.errors)
        return e[min(len(e) - 1, int(q * len(e)))]

    def coverage(self) -> float:
        return sum(abs(e) <= 3 * s for e, s in zip(self.errors, self.sigmas)) / len(self.errors)


@pytest.mark.parametrize("rate_hz, per_packet, latency", [
    (100.0, 10, rx_latency),  # the tracker: 1 kHz records in packets of 10
    (10.0, 1, rx_latency),    # a base's 10 Hz state
    (10.0, 1, uniform5),      # the same with latency spread evenly over 0-5 ms
])
def test_ten_minutes_within_half_a_millisecond_and_covered(rate_hz, per_packet, latency):
    r = Run(rate_hz, per_packet, seed=7)
    r.run(0.0, 600.0, latency)
    assert r.p(0.99) <= 0.5e6, r.p(0.99)
    assert r.coverage() >= 0.99, r.coverage()
    st = r.cm.status()
    assert abs(st["drift_ppm"] - 50.0) < 2.0, st
    assert st["window_s"] == pytest.approx(60.0, abs=0.2) and st["samples"] >= 599, st
    # the offset at the newest sample is the truth's (host - device there) within its sigma
    d = r.dev(600.0 - 1.0 / rate_hz)
    true_offset = HOST0 + (600.0 - 1.0 / rate_hz) * 1e9 - d
    assert abs(st["offset_ns"] - true_offset) <= 3 * st["sigma_ns"] + 1000, (st, true_offset)


def test_exchanges_bound_both_sides():
    r = Run(10.0, seed=3, two_way=True)
    r.run(0.0, 120.0)
    assert r.p(0.99) <= 0.5e6 and r.coverage() >= 0.99, (r.p(0.99), r.coverage())
    assert r.cm.status()["two_way"] is True


def test_latency_step_and_no_drift():
    r = Run(10.0, drift_ppm=0.0, seed=11)
    r.run(0.0, 90.0, lambda g: g.expovariate(1 / 0.2e-3))
    r.run(90.0, 240.0, lambda g: min(g.expovariate(1 / 2e-3), 5e-3))  # a busier host from here on
    assert r.p(0.99) <= 0.5e6 and r.coverage() >= 0.99, (r.p(0.99), r.coverage())
    assert abs(r.cm.status()["drift_ppm"]) < 2.0, r.cm.status()


def test_gap_longer_than_the_window():
    r = Run(10.0, seed=5)
    r.run(0.0, 60.0)
    n_before = len(r.errors)
    r.run(180.0, 240.0)  # 2 min without a sample: the window holds only what came after
    after = r.sigmas[n_before:]
    assert after[0] > 20 * r.sigmas[n_before - 1], (after[0], r.sigmas[n_before - 1])  # restarting: says so
    assert r.p(0.99) <= 0.5e6 and r.coverage() >= 0.99, (r.p(0.99), r.coverage())
    assert r.cm.status()["window_s"] < 60.0


def test_a_gap_within_the_window_extrapolates_with_growing_sigma():
    r = Run(10.0, seed=9)
    r.run(0.0, 60.0)
    s_now = r.cm.map(r.dev(60.0))[1]
    t, s_later = r.cm.map(r.dev(90.0))
    assert s_later > s_now
    assert abs(t - (HOST0 + 90.0 * 1e9)) <= 3 * s_later


@pytest.mark.parametrize("n", [1, 2, 3, 5, 10, 30])
def test_few_samples_say_so(n):
    """With few samples the sigma is large, shrinks as samples come, and covers the error."""
    worst = 0.0
    for seed in range(50):
        r = Run(10.0, seed=seed)
        r.run(0.0, (n + 0.5) / 10.0)
        assert len(r.errors) == 2 * n
        worst = max(worst, abs(r.errors[-1]) / r.sigmas[-1])
        if n == 1:
            assert r.sigmas[-1] >= 1e6, r.sigmas[-1]  # a single sample: latency unknown, ms
            assert r.cm.status()["drift_ppm"] is None
    assert worst <= 3.0, worst


def test_a_clock_set_ahead_starts_afresh_and_late_samples_do_not():
    cm = ClockMap()
    for i in range(50):  # 10 Hz, the 10th sample 3 s late (a stalled host): no reset
        cm.add(i * 10**8, HOST0 + i * 10**8 + (3 * 10**9 if i == 10 else 1000))
    assert cm.status()["resets"] == 0
    tai = 37 * 10**9 + 1_760_000_000 * 10**9  # the camera locks onto PTP time: its clock jumps ahead
    cm.add(tai, HOST0 + 50 * 10**8)
    st = cm.status()
    assert st["resets"] == 1 and st["samples"] == 1, st
    assert abs(st["offset_ns"] - (HOST0 + 50 * 10**8 - tai)) < 10**7, st


def test_clock_restart_and_bad_input():
    cm = ClockMap()
    with pytest.raises(ValueError, match="no samples"):
        cm.map(0)
    assert cm.status()["samples"] == 0
    cm.add(100_000_000_000, HOST0)
    cm.add(1_000_000, HOST0 + 10**9)  # the device clock went back by 100 s: it restarted
    st = cm.status()
    assert st["resets"] == 1 and st["samples"] == 1, st
    cm.add(2 * 10**9, HOST0 + 2 * 10**9)
    cm.add(0, HOST0 + 3 * 10**9)  # and again
    assert cm.status()["resets"] == 2
    with pytest.raises(ValueError, match="host_tx_ns 5 is after host_rx_ns 4"):
        cm.add(1, 4, 5)
    with pytest.raises(ValueError, match="window_s must be a positive number, got -1"):
        ClockMap(window_s=-1)
    with pytest.raises(ValueError, match="prior_drift_ppm must be a positive number, got nan"):
        ClockMap(prior_drift_ppm=float("nan"))
    with pytest.raises(ValueError, match=r"bin_s \(2\.0\) must be below window_s \(1\.0\)"):
        ClockMap(window_s=1.0, bin_s=2.0)
