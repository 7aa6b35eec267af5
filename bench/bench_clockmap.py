"""CPU of the clock map (daemon/bus/clockmap.py) per 120 simulated seconds of one device clock, fed the
way ritad's device clock feeds it: each packet added as it arrives, then its records mapped.

Run: ``.venv/bin/python bench/bench_clockmap.py [--seconds 120] [--repeat 3]``. Streams: the tracker
(100 Hz packets of 10 records at 1 kHz), the base (10 Hz, one record a packet) and a two-way exchange
at 10 Hz; a device clock 50 ppm fast, the receive latency exponential (mean 1 ms, capped at 5 ms) as in
tests/daemon/bus/test_clockmap.py. The figure is the process CPU (``time.process_time``) of the best
of ``--repeat`` runs: the machine is shared, the best run is the one least disturbed.
"""
from __future__ import annotations

import argparse
import os
import random
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import machine  # noqa: E402
from daemon.bus.clockmap import ClockMap  # noqa: E402

HOST0 = 1_760_000_000_000_000_000
DEV0 = 123_456_789_000
DRIFT = 50e-6


def dev(t: float) -> int:
    """The device's stamp of true time ``t`` s, at 1 µs resolution."""
    return (DEV0 + round(t * 1e9 * (1 - DRIFT))) // 1000 * 1000


def stream(seconds: float, rate_hz: float, per_packet: int, two_way: bool, seed: int) -> float:
    """CPU seconds to add and map ``seconds`` of one stream."""
    rng, cm = random.Random(seed), ClockMap(resolution_ns=1000)
    period, rec = 1.0 / rate_hz, 1.0 / (rate_hz * per_packet)
    c0 = time.process_time()
    for i in range(1, int(seconds * rate_hz)):
        t = i * period
        rx = HOST0 + round((t + min(rng.expovariate(1e3), 5e-3)) * 1e9)
        tx = HOST0 + round((t - rng.uniform(0.0, 1e-3)) * 1e9) if two_way else None
        cm.add(dev(t), rx, tx)
        cm.map_many([dev(t - j * rec) for j in range(per_packet)])
    return time.process_time() - c0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=120.0)
    ap.add_argument("--repeat", type=int, default=3)
    a = ap.parse_args()
    rows = [("tracker, 100 Hz packets of 10 records", 100.0, 10, False),
            ("base, 10 Hz", 10.0, 1, False), ("two-way exchanges, 10 Hz", 10.0, 1, True)]
    print(machine(), f"load {os.getloadavg()[0]:.1f}")
    print(f"\n| clock map, {a.seconds:g} simulated s | CPU (best of {a.repeat}) |\n|---|---|")
    for name, rate, per, two_way in rows:
        cpu = min(stream(a.seconds, rate, per, two_way, seed) for seed in range(a.repeat))
        print(f"| {name} | {cpu:.3f} s |")


if __name__ == "__main__":
    main()
