"""STOP → halt latency, with and without a link fault: the figures the fault tests leave to a benchmark.

Run: ``.venv/bin/python bench/bench_stop.py [--rounds N]``. Prints a Markdown table and the machine facts.
The rig is the fault tests' (tools/harness/stop_rig.py): the fake base at real-time speed on its own pty
in this process, a cable that can be cut, ritad as a process on it. Times are on this process's monotonic
clock, which is also the fake base's: a halt is the tick that ended the motion (the base ticks every 5 ms
while moving, so a figure may be up to 5 ms late).

Rows:
- no fault: ``robot.stop`` sent by a client → the base's wheels stopped (includes the client's send and
  ritad's command thread; the daemon-side goal is ≤ 50 ms);
- link cut, STOP, link restored 1 s later (a version-2 base, so that only the latch path halts it):
  restore → halted, and the travel after the restore;
- link cut (version-3 base): cut → the base halted itself (host timeout 0.3 s);
- ritad SIGKILLed mid-move (version-3 base): kill → the base halted itself;
- ritad SIGTERMed mid-move (version-2 base): SIGTERM → halted by ritad's STOP, before it exits;
- during the commissioning kit's MOVE (``robot.commission allow_motion``, the kit on ritad's owner thread
  with its own line to the base): ``robot.stop`` sent by a client → wheels stopped by the kit's STOP.

``--cases`` runs some rows only (their numbers, from 1, in the order above).
"""
from __future__ import annotations

import argparse
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Callable

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import machine, pct  # noqa: E402
from tools.harness.stop_rig import StopRig, wait_for  # noqa: E402

Round = Callable[[StopRig], tuple[float, float]]  # one measurement: (seconds, mm after the instant)


def _halt_after(rig: StopRig, t0: float, x0: float) -> tuple[float, float]:
    x_end = rig.halted()
    return rig.base.last_halt - t0, x_end - x0


def no_fault(rig: StopRig) -> tuple[float, float]:
    with rig.client() as c:
        c.call("robot.release")
        rig.move(c)
        t0, x0 = time.monotonic(), rig.x()
        c.call("robot.stop", timeout=10)
        return _halt_after(rig, t0, x0)


def link_cut_then_restored(rig: StopRig) -> tuple[float, float]:
    with rig.client() as c:
        c.call("robot.release")
        rig.move(c)
        rig.proxy.cut()
        c.call("robot.stop", timeout=10)
    time.sleep(1.0)  # the outage
    t0, x0 = time.monotonic(), rig.x()
    rig.proxy.restore()
    return _halt_after(rig, t0, x0)


def link_cut_watchdog(rig: StopRig) -> tuple[float, float]:
    with rig.client() as c:
        c.call("robot.stop")  # a FAULT HOST_LOST of the round before is cleared by a STOP
        c.call("robot.release")
        rig.move(c)
        t0, x0 = time.monotonic(), rig.x()
        rig.proxy.cut()
        got = _halt_after(rig, t0, x0)
    rig.proxy.restore()
    return got


def killed(sig: signal.Signals) -> Round:
    def one(rig: StopRig) -> tuple[float, float]:
        if rig.ritad is None or rig.ritad.proc.poll() is not None:
            rig.start()
        with rig.client() as c:
            c.call("robot.stop")
            c.call("robot.release")
            rig.move(c)
        assert rig.ritad is not None
        t0, x0 = time.monotonic(), rig.x()
        rig.ritad.proc.send_signal(sig)
        got = _halt_after(rig, t0, x0)
        rig.ritad.proc.wait(timeout=30)
        return got
    return one


def during_kit(rig: StopRig) -> tuple[float, float]:
    """robot.stop while the commissioning kit's MOVE runs; the kit's reply must name the stop."""
    out: dict[str, Any] = {}

    def commission() -> None:
        assert rig.ritad is not None
        with rig.ritad.client(timeout=120) as k:
            out["reply"] = k.call("robot.commission", allow_motion=True, clock_s=0.5, confirm=True)

    with rig.client() as c:
        c.call("robot.release")
        kit = threading.Thread(target=commission, daemon=True)
        kit.start()
        wait_for(rig.moving, 60, "the kit's MOVE under way")
        t0, x0 = time.monotonic(), rig.x()
        c.call("robot.stop", timeout=10)
        got = _halt_after(rig, t0, x0)
        kit.join(timeout=60)
    assert "STOP during the kit" in str(out.get("reply")), out
    return got


def run(name: str, protocol: int, fn: Round, rounds: int) -> str:
    with tempfile.TemporaryDirectory(prefix="bench-stop-") as tmp:
        rig = StopRig(Path(tmp), protocol)
        try:
            rig.start()
            got = [fn(rig) for _ in range(rounds)]
        finally:
            rig.close()
    ms = [g[0] * 1e3 for g in got]
    mm = [g[1] for g in got]
    return (f"| {name} | {protocol} | {rounds} | {pct(ms, 50):.1f} / {max(ms):.1f} | "
            f"{pct(mm, 50):.1f} / {max(mm):.1f} |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=10)
    ap.add_argument("--cases", default="", help="comma list of row numbers to run (default: all)")
    args = ap.parse_args()
    n = args.rounds
    cases: list[tuple[str, int, Round, int]] = [
        ("no fault: robot.stop → halted", 3, no_fault, n),
        ("link cut, STOP, restored 1 s later: restore → halted", 2, link_cut_then_restored, max(3, n // 2)),
        ("link cut: cut → the base halted itself", 3, link_cut_watchdog, max(3, n // 2)),
        ("ritad SIGKILL mid-move: kill → the base halted itself", 3, killed(signal.SIGKILL), 3),
        ("ritad SIGTERM mid-move: SIGTERM → halted by ritad", 2, killed(signal.SIGTERM), 3),
        ("commissioning kit's MOVE: robot.stop → halted by the kit's STOP", 3, during_kit, max(3, n // 2))]
    wanted = {int(x) for x in args.cases.split(",") if x} or set(range(1, len(cases) + 1))
    rows = [run(*case) for i, case in enumerate(cases, 1) if i in wanted]
    print(machine())
    print("| case (100 mm/s) | base protocol | rounds | ms p50 / max | mm driven after p50 / max |")
    print("|---|---:|---:|---:|---:|")
    print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
