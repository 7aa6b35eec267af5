"""Benchmark: emScon decode rate (pure codec) and records/s through the tracker adapter.

The streaming figure runs the fake tracker as a separate process (``--flood-batch``:
full MultiMeasResult packets back to back, no pacing) and counts the records the
``EmsconTracker`` adapter decodes and emits as ``tracker.point`` messages. The fake
shares the 2-core machine, so the client figure is a lower bound.

Run: ``.venv/bin/python bench/bench_tracker.py [--seconds 3]``
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.common import machine  # noqa: E402

from drivers.base import DeviceURL  # noqa: E402
from drivers.emscon.adapter import EmsconTracker  # noqa: E402
from drivers.emscon.codec import MEAS_VALUE, TO_CLIENT, encode_result  # noqa: E402
from drivers.emscon.framer import Framer  # noqa: E402
from fakes.world import World  # noqa: E402


def bench_codec(batch: int, seconds: float) -> tuple[float, float]:
    """Packets/s and records/s for framing + decoding MultiMeasResult packets of ``batch`` records."""
    rec = np.zeros(batch, MEAS_VALUE)
    rec["val1"] = np.arange(batch)
    raw = encode_result("multi", 0, rec) * 20
    f = Framer(TO_CLIENT)
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        n += len(f.feed(raw))
    dt = time.perf_counter() - t0
    return n / dt, n * batch / dt


def bench_single(seconds: float) -> float:
    raw = encode_result("single", 0, val1=1.0) * 100
    f = Framer(TO_CLIENT)
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        n += len(f.feed(raw))
    return n / (time.perf_counter() - t0)


def bench_stream(batch: int, seconds: float) -> tuple[float, float]:
    """Records/s and messages/s emitted by the adapter from a flooding fake process."""
    proc = subprocess.Popen([sys.executable, "-m", "fakes.tracker", "--port", "0", "--time-scale", "0.001",
                             "--flood-batch", str(batch)], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        port = int(proc.stdout.readline().split()[1])  # type: ignore[union-attr]
        counts = {"points": 0, "msgs": 0}

        def emit(topic: str, payload: object) -> None:
            if topic == "tracker.point":
                counts["points"] += payload["n"]  # type: ignore[index]
                counts["msgs"] += 1

        t = EmsconTracker(DeviceURL.parse(f"emscon://127.0.0.1:{port}?timeout=10"), emit=emit)
        t.open()
        truth = World().reflectors_trk()["robot"]  # same default world as the fake process
        t.aim(tuple(truth))
        t.start_stream(1000.0)
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            t.pump(0.05)
        dt = time.perf_counter() - t0
        t.close()
        return counts["points"] / dt, counts["msgs"] / dt
    finally:
        proc.kill()
        proc.wait(5)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0)
    a = ap.parse_args()
    rows = []
    for batch in (1, 100, 1000):
        pps, rps = bench_codec(batch, a.seconds / 3)
        rows.append((f"codec: frame+decode MultiMeasResult, {batch} rec/packet", f"{pps:,.0f} packets/s",
                     f"{rps:,.0f} records/s"))
    rows.append(("codec: frame+decode SingleMeasResult", f"{bench_single(a.seconds / 3):,.0f} packets/s", ""))
    for batch in (100, 1000):
        rps, mps = bench_stream(batch, a.seconds)
        rows.append((f"adapter <- fake process over TCP, {batch} rec/packet", f"{mps:,.0f} messages/s",
                     f"{rps:,.0f} records/s"))
    print("| measurement | packets or messages | records |")
    print("|---|---:|---:|")
    for r in rows:
        print(f"| {r[0]} | {r[1]} | {r[2]} |")
    print()
    print(machine())


if __name__ == "__main__":
    main()
