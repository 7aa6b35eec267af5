"""The operator console's cost: daemon CPU rise at 5 fps full-size live view, console CPU, page latency.

Goal: with the console showing a 5 fps live view of full-size frames, the
daemon's CPU rises by ≤ 5 % of a core; the console process's CPU and the browser-side
frame latency p99 are reported.

Method: ritad on the fakes with a full-size camera (4024×3036 Mono8, ``prerender=2&fps=5``:
two rendered frames cycled, so the simulation's rendering costs nothing per frame) and
CURVE on tcp, as a laptop connects. Three phases of ``--seconds`` each: (0) stream off,
(A) stream on with no subscriber, (B) stream on with ``ritactl console`` (operator key over
CURVE tcp) and a headless chromium page showing the live view at 5 fps, 1000 px wide.
CPU is utime+stime from /proc over each phase (all threads). The rise attributed to the
live view is B − A (``camera.preview``: a strided slice and a JPEG per shown frame, the
command traffic, CURVE on ~130 kB pictures); B − 0 (stream plus console) is reported too.
Page latency: acquisition
(the frame header's ``host_time_ns``) to drawn on the canvas (``Date.now()`` in the page),
same host clock.

Run: ``.venv/bin/python bench/bench_console.py [--seconds 20]`` (needs chromium + chromium-driver).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import cpu_seconds, machine, pct  # noqa: E402
from tools.harness.browser import console_session, start_robot, wait_for  # noqa: E402

CAMERA = "sim:?size=full&prerender=2&fps=5"


def cpu_over(pids: list[int], seconds: float) -> list[float]:
    """Fraction of one core each process used over ``seconds``."""
    c0, t0 = [cpu_seconds(p) for p in pids], time.monotonic()
    time.sleep(seconds)
    c1, t1 = [cpu_seconds(p) for p in pids], time.monotonic()
    return [(b - a) / (t1 - t0) for a, b in zip(c0, c1)]


def measure(seconds: float) -> dict[str, Any]:
    tmp = Path(tempfile.mkdtemp(prefix="bench-console-"))
    r, laptop = start_robot(tmp, camera=CAMERA, worker=False, keys={"ole": "operator"})
    out: dict[str, Any] = {}
    try:
        with r.client(timeout=60) as c:
            c.wait_ready(("camera",), 300)
            out["idle"] = cpu_over([r.proc.pid], seconds)[0]
            c.call("camera.stream.start")
            time.sleep(1.0)
            f0 = c.call("camera.status")["frames"]
            out["stream"] = cpu_over([r.proc.pid], seconds)[0]
            out["camera_fps"] = (c.call("camera.status")["frames"] - f0) / seconds
            args = ["--endpoint", r.endpoints[1], "--keys", str(laptop), "--key", "ole"]
            with console_session(args, tmp / "console") as (con, drv):
                drv.execute_script("const s = document.getElementById('view-width'); s.value = '1000';"
                                   "s.dispatchEvent(new Event('change'));")
                wait_for("frames drawn",
                         lambda: drv.execute_script("return window.rita.framesDrawn") >= 5, 30)
                drv.execute_script("window.rita.latencies = []; window.rita.framesDrawn = 0;")
                daemon, console = cpu_over([r.proc.pid, con.proc.pid], seconds)
                lat = drv.execute_script("return window.rita.latencies")
                drawn = drv.execute_script("return window.rita.framesDrawn")
                meta = drv.execute_script("return window.rita.meta")
            c.call("camera.stream.stop")
            out.update(live=daemon, console=console, lat=lat, page_fps=drawn / seconds, meta=meta)
    finally:
        r.stop()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="length of each measured phase")
    a = ap.parse_args()
    m = measure(a.seconds)
    rise, rise_idle = (m["live"] - m["stream"]) * 100, (m["live"] - m["idle"]) * 100
    lat = m["lat"]
    meta = m["meta"] or {}
    print(f"# bench_console\n\nMachine: {machine()}\n")
    print("| metric | value | goal | met |\n|---|---|---|---|")
    print(f"| daemon CPU: stream off / stream on (5 fps, 4024×3036) / plus console live view, "
          f"{a.seconds:g} s each "
          f"| {m['idle'] * 100:.1f} / {m['stream'] * 100:.1f} / {m['live'] * 100:.1f} % of a core | – | – |")
    print(f"| daemon CPU rise from the live view (console pulling camera.preview over CURVE tcp) "
          f"| {rise:+.1f} % of a core "
          f"| ≤ 5 % | {'yes' if rise <= 5 else 'NO'} |")
    print(f"| daemon CPU rise, stream and live view together vs. stream off "
          f"| {rise_idle:+.1f} % of a core | – | – |")
    print(f"| console process CPU (5 fps, page {meta.get('out_w')}×{meta.get('out_h')} JPEG, "
          f"1:{meta.get('step')}) "
          f"| {m['console'] * 100:.1f} % of a core | reported | – |")
    print(f"| frames drawn by the page | {m['page_fps']:.2f} /s (camera {m['camera_fps']:.2f} /s) | 5 | – |")
    print(f"| latency acquisition → drawn in the page "
          f"| p50 {pct(lat, 50):.0f} ms, p99 {pct(lat, 99):.0f} ms, "
          f"max {max(lat, default=float('nan')):.0f} ms ({len(lat)} frames) | reported | – |")


if __name__ == "__main__":
    main()
