"""Run a command beside N busy processes: the suite on a machine that others are using (issue 34).

    python tools/under_load.py [--spinners N] [--nice K] -- COMMAND [ARGS...]

N (default 2 × the machine's cores) pure CPU spinners run at the same priority as the command (``--nice``
lowers theirs) for as long as the command runs; the exit status is the command's. The spinners stop by
themselves: when the command ends, when this script is killed (even with SIGKILL: each spinner watches its
parent and, on Linux, asks the kernel for SIGTERM when its parent dies), and after ``--max-s`` seconds
whatever happens. ``make test-under-load`` runs ``make test`` this way (tests/README.md).
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time

SPIN = r"""
import ctypes, os, signal, sys, time
parent, end = int(sys.argv[1]), time.monotonic() + float(sys.argv[2])
try:  # Linux: SIGTERM to this spinner the moment its parent dies
    ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
except (OSError, AttributeError):
    pass
x = 1
while os.getppid() == parent and time.monotonic() < end:  # the parent gone or the time up: stop
    for _ in range(200_000):
        x = (x * 48271) % 2147483647
"""


def start_spinners(n: int, max_s: float, nice: int) -> list[subprocess.Popen[bytes]]:
    def lower() -> None:
        if nice:
            os.nice(nice)

    return [subprocess.Popen([sys.executable, "-c", SPIN, str(os.getpid()), str(max_s)], preexec_fn=lower,
                             stdin=subprocess.DEVNULL) for _ in range(n)]


def stop_spinners(spinners: list[subprocess.Popen[bytes]]) -> None:
    for p in spinners:
        if p.poll() is None:
            p.terminate()
    for p in spinners:
        try:
            p.wait(5)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(5)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spinners", type=int, default=2 * (os.cpu_count() or 1), 
                    help="busy processes (2 × cores)")
    ap.add_argument("--nice", type=int, default=0, help="niceness added to the spinners (0: the command's)")
    ap.add_argument("--max-s", type=float, default=3600.0, 
                    help="the spinners stop after this long regardless")
    ap.add_argument("command", nargs=argparse.REMAINDER, help="-- then the command to run")
    a = ap.parse_args(argv)
    cmd = a.command[1:] if a.command[:1] == ["--"] else a.command
    if not cmd or a.spinners < 0:
        ap.error("give a command after --, and --spinners ≥ 0")
    spinners = start_spinners(a.spinners, a.max_s, a.nice)
    print(f"under_load: {a.spinners} CPU spinners on {os.cpu_count()} cores beside: {' '.join(cmd)}",
          file=sys.stderr, flush=True)
    t0 = time.monotonic()
    child = subprocess.Popen(cmd)

    def forward(signum: int, _frame: object) -> None:
        child.send_signal(signum)  # the command ends as it would alone; the finally stops the spinners

    signal.signal(signal.SIGTERM, forward)
    signal.signal(signal.SIGINT, forward)
    try:
        rc = child.wait()
    finally:
        stop_spinners(spinners)
    print(f"under_load: exit {rc} after {time.monotonic() - t0:.0f} s with {a.spinners} spinners",
          file=sys.stderr, flush=True)
    return rc


if __name__ == "__main__":
    sys.exit(main())
