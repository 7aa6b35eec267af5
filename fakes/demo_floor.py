"""`make demo`, second part: the same camera and plate on a realistic floor.

A second ``ritad --sim --profile paper+imu`` (same seed: the same camera, plate and
robot; now with the AT901's distance-dependent error, an uneven floor, drives that bend,
reflector and target imperfections and an inclinometer, docs/accuracy.md) takes the
camera model and the surveyed plate of the first part, references with reversal and
runs the paper's 8-direction experiment with the compensations on (after a short experiment on
the other mark has stored the robot-frame bias b). The same dataset is
recomputed without them (``ritactl recompute --compensation none``), and both are
printed as the paper's table next to their errors against the simulated truth.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable

import numpy as np

from daemon.bus.client import Client
from daemon.bus.figures import Goal, goal_cell, verdict, worse_lines
from daemon.compute.report_shifts import compensation_effects, left_out_metrics
from fakes.accuracy import GOALS_MM, PAPER_MM
from fakes.launch import start_ritad
from fakes.operator import lock_on_robot, rough_mark
from fakes.score import score_experiment

PAPER = {k.removesuffix("_mm"): v for k, v in PAPER_MM.items()}
GOALS = {k.removesuffix("_mm"): Goal("<=", v, "mm") for k, v in GOALS_MM.items()}


ROWS = (("enclosing diameter [mm]", "enclosing"),
        ("mean pairwise distance of cluster means [mm]", "pairwise"),
        ("absolute error RMS vs truth [mm]", "abs_rms"), ("grand mean vs truth [mm]", "grand_mean"))


def summary_lines(without: dict[str, float], with_: dict[str, float], comp: dict[str, Any],
                  left_out: dict[str, dict[str, float]] | None = None) -> list[str]:
    """The paper's figures without and with the compensations, each goal met or MISSED for both columns, and
    a line for every figure the compensations made worse, naming the compensation that did (``left_out``:
    per compensation the figures with it left out alone) or the possible reasons."""
    applied = "+".join(k for k, n in (comp.get("applied") or {}).items() if n) or "none"
    out = [f"| paper profile + inclinometer, 8 × 5 | the paper | without compensation | with {applied} "
           "| goal |",
           "|---|---:|---:|---:|---|"]
    for label, k in ROWS:
        paper = f"{PAPER[k]:.3f}" if k in PAPER else "–"
        goal = f"{goal_cell(with_[k], GOALS[k])} (without: {verdict(GOALS[k].met(without[k]))})" \
            if k in GOALS else ""
        out.append(f"| {label} | {paper} | {without[k]:.3f} | {with_[k]:.3f} | {goal} |")
    for label, k in ROWS:
        left = {name: figures[k] for name, figures in (left_out or {}).items()}
        out += worse_lines(label.split(" [")[0], without[k], with_[k], comp, k == "enclosing", left)
    return out


def left_out_scores(result: dict[str, Any], truth_mark: dict[str, Any]) -> dict[str, dict[str, float]]:
    """Per compensation the stops applied: the scored figures with it left out alone (each mark minus its
    shift, daemon/compute/report_shifts.py, as the report names the one that made a figure worse)."""
    effects = compensation_effects(result, result["dataset"])
    out = {}
    for name, metrics in left_out_metrics(result, effects).items():
        marks = [{"abs_xyz": (np.asarray(m["abs_xyz"][:2]) - s.get(name, (0.0, 0.0))).tolist()}
                 for m, s in zip(result["marks"], effects.shifts)]
        out[name] = score_experiment({"marks": marks, "metrics": metrics}, truth_mark)
    return out


#: the simulated base runs 50× faster than real time: its inclinometer's 0.1 s output period is 2 ms
SIM_IMU = {"imu_interval_s": 0.002}


def _job(c: Client, endpoint: str, ritactl: Callable[..., int], procedure: str, params: dict[str, Any],
         shown: str) -> tuple[int, dict[str, Any]]:
    """Post a job with its parameters, follow it with ``ritactl follow``; (exit code, its stored result)."""
    print(f"$ ritactl {shown}")
    job = c.call("calib.start", procedure=procedure, params={**params, **SIM_IMU})["job"]
    rc = ritactl(endpoint, "follow", job, timeout=1800)
    hist = c.call("calib.results")["history"]
    mine = [h for h in hist if h.get("job") == job]
    result = json.loads(Path(mine[0]["file"]).read_text()) if mine else {}
    # a `warn` is a finished result whose reasons ``follow`` printed: the demo shows it and goes on
    return (0 if rc and result.get("verdict") == "warn" else rc), result


def _experiments(c: Client, out: Path, endpoint: str, ritactl: Callable[..., int]) -> int:
    from daemon.compute.recompute import recompute

    truth_marks = c.call("sim.truth")["marks"]  # scoring only (and the operator's eye: rough_mark)
    name, approx = rough_mark(c, 1)
    print(f"\n== a short experiment on mark {name} (8 × 1) stores the robot-frame bias b "
          "with the calibration")
    kind = truth_marks[1]["kind"]
    rc, _ = _job(c, endpoint, ritactl, "experiment",
                 {"mark_xy": approx, "kind": kind, "repetitions": 1, "store_bias": True},
                 f"experiment --mark {approx[0]} {approx[1]} --kind {kind} --reps 1 --store-bias")
    if rc:
        return rc
    name, approx = rough_mark(c, 0)
    print(f"\n== 8-direction experiment on mark {name} with the compensations (8 × 5)")
    rc, result = _job(c, endpoint, ritactl, "experiment", {"mark_xy": approx, "repetitions": 5},
                      f"experiment --mark {approx[0]} {approx[1]} --reps 5")
    if rc or not result:
        return rc or 1
    plain, _ = recompute(Path(result["dataset"]), compensation="none")
    print("\n  The paper's table WITHOUT compensation "
          "(the same dataset, ritactl recompute --compensation none):\n")
    print("  " + plain["table_markdown"].replace("\n", "\n  "))
    print()
    scored = (score_experiment(plain, truth_marks[0]), score_experiment(result, truth_marks[0]))
    left_out = left_out_scores(result, truth_marks[0])
    for line in summary_lines(*scored, result.get("compensation") or {}, left_out):
        print(f"  {line}")
    report = out / "report"
    report.mkdir(exist_ok=True)
    files = [f for f in result.get("files") or [] if (Path(result["dataset"]) / f).exists()]
    for f in files:
        (report / f).write_bytes((Path(result["dataset"]) / f).read_bytes())
    print(f"\n  report files (with the compensations) in {report}: {', '.join(files)}")
    return 0


def run_realistic_floor(out: Path, camera_model: Path, plate: Path, nests: Path, say: Callable[[str], None],
                        ritactl: Callable[..., int]) -> int:
    """Part two of the demo; ``camera_model`` and ``plate`` come from the first part's procedures."""
    say("a realistic floor: ritad --sim --profile paper+imu (same camera, plate and robot; the AT901's "
        "error model, an uneven floor, bent drives, an inclinometer; docs/accuracy.md)")
    folder = out / "paper+imu"
    folder.mkdir()
    try:
        ritad = start_ritad(tmp=folder, args=["--seed", "1", "--profile", "paper+imu"])
    except RuntimeError as exc:
        print(f"  ritad (paper+imu) did not start: {exc}")
        return 1
    try:
        ritad.wait_ready(timeout=90)
        with ritad.client() as c:
            p = lock_on_robot(c)
            say("referencing with reversal (the inclinometer's offset is calibrated on the plate)")
            params = {"camera_model": json.loads(camera_model.read_text()),
                      "plate": json.loads(plate.read_text()),
                      "nests_approx_trk": json.loads(nests.read_text()), "reversal": True,
                      "robot_approx_trk": [p["x"], p["y"], p["z"]]}
            rc, _ = _job(c, ritad.endpoint, ritactl, "referencing", params,
                         f"calibrate --reversal --camera-model {camera_model} --plate {plate} "
                         f"--nests-approx {nests} --robot-approx {p['x']:.1f} {p['y']:.1f} {p['z']:.1f}")
            if rc:
                return rc
            off = c.call("calib.results")["active"].get("imu_offset_deg")
            if off:
                print(f"  inclinometer offset on the plate: roll {off[0]:+.4f}°, pitch {off[1]:+.4f}°")
            return _experiments(c, out, ritad.endpoint, ritactl)
    finally:
        code = ritad.stop(10)
        print(f"  ritad (paper+imu) exited with {code}")
