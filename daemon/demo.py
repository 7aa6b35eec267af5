"""`make demo`: the main job on the simulated world, driven over the bus as an operator would.

Starts ``ritad --sim`` as a child process, waits for it, shows the device states,
locks the tracker onto the robot's reflector, takes a capture (image + tracker point
+ robot state saved as a dataset entry), drives the robot, watches telemetry for a
moment and stops the daemon with SIGTERM. Output goes to ``demo-out/``.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from daemon.client import Client
from daemon.protocol import CommandError

ROOT = Path(__file__).resolve().parents[1]


def say(text: str) -> None:
    print(f"\n== {text}", flush=True)


def start_daemon(out: Path, seed: int = 1) -> tuple[subprocess.Popen, str]:
    rt = out / "run"
    rt.mkdir(parents=True, exist_ok=True)
    log = open(out / "ritad.log", "w")
    proc = subprocess.Popen([sys.executable, "-m", "daemon.main", "--sim", "--runtime-dir", str(rt),
                             "--data-dir", str(out / "data"), "--seed", str(seed)],
                            cwd=ROOT, stdout=log, stderr=subprocess.STDOUT,
                            env={**os.environ, "PYTHONPATH": str(ROOT)})
    return proc, f"ipc://{rt}/cmd"


def wait_ready(c: Client, proc: subprocess.Popen, timeout: float = 90.0) -> dict[str, Any]:
    end = time.monotonic() + timeout
    last: dict[str, Any] = {}
    while time.monotonic() < end:
        if proc.poll() is not None:
            raise SystemExit(f"ritad exited with {proc.returncode}; see demo-out/ritad.log")
        try:
            last = c.call("status", timeout=2)
        except CommandError:
            time.sleep(0.2)
            continue
        if all(d["state"] == "READY" for d in last["devices"].values()):
            return last
        time.sleep(0.3)
    raise SystemExit(f"devices not ready after {timeout:.0f} s: {json.dumps(last.get('devices'), indent=1)}")


def lock_on_robot(c: Client) -> dict[str, Any]:
    """Point the tracker at the robot's reflector (truth gives the approximate spot) and lock on."""
    truth = c.call("sim.truth")
    import numpy as np  # the demo runs beside the daemon, not on the thin laptop client

    abs_H_trk = np.array(truth["abs_H_trk"])
    p_abs = np.array(truth["abs_H_rob"])[:3, 3] + [3.0, -2.0, 1.0]  # "about here", a few mm off
    p_trk = np.linalg.inv(abs_H_trk) @ [*p_abs, 1.0]
    c.call("tracker.aim", timeout=60, x=float(p_trk[0]), y=float(p_trk[1]), z=float(p_trk[2]))
    c.call("tracker.find", timeout=60)
    return c.call("tracker.measure", timeout=60)


def main() -> int:
    out = ROOT / "demo-out"
    out.mkdir(exist_ok=True)
    t0 = time.monotonic()
    say("starting ritad --sim (simulated camera, tracker and robot in one world)")
    proc, endpoint = start_daemon(out)
    rc = 0
    try:
        with Client(endpoint, timeout=10) as c:
            h = wait_ready(c, proc)
            print(f"ritad ready on {endpoint} after {time.monotonic() - t0:.1f} s")
            for kind, s in h["devices"].items():
                print(f"  {kind:8s} {s['state']}  {s['info']}")
            say("tracker: aim at the robot's reflector, find, measure")
            p = lock_on_robot(c)
            print(f"  reflector at ({p['x']:.4f}, {p['y']:.4f}, {p['z']:.4f}) mm, σ {p['std']}")
            say("capture: one image + one tracker measurement + robot state")
            r = c.call("capture", timeout=60, label="demo")
            print(f"  saved {r['path']}  image {r['header']['shape']}")
            say("robot: drive 200 mm straight, then measure again")
            c.call("robot.move", timeout=120, distance_mm=200.0, speed_mm_s=100.0, confirm=True)
            p2 = c.call("tracker.measure", timeout=60)
            moved = sum((p2[k] - p[k]) ** 2 for k in "xyz") ** 0.5
            print(f"  reflector moved {moved:.3f} mm (commanded 200 mm)")
            say("telemetry for 2 s")
            sub = c.subscriber()
            counts: dict[str, int] = {}
            for topic, _, _ in sub.iter(2.0):
                counts[topic] = counts.get(topic, 0) + 1
            sub.close()
            print("  " + ", ".join(f"{k}: {v}" for k, v in sorted(counts.items())))
    except CommandError as exc:
        print(f"demo failed: {exc}", file=sys.stderr)
        rc = 1
    finally:
        say("stopping ritad (SIGTERM)")
        proc.send_signal(signal.SIGTERM)
        try:
            code = proc.wait(10)
            print(f"  ritad exited with {code}")
        except subprocess.TimeoutExpired:
            proc.kill()
            print("  ritad did not stop within 10 s: killed", file=sys.stderr)
            rc = 1
    print(f"\ndemo finished in {time.monotonic() - t0:.1f} s; outputs in {out}")
    return rc


if __name__ == "__main__":
    sys.exit(main())
