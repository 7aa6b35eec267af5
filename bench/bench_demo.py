"""Wall time of `make demo`'s main job and of each of its phases and procedure steps.

Method: runs ``python -m fakes.demo`` (what ``make demo`` runs once the venv exists)
unbuffered and timestamps every output line as it arrives. Phases are the demo's
``== ...`` headings; procedure steps are the ``[ xx.x%] step`` lines ritactl prints
from the worker's ``calib.progress`` telemetry, each lasting until the next line of
progress or the result. Repeated steps (``direction 3/8, repetition 2/5``) are grouped
with their numbers taken out. The README promises "about 1–2 minutes".

Run: ``.venv/bin/python bench/bench_demo.py`` (writes ``demo-out/`` like ``make demo``).
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import ROOT, machine  # noqa: E402

STEP = re.compile(r"^\[\s*([\d.]+)%\]\s+(.*?)(?:\s+—\s+waiting for .*)?$")


def run_demo(timeout: float) -> tuple[list[tuple[float, str]], int, float]:
    """Run the demo; return its (seconds since start, line) pairs, exit code and wall time."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "PYTHONPATH": str(ROOT)}
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "fakes.demo"], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    lines: list[tuple[float, str]] = []
    assert proc.stdout is not None
    for line in proc.stdout:
        lines.append((time.monotonic() - t0, line.rstrip("\n")))
        if time.monotonic() - t0 > timeout:
            proc.kill()
            raise RuntimeError(f"demo still running after {timeout:.0f} s")
    rc = proc.wait(30)
    return lines, rc, time.monotonic() - t0


def phases(lines: list[tuple[float, str]], wall: float) -> list[tuple[str, float]]:
    """(heading, seconds) for every ``== heading`` up to the next heading or the end."""
    heads = [(t, s[3:]) for t, s in lines if s.startswith("== ")]
    ends = [t for t, _ in heads[1:]] + [wall]
    return [(name, end - t) for (t, name), end in zip(heads, ends)]


def steps(lines: list[tuple[float, str]]) -> dict[str, list[float]]:
    """Procedure step durations grouped by name with digits replaced by ``N``."""
    out: dict[str, list[float]] = {}
    open_step: tuple[float, str] | None = None
    for t, s in lines:
        m = STEP.match(s.strip())
        is_end = s.startswith(("result:", "FAILED", "== ", "$ ritactl"))
        if open_step is not None and (m or is_end):
            out.setdefault(open_step[1], []).append(t - open_step[0])
            open_step = None
        if m:
            open_step = (t, re.sub(r"\d+", "N", m.group(2)))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--timeout", type=float, default=1200.0)
    ap.add_argument("--log", type=Path, help="also write the timestamped demo output here")
    a = ap.parse_args()
    lines, rc, wall = run_demo(a.timeout)
    if a.log:
        a.log.write_text("".join(f"{t:8.2f}  {s}\n" for t, s in lines))
    print(f"# bench_demo\n\nMachine: {machine()}\n")
    print("| phase / step | wall time | goal | met |\n|---|---|---|---|")
    ok = rc == 0 and wall <= 120
    print(f"| **`python -m fakes.demo` in total** (exit code {rc}) | {wall:.1f} s | about 1–2 min "
          f"(README) | {'yes' if ok else 'NO'} |")
    for name, dt in phases(lines, wall):
        print(f"| phase: {name} | {dt:.1f} s | – | – |")
    for name, ds in steps(lines).items():
        label = f"{len(ds)}×, mean {sum(ds) / len(ds):.2f} s, max {max(ds):.2f} s" if len(ds) > 1 else ""
        print(f"| step: {name} | {sum(ds):.1f} s {('(' + label + ')') if label else ''} | – | – |")
    if rc:
        print("\nThe demo failed; its last lines:\n\n```\n" + "\n".join(s for _, s in lines[-15:]) + "\n```")


if __name__ == "__main__":
    main()
