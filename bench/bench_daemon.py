"""Daemon basics: start-up time to READY=1 (simulated world) and command round-trip latency.

Goals: READY ≤ 3 s; `ping` round trip p99 ≤ 5 ms on loopback. Also SIGTERM → exit with its devices READY
(tests/daemon/ritad/test_ritad_process.py asserts the clean exit and STOPPING=1; how soon is measured here).
"""
from __future__ import annotations

import signal
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import machine, pct, ritad_toml, start_ritad  # noqa: E402
from daemon.bus.client import Client  # noqa: E402

TCP_CONFIG = ritad_toml(ipc_dir=None, tcp=True, insecure_tcp=True)  # loopback only: the plain bus


def round_trips(endpoint: str, n: int = 3000, cmd: str = "ping") -> list[float]:
    out = []
    with Client(endpoint, timeout=5) as c:
        for _ in range(200):
            c.call(cmd)  # warm up
        for _ in range(n):
            t = time.perf_counter()
            c.call(cmd)
            out.append((time.perf_counter() - t) * 1e3)
    return out


def main() -> None:
    print(f"# bench_daemon\n\nMachine: {machine()}\n")
    readies = []
    for _ in range(3):
        r = start_ritad()
        ep, ready = r.endpoint, r.ready_s
        readies.append(ready)
        r.stop()
    print("| metric | value | goal |\n|---|---|---|")
    print(f"| start → READY=1, `ritad --sim` (median of 3; min–max) | {sorted(readies)[1]:.2f} s "
          f"({min(readies):.2f}–{max(readies):.2f}) | ≤ 3 s |")
    exits = []
    for _ in range(3):
        r = start_ritad()
        try:
            r.wait_ready(timeout=90)
            t = time.perf_counter()
            r.proc.send_signal(signal.SIGTERM)
            code = r.proc.wait(60)
            exits.append(time.perf_counter() - t)
            assert code == 0, code
        finally:
            r.stop()
    print(f"| SIGTERM → exit 0, devices READY, `ritad --sim` (median of 3; min–max) | "
          f"{sorted(exits)[1]:.2f} s "
          f"({min(exits):.2f}–{max(exits):.2f}) | ≤ 5 s |")
    r = start_ritad()
    ep = r.endpoint
    try:
        time.sleep(3)  # let the sim devices connect so the daemon is in its steady state
        for cmd in ("ping", "status"):
            rt = round_trips(ep, cmd=cmd)
            print(f"| `{cmd}` round trip, ipc, n={len(rt)} "
                  f"| p50 {pct(rt, 50):.3f} ms, p99 {pct(rt, 99):.3f} ms "
                  f"| p99 ≤ 5 ms |")
    finally:
        r.stop()
    r = start_ritad(TCP_CONFIG)
    ep = r.endpoint
    try:
        time.sleep(3)
        rt = round_trips(ep)
        print(f"| `ping` round trip, tcp 127.0.0.1, n={len(rt)} | p50 {pct(rt, 50):.3f} ms, "
              f"p99 {pct(rt, 99):.3f} ms | p99 ≤ 5 ms |")
    finally:
        r.stop()


if __name__ == "__main__":
    main()
