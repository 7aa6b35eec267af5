"""``ritactl record`` beside a live subscriber: does a recording cost the robot's other readers frames?

Goal (issue 35): a live frame subscriber keeps ≥ 0.9× its rate while ``ritactl record --frames every
1`` runs beside it, at 10 fps and at the simulated camera's top rate; and the frames the recorder
writes per second.

Method: ritad --sim in this process (camera ``sim:?size=1000x750&prerender=4&fps=F``: 750 kB Mono8
frames, prerendered so the renderer is not the limit; F = 10, and 1000 for the top rate: as fast as
the simulated camera delivers), tracker and robot simulated. A subscriber process counts the frames
it receives in a window of ``--seconds``; first alone, then with ``ritactl record --frames every 1
--duration S --json`` (its own process, file in a temporary folder) running over the same window.
The ratio is the subscriber's frames per second with the recorder over without it; frames written
per second are the recorder's own count over its duration (its ``--json`` line), with the frames
it dropped.
Run: ``.venv/bin/python bench/bench_record_live.py [--seconds 10]``.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import machine  # noqa: E402
from daemon.bus.client import Client  # noqa: E402
from daemon.ritad import config  # noqa: E402
from daemon.ritad.daemon import Daemon  # noqa: E402

COUNT = """
import sys, time
from daemon.bus.client import Client
c = Client(sys.argv[1], timeout=10)
sub = c.subscriber(frames=True, hwm=4)
time.sleep(0.5)
n, end = 0, time.monotonic() + float(sys.argv[2])
for _ in sub.iter(float(sys.argv[2]) + 1):
    if time.monotonic() >= end:
        break
    n += 1
print(n / float(sys.argv[2]))
"""


def subscriber(ep: str, seconds: float) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-c", COUNT, ep, str(seconds)], stdout=subprocess.PIPE, text=True)


def measure(fps: int, seconds: float, tmp: Path) -> dict[str, float]:
    cfg = config.sim_config(tmp / f"rt{fps}", tmp / f"data{fps}")
    cfg.daemon.start_worker = False
    cfg.devices.camera = f"sim:?size=1000x750&noise=0&prerender=4&fps={fps}"
    d = Daemon(cfg)
    d.start()
    c = Client(d.server.endpoints[0], timeout=20)
    try:
        c.wait_ready(timeout=60)
        c.call("camera.stream.start")
        ep = d.server.endpoints[0]
        alone = float(subscriber(ep, seconds).communicate()[0])
        sub = subscriber(ep, seconds)
        rec = subprocess.run([sys.executable, "-m", "daemon.ctl.main", "--endpoint", ep, "--json", "record",
                              "--out", str(tmp / f"r{fps}.mcap"), "--frames", "every", "1", "--duration",
                              str(seconds + 1), "--min-free", "500M"], capture_output=True, text=True)
        beside = float(sub.communicate()[0])
        out = json.loads(rec.stdout.splitlines()[-1])
        c.call("camera.stream.stop")
    finally:
        c.close()
        d.stop_event.set()
        d.stop()
        for r in (rig.runner for rig in d.rigs):
            if hasattr(r.device, "shutdown"):
                r.device.shutdown()
    return {"fps": fps, "alone": alone, "beside": beside, "ratio": beside / alone if alone else 0.0,
            "written": out["frames"] / out["duration_s"], "dropped": out["frames_missed"],
            "frames": out["frames"], "duration": out["duration_s"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rates", type=int, nargs="+", default=[10, 1000], help="camera fps to measure at")
    a = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for fps in a.rates:
            rows.append(measure(fps, a.seconds, Path(d)))
            time.sleep(1)
    print(machine())
    print("\n| camera asked for | subscriber alone (frames/s) | subscriber beside the recorder | ratio (goal ≥ 0.9) "
          "| frames written/s | dropped by the recorder |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['fps']} fps | {r['alone']:.1f} | {r['beside']:.1f} | {r['ratio']:.2f} | {r['written']:.1f} "
              f"({r['frames']} in {r['duration']:.1f} s) | {r['dropped']} |")


if __name__ == "__main__":
    main()
