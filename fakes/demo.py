"""`make demo`: the main job on the simulated world, driven over the bus as an operator would.

Starts ``ritad --sim`` as a child process (it starts the calibration worker), waits
for it, shows the device states, locks the tracker onto the robot's reflector, takes
a capture (image + tracker point + robot state saved as a dataset entry), watches
telemetry for a moment, then runs the closed loop an operator runs on a real Rita:
the guided intrinsics (the simulated operator holds the board), the plate survey from
photographs and ``ritactl calibrate --reversal`` with that camera model and plate; then
the same camera and plate on a realistic floor (``--profile paper+imu``, fakes/demo_floor.py):
referencing and ``ritactl experiment`` with and without the compensations. Each result is
printed next to the simulated ground truth
(``fakes/score.py``: truth grades, it never feeds the loop). Stops the daemon with
SIGTERM. Output goes to ``demo-out/`` (emptied first).
"""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

from daemon.bus.client import Client
from daemon.bus.protocol import CommandError
from fakes.launch import start_ritad
from daemon.bus.figures import Goal, goal_text
from fakes.operator import lock_on_robot

ROOT = Path(__file__).resolve().parents[1]


def say(text: str) -> None:
    print(f"\n== {text}", flush=True)


def operator_files(c: Client, out: Path) -> dict[str, Path]:
    """What an operator has before calibrating: the plate's design file, the intrinsics board's
    file, rough nest positions, and (after ``sim.survey_images``) the survey photographs.

    ``ritad --sim`` installs them in its data dir (the simulated world plays the installer,
    fakes/installer.py); they are fetched over the bus as a laptop would (``ritactl fetch sim``).
    None of them is a measured result: the camera model and the surveyed plate come from the
    product's own procedures below.
    """
    from daemon.ctl.fetch import fetch

    r = fetch(c, ["sim"], out, say=lambda _: None)
    if r["errors"]:
        raise SystemExit(f"cannot fetch the simulation's installed files: {r['errors']}")
    sim = out / "sim"
    return {"plate_design": sim / "plate.json", "board": sim / "board.json", "nests": sim / "nests.json",
            "survey": sim / "survey"}


def ritactl(endpoint: str, *args: str, timeout: float = 600) -> int:
    """Run ritactl as the operator would, output straight to the terminal."""
    cmd = [sys.executable, "-m", "daemon.ctl.main", "--endpoint", endpoint, *args]
    print("$ ritactl " + " ".join(args), flush=True)
    return subprocess.run(cmd, cwd=ROOT, timeout=timeout).returncode


def intrinsics_goals(err: dict[str, float]) -> list[str]:
    """The intrinsics' errors against truth, each with its goal and verdict (docs/accuracy.md)."""
    return [goal_text(err["df_rel"] * 100, Goal("<=", 0.1, "%"), label="focal length off by"),
            goal_text(err["pp_full_px"], Goal("<=", 1.5, "px"), ".2f",
                      "principal point off, at full size, by")]


def survey_goals(err: dict[str, float]) -> list[str]:
    """The surveyed nest seats against truth: each seat, the worst with its goal and verdict."""
    each = ", ".join(f"{n} {e * 1000:.0f} µm" for n, e in err.items())
    worst = max(err.values()) * 1000 if err else float("nan")
    return [goal_text(worst, Goal("<=", 50, "µm"), ".0f", f"nest seats off by {each}; the worst")]


def referencing_goals(err: dict[str, float]) -> list[str]:
    """rob_H_cam against truth, each figure with its goal and verdict."""
    return [goal_text(err["t_xy_mm"] * 1000, Goal("<", 60, "µm"), ".1f", "t_xy"),
            goal_text(err["t_z_mm"] * 1000, Goal("<", 45, "µm"), ".1f", "t_z"),
            goal_text(err["rot_deg"], Goal("<", 0.015, "°"), ".4f", "rotation")]


def print_goals(lines: list[str]) -> None:
    """'vs ground truth', one figure a line: a miss cannot hide in the middle of a long line."""
    print("  vs ground truth:")
    for line in lines:
        print(f"    {line}")


def run_intrinsics(c: Client, out: Path) -> int:
    """The guided intrinsics: the simulated operator holds the board as each prompt asks."""
    from fakes.board import run_intrinsics as play_operator
    from fakes.score import score_camera_model

    board = json.loads(operator_files(c, out)["board"].read_text())
    say("camera intrinsics: ritactl intrinsics, the operator holds the board as the prompts ask")
    r = play_operator(c, {"board": board}, seed=1, timeout=600)
    if r.get("failed") or r.get("verdict") not in ("ok", "warn"):
        print(f"  intrinsics failed: {r.get('error') or r.get('messages')}")
        return 1
    model = json.loads((Path(r["dataset"]) / "result.json").read_text())["camera_model"]
    (out / "camera_model.json").write_text(json.dumps(model))  # the second part takes it to another floor
    std = model.get("std") or {}
    K = model["K"]
    print(f"  {len(r['_prompts'])} prompts answered; verdict {r['verdict']}; "
          f"f = {K[0][0]:.2f} ± {std.get('fx', 0):.2f} px,"
          f" centre ({K[0][2]:.2f}, {K[1][2]:.2f}) px at {model['size'][0]}×{model['size'][1]}")
    print_goals(intrinsics_goals(score_camera_model(model, c.call("sim.truth"))))
    return 0


def run_survey(c: Client, out: Path, endpoint: str) -> Path | None:
    """Photographs of the whole plate → ``ritactl plate survey`` → the surveyed plate.json."""
    from fakes.score import score_nests

    say("plate survey: photographs of the whole plate (a simulated DSLR), then ritactl plate survey")
    made = c.call("sim.survey_images", timeout=300, views=8)
    print(f"  {len(made['files'])} photographs in data_dir/{made['folder']}")
    files = operator_files(c, out)
    plate = out / "plate.json"
    if ritactl(endpoint, "plate", "survey", str(files["survey"]), "--plate", str(files["plate_design"]),
               "--out", str(plate)) not in (0, 1):
        return None
    print_goals(survey_goals(score_nests(json.loads(plate.read_text()), c.call("sim.truth"))))
    return plate


def run_referencing(c: Client, out: Path, endpoint: str, plate: Path, robot_trk: list[float]) -> int:
    """Referencing with reversal on the surveyed plate and the camera model the intrinsics installed."""
    from fakes.score import score_rob_H_cam

    files = operator_files(c, out)
    say("referencing with instrument reversal (robot on the plate; tracker finds the nests)")
    rc = ritactl(endpoint, "calibrate", "--reversal", "--plate", str(plate),
                 "--nests-approx", str(files["nests"]), "--robot-approx", *(str(v) for v in robot_trk))
    if rc:
        return rc
    active = c.call("calib.results")["active"]
    print()
    print_goals(referencing_goals(score_rob_H_cam(active["rob_H_cam"], c.call("sim.truth")["rob_H_cam"])))
    return 0


def run_calibration(c: Client, out: Path, endpoint: str, robot_trk: list[float]) -> int:
    """intrinsics → plate survey → referencing, each consuming the previous one's output; then the
    same camera and plate on a realistic floor (fakes/demo_floor.py): referencing and experiment."""
    from fakes.demo_floor import run_realistic_floor

    print("\n  (sim.truth is read by the simulated operator's eye to point the tracker, "
          "and to score the results printed as 'vs ground truth'; "
          "it never enters the product's calculations)")
    rc = run_intrinsics(c, out)
    plate = None if rc else run_survey(c, out, endpoint)
    if plate is None:
        return rc or 1
    return run_referencing(c, out, endpoint, plate, robot_trk) or run_realistic_floor(
        out, out / "camera_model.json", plate, operator_files(c, out)["nests"], say, ritactl)


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
            rc = run_calibration(c, out, endpoint, [p["x"], p["y"], p["z"]])
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
