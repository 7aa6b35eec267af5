"""ritad --sim's own CPU (its process only: the calibration worker is a child of its own) with the
simulated devices idle and with the base driving, and the round trip of ``robot.status``.

Run: ``.venv/bin/python bench/bench_sim_cpu.py [--seconds 20]``. At the simulator's 50x speed the
base streams STATE at 50 Hz and INCL at 500 lines/s of wall time into ritad (docs/robot-protocol.md),
which every test that runs a simulated ritad pays. "Driving": 1000 mm moves at 100 mm/s back and
forth (0.2 s of wall time each), so the base is in motion nearly all the time whatever the command
latency.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import cpu_seconds, machine, pct  # noqa: E402
from fakes.launch import start_ritad  # noqa: E402


def cpu_over(pid: int, seconds: float) -> float:
    """Fraction of one core the process used over ``seconds``."""
    c0, t0 = cpu_seconds(pid), time.monotonic()
    time.sleep(seconds)
    return (cpu_seconds(pid) - c0) / (time.monotonic() - t0)


def measure(seconds: float, n_status: int) -> dict[str, float]:
    tmp = Path(tempfile.mkdtemp(prefix="bench-sim-cpu-"))
    with start_ritad(tmp=tmp, args=["--seed", "1"], timeout=90) as r:
        r.wait_ready(("camera", "tracker", "robot"), timeout=120)
        with r.client(timeout=60) as c:
            time.sleep(2.0)  # the devices' start-up is not the idle figure
            out = {"idle": cpu_over(r.proc.pid, seconds)}
            lat = []
            for _ in range(n_status):
                t0 = time.perf_counter()
                c.call("robot.status")
                lat.append(time.perf_counter() - t0)
            out.update(status_p50=pct(lat, 50), status_p95=pct(lat, 95))
            stop, moves = threading.Event(), [0]

            def drive() -> None:
                with r.client(timeout=60) as d:
                    while not stop.is_set():
                        d.call("robot.move", distance_mm=1000.0 if moves[0] % 2 == 0 else -1000.0,
                               speed_mm_s=100.0, confirm=True, timeout=60)
                        moves[0] += 1

            th = threading.Thread(target=drive, daemon=True)
            th.start()
            time.sleep(1.0)
            out["moving"] = cpu_over(r.proc.pid, seconds)
            stop.set()
            th.join(30)
            out["moves"] = moves[0]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--status", type=int, default=200, help="robot.status round trips timed")
    a = ap.parse_args()
    m = measure(a.seconds, a.status)
    print(machine())
    print("\n| ritad --sim | figure |\n|---|---|")
    print(f"| CPU, devices idle ({a.seconds:g} s) | {m['idle'] * 100:.1f} % of a core |")
    print(f"| CPU, base driving ({a.seconds:g} s, {int(m['moves'])} moves) "
          f"| {m['moving'] * 100:.1f} % of a core |")
    print(f"| `robot.status` round trip p50 / p95 (n={a.status}) | {m['status_p50'] * 1e3:.2f} / "
          f"{m['status_p95'] * 1e3:.2f} ms |")


if __name__ == "__main__":
    main()
