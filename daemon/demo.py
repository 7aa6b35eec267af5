"""`make demo`: the main job on the simulated world, driven over the bus as an operator would.

Starts ``ritad --sim`` as a child process (it starts the calibration worker), waits
for it, shows the device states, locks the tracker onto the robot's reflector, takes
a capture (image + tracker point + robot state saved as a dataset entry), watches
telemetry for a moment, then runs ``ritactl calibrate --reversal`` and ``ritactl
experiment`` and prints their results next to the simulated ground truth, and stops
the daemon with SIGTERM. Output goes to ``demo-out/`` (emptied first).
"""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

from daemon.bus.client import Client
from daemon.bus.protocol import CommandError
from fakes.launch import start_ritad
from fakes.operator import lock_on_robot

ROOT = Path(__file__).resolve().parents[1]


def say(text: str) -> None:
    print(f"\n== {text}", flush=True)


def operator_files(c: Client, out: Path) -> dict[str, Path]:
    """What an operator has before calibrating: plate file, camera model, rough nest positions.

    ``ritad --sim`` installs them in its data dir (the simulated world plays the installer,
    fakes/installer.py); they are fetched over the bus as a laptop would (``ritactl fetch sim``).
    """
    from daemon.ctl.fetch import fetch

    r = fetch(c, ["sim"], out, say=lambda _: None)
    if r["errors"]:
        raise SystemExit(f"cannot fetch the simulation's installed files: {r['errors']}")
    sim = out / "sim"
    return {"plate": sim / "plate.json", "camera_model": sim / "camera_model.json", "nests": sim / "nests.json"}


def ritactl(endpoint: str, *args: str, timeout: float = 600) -> int:
    """Run ritactl as the operator would, output straight to the terminal."""
    cmd = [sys.executable, "-m", "daemon.ctl.main", "--endpoint", endpoint, *args]
    print("$ ritactl " + " ".join(args), flush=True)
    return subprocess.run(cmd, cwd=ROOT, timeout=timeout).returncode


def run_calibration(c: Client, out: Path, endpoint: str) -> int:
    """Referencing with reversal, then the 8-direction experiment, compared with the ground truth."""
    import numpy as np

    from fakes.score import score_rob_H_cam

    files = operator_files(c, out)
    truth = c.call("sim.truth")
    p = c.call("tracker.measure", timeout=60)
    say("referencing with instrument reversal (robot on the plate; tracker finds the nests)")
    rc = ritactl(endpoint, "calibrate", "--reversal", "--plate", str(files["plate"]), "--camera-model",
                 str(files["camera_model"]), "--nests-approx", str(files["nests"]), "--robot-approx",
                 str(p["x"]), str(p["y"]), str(p["z"]))
    if rc:
        return rc
    active = c.call("calib.results")["active"]
    err = score_rob_H_cam(active["rob_H_cam"], truth["rob_H_cam"])
    print(f"\n  vs ground truth: t_xy {err['t_xy_mm'] * 1000:.1f} µm, t_z {err['t_z_mm'] * 1000:.1f} µm, "
          f"rotation {err['rot_deg'] * 3600:.1f} arcsec")
    mark = truth["marks"][0]
    say(f"8-direction repeatability experiment on mark {mark['name']} (5 repetitions each)")
    rc = ritactl(endpoint, "experiment", "--mark", str(mark["x_mm"] + 1.5), str(mark["y_mm"] - 1.0),
                 "--reps", "5")
    if rc:
        return rc
    hist = c.call("calib.results")["history"]
    exp = json.loads(Path(hist[0]["file"]).read_text()) if hist else {}
    if exp.get("procedure") == "experiment":
        xy = np.array([m["abs_xyz"][:2] for m in exp["marks"]])
        true = np.array([mark["x_mm"], mark["y_mm"]])
        fit = exp["metrics"].get("fit") or {}
        print(f"\n  vs ground truth: grand mean off by {np.hypot(*(xy.mean(0) - true)) * 1000:.1f} µm; "
              f"fitted M off by {np.hypot(*(np.array(fit.get('M', xy.mean(0))) - true)) * 1000:.1f} µm; "
              f"|b| = {fit.get('b_norm_mm', float('nan')) * 1000:.1f} µm")
        report = out / "report"
        report.mkdir(exist_ok=True)
        for name in ("report.md", "report.csv", "clusters.png"):
            src = Path(exp["dataset"]) / name
            if src.exists():
                (report / name).write_bytes(src.read_bytes())
        print(f"  report files: {report}/report.md, report.csv, clusters.png")
    return 0


def main() -> int:
    out = ROOT / "demo-out"
    if out.exists():  # a fresh world each run: no half-finished jobs from an interrupted demo
        shutil.rmtree(out)
    out.mkdir()
    t0 = time.monotonic()
    say("starting ritad --sim (simulated camera, tracker and robot in one world)")
    try:
        ritad = start_ritad(tmp=out, args=["--seed", "1"])
    except RuntimeError as exc:
        raise SystemExit(f"ritad did not start: {exc}") from None
    endpoint, rc = ritad.endpoint, 0
    try:
        h = ritad.wait_ready(timeout=90)
        with ritad.client() as c:
            print(f"ritad ready on {endpoint} after {time.monotonic() - t0:.1f} s")
            for kind, s in h["devices"].items():
                print(f"  {kind:8s} {s['state']}  {s['info']}")
            say("tracker: aim at the robot's reflector, find, measure")
            p = lock_on_robot(c)
            print(f"  reflector at ({p['x']:.4f}, {p['y']:.4f}, {p['z']:.4f}) mm, σ {p['std']}")
            say("capture: one image + one tracker measurement + robot state")
            r = c.call("capture", timeout=60, label="demo")
            print(f"  saved {r['path']}  image {r['header']['shape']}")
            say("telemetry for 2 s")
            sub = c.subscriber()
            counts: dict[str, int] = {}
            for topic, _, _ in sub.iter(2.0):
                counts[topic] = counts.get(topic, 0) + 1
            sub.close()
            print("  " + ", ".join(f"{k}: {v}" for k, v in sorted(counts.items())))
            rc = run_calibration(c, out, endpoint)
    except CommandError as exc:  # ClientTimeout (devices never READY, ritad gone) included
        print(f"demo failed: {exc}; see {ritad.log}", file=sys.stderr)
        rc = 1
    finally:
        say("stopping ritad (SIGTERM)")
        code = ritad.stop(10)
        print(f"  ritad exited with {code}")
        if code not in (0, None):
            rc = rc or 1
    print(f"\ndemo finished in {time.monotonic() - t0:.1f} s; outputs in {out}")
    return rc


if __name__ == "__main__":
    sys.exit(main())
