"""`ritactl status` on the laptop: wall time of the whole process against a local ritad.

The goal is an answer within 0.3 s of starting the process: interpreter, imports (the bus
client only: no numpy, no OpenCV) and one round trip. Prints the import time of
``daemon.ctl.main`` alone too, so a regression shows where it is.
"""
from __future__ import annotations

import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import machine, pct, start_ritad  # noqa: E402


def timed(argv: list[str], n: int) -> list[float]:
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        subprocess.run(argv, capture_output=True, check=True, timeout=60)
        out.append(time.perf_counter() - t0)
    return out


def main(n: int = 15) -> None:
    print(f"# bench_ctl_start\n\nMachine: {machine()}\n")
    with tempfile.TemporaryDirectory() as tmp, start_ritad(tmp=Path(tmp)) as r:
        r.wait_ready(timeout=90)
        py = sys.executable
        bare = timed([py, "-c", "pass"], n)
        imports = timed([py, "-c", "import daemon.ctl.main"], n)
        status = timed([py, "-m", "daemon.ctl.main", "--endpoint", r.endpoint, "status"], n)
    print("| what | median | p95 | goal |\n|---|---|---|---|")
    for label, t, goal in (("python -c pass", bare, ""), ("import daemon.ctl.main", imports, ""),
                           ("ritactl status (whole process)", status, "≤ 0.3 s")):
        met = "" if not goal else (" **met**" if statistics.median(t) <= 0.3 else " **missed**")
        print(f"| {label}, n={n} | {statistics.median(t):.3f} s | {pct(t, 95):.3f} s | {goal}{met} |")


if __name__ == "__main__":
    main()
