"""ritad's journal in a busy session: INFO lines per minute with a console page open, a 5 fps live
view and an experiment running.

Goal (≤ 60 INFO lines per minute, i.e. ≤ 1 per second on average): the journal keeps what an
operator or an audit needs (motions with their key, jobs, changes, refusals) and leaves the
polling to DEBUG.

Method: ``ritad`` on the simulated devices with the calibration worker, the robot base in real
time (``sim:?time_scale=1``: a 200 mm drive takes 2 s, as on the floor; ``--time-scale 0.02`` is
the simulator's default 50× speed, a stress case) and INFO logging to a file. Setup (not
measured): the tracker locks on, the guided intrinsics install a camera model (the simulated
operator holds the board), a referencing on the plate's design file installs a calibration.
Measured: the camera streams at 5 fps; a bus client does what one open console page makes the
console send (daemon/console/bridge.py, static/console.js, procedures.js): ``hello``, the role
probe and ``state`` once, then every second ``tracker.status``, ``camera.status`` and
``calib.jobs``, and ``camera.preview`` for a 5 fps live view (asking again after 50 ms while the
newest frame is the one shown, as the console does); an 8-direction experiment runs. The INFO
(and WARNING+) lines ritad writes during ``--seconds`` are counted, with the commands behind
them. Run: ``.venv/bin/python bench/bench_journal.py [--seconds 60] [--time-scale 1]``.
"""
from __future__ import annotations

import argparse
import collections
import json
import re
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import machine, ritad_toml, start_ritad  # noqa: E402
from daemon.bus.client import Client  # noqa: E402
from daemon.bus.protocol import CommandError  # noqa: E402
from fakes.board import run_intrinsics  # noqa: E402
from fakes.operator import lock_on_robot, rough_mark  # noqa: E402

LINE = re.compile(r"^\S+ \S+ (DEBUG|INFO|WARNING|ERROR|CRITICAL) (\S+): (.*)$")


def wait_job(c: Client, job: str, timeout: float) -> dict[str, Any]:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        j = {j["job"]: j for j in c.call("calib.jobs")["jobs"]}[job]
        if j["state"] in ("done", "failed", "cancelled"):
            return j
        time.sleep(0.5)
    raise RuntimeError(f"job {job} not finished in {timeout} s")


def setup(c: Client, data: Path) -> list[float]:
    """A locked tracker, a camera model and a calibration; returns the mark's rough position."""
    p = lock_on_robot(c)
    sim = data / "sim"  # the simulated world's installer put the operator's files here
    intr = run_intrinsics(c, {"board": json.loads((sim / "board.json").read_text())}, seed=1)
    if intr.get("failed"):
        raise RuntimeError(f"intrinsics failed: {intr.get('message')}")
    params = {"plate": json.loads((sim / "plate.json").read_text()),
              "nests_approx_trk": json.loads((sim / "nests.json").read_text()),
              "robot_approx_trk": [p["x"], p["y"], p["z"]]}
    ref = wait_job(c, c.call("calib.start", procedure="referencing", params=params)["job"], 600)
    if ref["state"] != "done":
        raise RuntimeError(f"referencing {ref['state']}: {ref.get('error')}")
    return rough_mark(c, 0)[1]


class Page:
    """The bus traffic of one open console page with a 5 fps live view, in two threads."""

    def __init__(self, endpoint: str, fps: float = 5.0) -> None:
        self.endpoint, self.fps = endpoint, fps
        self.stop = threading.Event()
        self.calls = collections.Counter[str]()
        self.threads = [threading.Thread(target=self._slow, daemon=True), threading.Thread(target=self._view,
                                                                                           daemon=True)]

    def _call(self, c: Client, cmd: str, args: dict[str, Any] | None = None) -> Any:
        self.calls[cmd] += 1
        try:
            return c.call_raw(cmd, args or {}, timeout=30)[0]
        except CommandError:
            return None

    def _slow(self) -> None:
        with Client(self.endpoint, timeout=30) as c:
            for cmd, args in (("hello", {}), ("calib.answer", {}), ("state", {}), ("data.dir", {})):
                self._call(c, cmd, args)
            while not self.stop.wait(1.0):
                for cmd in ("tracker.status", "camera.status", "calib.jobs"):
                    self._call(c, cmd)

    def _view(self) -> None:
        after, sent = -1, 0.0
        with Client(self.endpoint, timeout=30) as c:
            while not self.stop.is_set():
                time.sleep(max(0.0, sent + 0.9 / self.fps - time.monotonic()))
                meta = self._call(c, "camera.preview", {"width": 1000, "after": after})
                if meta is None:
                    self.stop.wait(0.5)
                elif meta.get("unchanged"):
                    self.stop.wait(0.05)
                else:
                    after, sent = meta["header"]["frame_id"], time.monotonic()

    def __enter__(self) -> "Page":
        for t in self.threads:
            t.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        for t in self.threads:
            t.join(35)


def count_lines(text: str) -> tuple[collections.Counter[str], collections.Counter[str]]:
    """(lines per level, INFO+ lines per source: the command or the message's first words)."""
    levels, sources = collections.Counter[str](), collections.Counter[str]()
    for line in text.splitlines():
        m = LINE.match(line)
        if not m:
            continue
        levels[m.group(1)] += 1
        if m.group(1) != "DEBUG":
            words = m.group(3).split()
            sources[" ".join(words[:2]) if words[0] in ("motion", "command") else " ".join(words[:3])] += 1
    return levels, sources


def measure(seconds: float, scale: float) -> dict[str, Any]:
    tmp = Path(tempfile.mkdtemp(prefix="bench-journal-"))
    # DEBUG: every line, so the DEBUG ones can be counted too; INFO+ is what the default writes
    config = ritad_toml(worker=True, log_level="DEBUG",
                        devices={"camera": "sim:?fps=5", "robot": f"sim:?time_scale={scale:g}"})
    r = start_ritad(config, tmp=tmp)
    try:
        r.wait_ready(timeout=120, worker=True)
        with r.client(timeout=60) as c:
            mark = setup(c, tmp / "data")
            c.call("camera.stream.start")
            with Page(r.endpoint) as page:
                job = c.call("calib.start", procedure="experiment",
                             params={"mark_xy": mark, "directions": 8, "repetitions": 20})["job"]
                time.sleep(3.0)  # the job under way and the page's first calls made
                start, t0 = r.log.stat().st_size, time.monotonic()
                page.calls.clear()
                time.sleep(seconds)
                text = r.log.read_bytes()[start:].decode(errors="replace")
                elapsed = time.monotonic() - t0
                calls = dict(page.calls)
            state = {j["job"]: j for j in c.call("calib.jobs")["jobs"]}[job]
            c.call("calib.cancel", job=job)
    finally:
        r.stop()
    levels, sources = count_lines(text)
    return {"elapsed": elapsed, "levels": levels, "sources": sources, "calls": calls, "job": state}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="length of the counted window")
    ap.add_argument("--time-scale", type=float, default=1.0,
                    help="simulated robot's wall time per robot second")
    a = ap.parse_args()
    m = measure(a.seconds, a.time_scale)
    per_min = 60.0 / m["elapsed"]
    info = m["levels"]["INFO"]
    warn = sum(m["levels"][k] for k in ("WARNING", "ERROR", "CRITICAL"))
    job = m["job"]
    print(f"## ritad's journal, busy session (bench/bench_journal.py)\n\nMachine: {machine()}\n")
    print(f"Robot time scale {a.time_scale:g}; window {m['elapsed']:.1f} s; experiment {job['state']} "
          f"({(job.get('progress') or {}).get('step', '')}).\n")
    print("| figure | value |\n|---|---|")
    print(f"| **INFO lines per minute** (goal ≤ 60) | **{info * per_min:.1f}** |")
    print(f"| WARNING+ lines per minute | {warn * per_min:.1f} |")
    print(f"| DEBUG lines per minute (not written at the default level, INFO) "
          f"| {m['levels']['DEBUG'] * per_min:.1f} |")
    busiest = sorted(m['calls'].items(), key=lambda kv: -kv[1])
    print(f"| page's bus calls per minute | {sum(m['calls'].values()) * per_min:.0f} "
          f"({', '.join(f'{k} {v * per_min:.0f}' for k, v in busiest)}) |")
    print("\nINFO+ lines by source (per minute): " + ", ".join(
        f"{k} {v * per_min:.1f}" for k, v in m["sources"].most_common(12)))


if __name__ == "__main__":
    main()
