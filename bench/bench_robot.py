"""Robot base benchmarks: codec speed and driver round trips to the fake base on a pty.

Run: ``.venv/bin/python bench/bench_robot.py [--n N]``. Prints a Markdown table and
the machine facts. Everything runs in this process: the fake base serves a pty from
a background thread, so the round trips include two thread hand-overs and the pty.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import machine, pct  # noqa: E402
from drivers import robot_protocol as rp  # noqa: E402
from drivers.base import DeviceLost  # noqa: E402
from fakes.robot import SimRobot  # noqa: E402
from fakes.world import World, WorldParams  # noqa: E402
from fakes.worlds import sim_url  # noqa: E402
from tools.harness.robot import wait_idle  # noqa: E402


def _robot(query: str) -> SimRobot:
    world = World(WorldParams(start_pose=(3000.0, 3000.0, 0.0)))
    robot = SimRobot(sim_url(world, f"state_hz=0&{query}"))
    return robot


def _ms(values: list[float]) -> str:
    return f"{pct(values, 50) * 1e3:.3f} / {pct(values, 95) * 1e3:.3f} / {pct(values, 99) * 1e3:.3f}"


def bench_codec(n: int) -> list[tuple[str, str]]:
    line = rp.encode("STATUS", 42, "MOVING", 1234.5678, -98.7654, 123.456789, None, None, 25.1, "")
    t = time.perf_counter()
    for _ in range(n):
        rp.encode("STATUS", 42, "MOVING", 1234.5678, -98.7654, 123.456789, None, None, 25.1, "")
    t_enc = (time.perf_counter() - t) / n
    t = time.perf_counter()
    for _ in range(n):
        rp.decode(line)
    t_dec = (time.perf_counter() - t) / n
    return [("codec: encode a STATUS line", f"{t_enc * 1e6:.1f} µs"),
            ("codec: decode a STATUS line", f"{t_dec * 1e6:.1f} µs")]


def bench_round_trips(n: int) -> list[tuple[str, str]]:
    robot = _robot("time_scale=0")
    rows = []
    try:
        t = time.perf_counter()
        robot.open()
        rows.append(("open (pty + HELLO + STATUS), first", f"{(time.perf_counter() - t) * 1e3:.2f} ms"))
        status, ack, whole = [], [], []
        for _ in range(n):
            t = time.perf_counter()
            robot.status()
            status.append(time.perf_counter() - t)
        for _ in range(n // 4):
            t = time.perf_counter()
            robot.move(1.0, 100.0)
            ack.append(time.perf_counter() - t)
            wait_idle(robot, 5.0)
            whole.append(time.perf_counter() - t)
        rows += [(f"STATUS round trip, p50/p95/p99 (n={n})", _ms(status) + " ms"),
                 (f"MOVE → ACK, p50/p95/p99 (n={n // 4})", _ms(ack) + " ms"),
                 (f"MOVE → idle confirmed, time_scale 0, p50/p95/p99 (n={n // 4})", _ms(whole) + " ms")]
        lost, reopen = [], []
        for _ in range(10):
            robot.drop_port()
            t = time.perf_counter()
            try:
                robot.status()
            except DeviceLost:
                lost.append(time.perf_counter() - t)
            robot.close()
            t = time.perf_counter()
            robot.open()
            reopen.append(time.perf_counter() - t)
        rows += [(f"port vanished → DeviceLost, p50/p95 (n={len(lost)})",
                  f"{pct(lost, 50) * 1e3:.3f} / {pct(lost, 95) * 1e3:.3f} ms"),
                 ("reopen on a new pty, p50/p95 (n=10)",
                  f"{pct(reopen, 50) * 1e3:.2f} / {pct(reopen, 95) * 1e3:.2f} ms")]
    finally:
        robot.shutdown()
    return rows


def bench_noisy_line(n: int) -> list[tuple[str, str]]:
    robot = _robot("time_scale=0&garbage_rate=0.3&corrupt_rate=0.1&timeout=0.05&retries=10")
    try:
        robot.open()
        times = []
        for _ in range(n):
            t = time.perf_counter()
            robot.status()
            times.append(time.perf_counter() - t)
        c = robot.info()["counters"]
    finally:
        robot.shutdown()
    return [(f"STATUS on a noisy line (30 % garbage bursts, 10 % corrupted, timeout 50 ms), "
             f"p50/p95/p99 (n={n})", _ms(times) + " ms"),
            ("  … counted: garbage / bad checksum / retries / stale",
             f"{c['garbage']} / {c['bad_checksum']} / {c['retries']} / {c['stale']}")]


def bench_silent_base(n: int) -> list[tuple[str, str]]:
    """A base that stops answering: STATUS → DeviceLost with timeout 0.1 s and one retry (two tries: 0.2 s
    at least). tests/drivers/test_robot_driver.py asserts the two tries ended it; how soon: here."""
    robot = _robot("time_scale=0&timeout=0.1&retries=1")
    times = []
    try:
        robot.open()
        robot.set_line_faults(silent=True)
        for _ in range(n):
            t = time.perf_counter()
            try:
                robot.status()
            except DeviceLost:
                times.append(time.perf_counter() - t)
    finally:
        robot.shutdown()
    return [(f"silent base: STATUS → DeviceLost (timeout 0.1 s, 1 retry), p50/p95/p99/max "
             f"(n={n}, all lost: {len(times) == n})", _ms(times) + f" / {max(times) * 1e3:.1f} ms")]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=2000, help="round trips per measurement")
    args = ap.parse_args()
    rows = (bench_codec(20000) + bench_round_trips(args.n) + bench_noisy_line(args.n // 4)
            + bench_silent_base(max(5, args.n // 100)))
    print("| robot benchmark | result |")
    print("|---|---|")
    for name, value in rows:
        print(f"| {name} | {value} |")
    print(f"\nMachine: {machine()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
