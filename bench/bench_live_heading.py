"""``heading_fit`` on the live path: through ritad and the worker, several seeds of ``paper+imu``.

Per seed, one ``ritad --sim --profile paper+imu --seed N`` at the simulator's default speed
(the base at ``time_scale`` 0.02) runs what an operator runs: the guided intrinsics, the plate
survey, the referencing (with its reversal, the default), an 8 × ``--learn-reps`` experiment on
mark M2 that stores the robot-frame bias and heading_fit's weight, then the 8 × 5 experiment on
mark M1 with the default compensations. The same stored dataset is then recomputed offline
(``daemon.compute.recompute``) with ``none``, the chord (``tilt,bias,mount``) and the default, and
each is scored against the world's mark (``sim.truth``: scoring only). docs/accuracy.md records
the table.

``.venv/bin/python bench/bench_live_heading.py --seeds 3 4 5 6 7 [--learn-reps 5] [--json out.json]``
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import machine  # noqa: E402
from daemon.bus.client import Client  # noqa: E402
from daemon.bus.procedures import MEASURE_MARK  # noqa: E402
from daemon.compute.recompute import recompute  # noqa: E402
from daemon.compute.survey import survey_plate  # noqa: E402
from fakes.board import run_intrinsics  # noqa: E402
from fakes.demo import operator_files  # noqa: E402
from fakes.launch import start_ritad  # noqa: E402
from fakes.operator import lock_on_robot, rough_mark  # noqa: E402
from fakes.score import score_experiment  # noqa: E402

#: the simulated base runs 50× faster than real time: its inclinometer's 0.1 s output period is 2 ms
SIM_IMU = {"imu_interval_s": 0.002}


def _job(c: Client, procedure: str, params: dict[str, Any], timeout: float = 1200) -> dict[str, Any]:
    """Run a job to its end; its stored result (raises with the job's record when it failed)."""
    job = c.call("calib.start", procedure=procedure, params={**params, **SIM_IMU})["job"]
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        rec = next((j for j in c.call("calib.jobs")["jobs"] if j.get("job") == job), None)
        if rec is not None and rec.get("state") in ("done", "failed", "stopped", "cancelled"):
            break
        time.sleep(1.0)
    mine = [h for h in c.call("calib.results")["history"] if h.get("job") == job]
    if not mine:
        raise RuntimeError(f"{procedure} ended without a result: {rec}")
    return json.loads(Path(mine[0]["file"]).read_text())


def _inputs(c: Client, tmp: Path, seed: int) -> dict[str, Any]:
    """The guided intrinsics (installs the camera model) and the plate survey; the referencing's params."""
    files = operator_files(c, tmp)
    intr = run_intrinsics(c, {"board": json.loads(files["board"].read_text())}, seed=seed, timeout=600)
    if intr.get("verdict") not in ("ok", "warn"):
        raise RuntimeError(f"intrinsics: {intr}")
    c.call("sim.survey_images", views=8, width_px=1800, timeout=300)
    files = operator_files(c, tmp)
    plate = survey_plate(files["survey"], json.loads(files["plate_design"].read_text()))
    p = lock_on_robot(c)
    return {"plate": plate, "nests_approx_trk": json.loads(files["nests"].read_text()),
            "robot_approx_trk": [p["x"], p["y"], p["z"]]}


#: the comparisons: label → compensation of the recompute
WAYS = {"none": "none", "chord": "tilt,bias,mount", "default": MEASURE_MARK.param("compensation").default}


def one_seed(seed: int, tmp: Path, learn_reps: int = 5) -> dict[str, Any]:
    t0 = time.monotonic()
    with start_ritad(tmp=tmp, args=["--seed", str(seed), "--profile", "paper+imu"], timeout=90) as r:
        r.wait_ready(timeout=90, worker=True)
        with r.client() as c:
            _job(c, "referencing", _inputs(c, tmp, seed))
            marks = c.call("sim.truth")["marks"]  # scoring only (and the operator's eye: rough_mark)
            _job(c, "experiment", {"mark_xy": rough_mark(c, 1)[1], "kind": marks[1]["kind"],
                                   "repetitions": learn_reps, "store_bias": True})
            weight = c.call("calib.results")["active"].get("heading_weight")
            exp = _job(c, "experiment", {"mark_xy": rough_mark(c, 0)[1], "repetitions": 5})
    out: dict[str, Any] = {"seed": seed, "seconds": round(time.monotonic() - t0, 1), "weight": weight,
                           "stored_applied": exp.get("compensation", {}).get("applied")}
    for label, comp in WAYS.items():
        res, _ = recompute(Path(exp["dataset"]), compensation=comp)
        out[label] = score_experiment(res, marks[0])
        out[label]["applied"] = res.get("compensation", {}).get("applied")
        out[label]["skipped"] = res.get("compensation", {}).get("skipped")
    return out


def table(rows: list[dict[str, Any]]) -> str:
    lines = ["| seed | compensation | enclosing | pairwise | abs RMS | heading_fit applied at (weight) |",
             "|---|---|---:|---:|---:|---|"]
    for r in rows:
        w = r.get("weight") or {}
        for label in WAYS:
            s = r[label]
            hf = "" if label != "default" else (f"{(s.get('applied') or {}).get('heading_fit', '–')} "
                                                f"({w.get('weight', 0):.2f}, {w.get('model', '–')})")
            lines.append(f"| {r['seed']} | {label} | {s['enclosing']:.3f} | {s['pairwise']:.3f} | "
                         f"{s['abs_rms']:.3f} | {hf} |")
    for label in ("chord", "default"):
        for key in ("enclosing", "pairwise", "abs_rms"):
            v = [r[label][key] for r in rows]
            lines.append(f"| median / max | {label} {key} | {np.median(v):.3f} / {max(v):.3f} | | | |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[3, 4, 5, 6, 7])
    ap.add_argument("--learn-reps", type=int, default=5, help="repetitions of the learning experiment on M2")
    ap.add_argument("--json", type=Path, help="also write the rows here")
    args = ap.parse_args()
    print(machine())
    rows = []
    for seed in args.seeds:
        with tempfile.TemporaryDirectory(prefix=f"live-heading-{seed}-") as d:
            rows.append(one_seed(seed, Path(d), args.learn_reps))
        r = rows[-1]
        print(f"seed {seed} ({r['seconds']} s): " + "; ".join(
            f"{k} {r[k]['enclosing']:.3f}/{r[k]['pairwise']:.3f}/{r[k]['abs_rms']:.3f}"
            for k in WAYS), flush=True)
        if args.json:
            args.json.write_text(json.dumps(rows, indent=1, default=str))
    print(table(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
