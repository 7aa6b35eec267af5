"""Path shapes the heading fit was not built with: the product's own verdicts against truth (issue #33).

For each seed: one referencing (with reversal) of a ``paper+imu`` world; then, per path shape of
the final approach (fakes/path_shapes.py), the documented learning flow run through the product's
code — ``compute_experiment`` on an 8 × 5 experiment over mark M2 with the compensation under test,
its result stored with ``biased_calibration`` (the live ``store_bias``), then the scored 8 × 5
experiment over mark M1 with that calibration. Both for the default (``tilt,heading_fit,bias,mount``)
and for the chord (``tilt,bias,mount``, which learns and stores its own b). A *changed* case
learns on one shape and scores on another: a robot whose path changed after its weight was learned.
The referencing keeps the world's arc, so on one seed every case shares one calibration.

Per case (one seed, one shape pair, one compensation): p95 over the 40 stops of |e|/σ (e: the mark's
xy error against truth, σ: the ``std_mm`` the product states; an honest isotropic 2-D Gaussian σ
gives 1.73), enclosing diameter, absolute RMS and pairwise mean (mm), the verdict and its messages,
the weight applied and the one the scored experiment learns for itself.

    PYTHONPATH=$PWD .venv/bin/python bench/accuracy_shapes.py --seeds 4 --out shapes.jsonl
    PYTHONPATH=$PWD .venv/bin/python bench/accuracy_shapes.py --table shapes.jsonl [--before old.jsonl]
    PYTHONPATH=$PWD .venv/bin/python bench/accuracy_shapes.py --envelope --seeds 4 --out envelope.jsonl

Not in ``make test`` (minutes); tests/bench/test_accuracy_shapes.py runs one small case.
"""
from __future__ import annotations

import argparse
import gzip
import json
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from typing import Any
from unittest.mock import patch

import numpy as np

from bench.shapes_data import calibration_record, experiment_obs, image_loader
from calibration.heading_weight import MODELS, learn_model
from daemon.bus.procedure_params import COMPENSATION
from daemon.compute import experiment_checks
from daemon.compute.procedures import compute_experiment
from daemon.worker.compensations import biased_calibration
from fakes import profiles
from fakes.accuracy import Case, referencing
from fakes.path_shapes import SHAPES
from fakes.simulate import SimConfig, Simulation
from fakes.world import World, WorldParams

#: the compensations compared: the product's default and the chord with its own b
COMPS = {"default": COMPENSATION.default, "chord": "tilt,bias,mount"}
#: ``--joint``: also the default with the weight and its joint b stored as fitted in-sample (the bend model
#: whose weight leaves the smaller scatter, no cross-validated choice): the b/w goal's other comparator
JOINT = "joint"
#: (learned on, scored on): every shape as itself, then the arc's weight used on every other shape
CASES = tuple((s, s) for s in SHAPES) + tuple(("arc", s) for s in SHAPES if s != "arc")
PROFILE = "paper+imu"
#: the experiments' move between heading positions (SimConfig default, mm)
MOVE_MM = SimConfig().move_mm


def joint_from_stops(stops: list[Any], headings: Any, groups: Any = None) -> Any:
    """The in-sample joint fit of w and b (the comparator, not the product's choice): of the bend models whose
    weight is shown, the one leaving the marks' smaller residual rms; else the lowest's record."""
    found = [learn_model(stops, headings, groups, m) for m in MODELS]
    shown = [w for w in found if w.applied]
    return min(shown, key=lambda w: w.rms_mm) if shown else found[0]


def _learn(world: World, cfg: SimConfig, calib: dict[str, Any], shape: str, comp: str,
           joint: bool = False) -> dict[str, Any]:
    """The learning experiment over M2 on ``shape``; the calibration the live store_bias would write
    (``stored``), or the unchanged one and the store's refusal (``refused``); ``joint``: the weight learned
    by :func:`joint_from_stops` instead of the product's cross-validated choice."""
    val = Simulation(world, replace(cfg, mark="M2", path_shape=shape)).validation("learn-bias")
    load = image_loader(val, calib["scs"]["gsd_mm"], cfg.size)
    with patch.object(experiment_checks, "learn_from_stops", joint_from_stops if joint
                      else experiment_checks.learn_from_stops):
        res = compute_experiment(experiment_obs(val, calib, comp, world.abs_H_trk, MOVE_MM), load)
    try:
        return {"stored": biased_calibration(calib, res), "refused": None, "verdict": res["verdict"]}
    except ValueError as exc:
        return {"stored": calib, "refused": str(exc), "verdict": res["verdict"]}


def _score(res: dict[str, Any], mark_abs: np.ndarray) -> dict[str, Any]:
    """The case's figures against truth, and what the product said."""
    xy = np.array([m["abs_xyz"][:2] for m in res["marks"]])
    std = np.array([m["std_mm"] for m in res["marks"]])
    err = np.linalg.norm(xy - mark_abs[:2], axis=1)
    met = res["metrics"]
    w = res.get("heading_weight") or {}
    return {"p95_ratio": float(np.percentile(err / std, 95)), "max_ratio": float(np.max(err / std)),
            "enclosing_mm": float(met["enclosing_diameter_mm"]),
            "pairwise_mm": float(met["pairwise_mean_mm"]),
            "abs_rms_mm": float(np.sqrt(np.mean(err ** 2))), "verdict": res["verdict"],
            "messages": list(res.get("messages") or []),
            "own_weight": w.get("weight_fit"), "own_sigma": w.get("sigma"), "own_applied": w.get("applied")}


def run_seed(seed: int, cases: tuple[tuple[str, str], ...] = CASES, repetitions: int = 5,
             envelope: Case | None = None, comps: dict[str, str] = COMPS) -> list[dict[str, Any]]:
    """Every case of one seed (rows as written to the JSON lines file); ``repetitions`` per direction
    (5: the documented flow; fewer only for a quick smoke test); ``envelope``: a world of the accuracy
    envelope (bench/accuracy_envelope.py: its profile and tweak) instead of ``paper+imu``."""
    t0 = time.perf_counter()
    p = profiles.apply(envelope.profile if envelope else PROFILE, WorldParams(seed=seed))
    world = World(p.with_(errors=p.errors.tweaked(envelope.tweak)) if envelope else p)
    cfg = SimConfig(seed=seed, pnp_sigma_px=0.05, report_tilt=world.params.base_has_inclinometer,
                    repetitions=repetitions)
    calib = calibration_record(referencing(Simulation(world, cfg), True))
    learned = {(shape, name): _learn(world, cfg, calib, shape, comp, name == JOINT)
               for shape in sorted({c[0] for c in cases}) for name, comp in comps.items()}
    rows = []
    for learn_shape, shape in cases:
        val = Simulation(world, replace(cfg, path_shape=shape)).validation()
        load = image_loader(val, calib["scs"]["gsd_mm"], cfg.size)
        for name, comp in comps.items():
            lr = learned[(learn_shape, name)]
            res = compute_experiment(experiment_obs(val, lr["stored"], comp, world.abs_H_trk, MOVE_MM), load)
            applied = lr["stored"].get("heading_weight") or {}
            rows.append({"seed": seed, "world": envelope.label if envelope else "", "learned_on": learn_shape,
                         "shape": shape, "comp": name,
                         "store_refused": lr["refused"], "learn_verdict": lr["verdict"],
                         "weight": applied.get("weight"), "weight_fit": applied.get("weight_fit"),
                         "weight_sigma": applied.get("sigma"), **_score(res, val.mark_abs)})
    for r in rows:
        r["seconds_per_seed"] = round(time.perf_counter() - t0, 1)
    return rows


def envelope_worlds() -> tuple[Case, ...]:
    """The envelope's worlds that are not a shape here already (its baseline is the arc, its S the ``s``) and
    not a compensation (its chord case)."""
    from bench.accuracy_envelope import CASES as ENVELOPE

    return tuple(c for c in ENVELOPE[1:] if c.comp.heading_fit and all(t[:2] != ("robot", "path_shape")
                                                                     for t in c.tweak))


def _job(job: tuple[int, int]) -> list[dict[str, Any]]:
    """One seed's cases (``job[1]`` -1), the shapes learned and scored on themselves with the joint fit too
    (-2), or the arc in envelope world ``job[1]``."""
    seed, env = job
    if env == -2:
        return run_seed(seed, tuple((s, s) for s in SHAPES), comps={**COMPS, JOINT: COMPS["default"]})
    return run_seed(seed) if env < 0 else run_seed(seed, (("arc", "arc"),), envelope=envelope_worlds()[env])


def _read(path: str) -> list[dict[str, Any]]:
    """The rows of a JSON lines file (gzipped when its name ends in .gz, as the committed before-run)."""
    with (gzip.open(path, "rt") if path.endswith(".gz") else open(path)) as f:
        return [json.loads(line) for line in f if line.strip()]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=4, help="how many seeds (from --start)")
    ap.add_argument("--start", type=int, default=100, help="the first seed (the envelope's are 100-139)")
    ap.add_argument("--jobs", type=int, default=1, help="processes (2 only on an otherwise idle machine)")
    ap.add_argument("--out", help="append every case's row to this JSON lines file")
    ap.add_argument("--table", help="print the tables of this JSON lines file (no run)")
    ap.add_argument("--envelope", action="store_true",
                    help="the arc in each envelope world instead of the shapes")
    ap.add_argument("--before", help="with --table: the run before a change, for the joint fit's figures")
    ap.add_argument("--joint", action="store_true",
                    help="each shape learned and scored on itself, with the joint fit as a third compensation")
    a = ap.parse_args(argv)
    from bench.shapes_tables import tables

    if a.table:
        before = None if not a.before else _read(a.before)
        print(tables(_read(a.table), before))
        return 0
    envs = range(len(envelope_worlds())) if a.envelope else [-2 if a.joint else -1]
    jobs = [(seed, e) for seed in range(a.start, a.start + a.seeds) for e in envs]
    rows: list[dict[str, Any]] = []
    with ProcessPoolExecutor(max(1, a.jobs)) as pool:
        for seed_rows in pool.map(_job, jobs):
            first = seed_rows[0]
            print(f"seed {first['seed']}: {first['seconds_per_seed']} s", file=sys.stderr, flush=True)
            rows += seed_rows
            if a.out:
                with open(a.out, "a") as f:
                    f.writelines(json.dumps(r) + "\n" for r in seed_rows)
    print(tables(rows, None))
    return 0


if __name__ == "__main__":
    sys.exit(main())
