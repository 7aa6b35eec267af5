"""Benchmark of the plate survey on rendered whole-plate photographs, over several world seeds.

Per seed: render ``--views`` photographs (fakes/survey_views.py) of a world whose plate
design has its nests 0.2–0.36 mm off, survey them (calibration.plate_survey.run_survey)
and score the seats against the fake's truth: 3-D error, the largest |error|/σ over
the 9 coordinates, the 3-D 1σ. Goal: every seat ≤ 50 µm from truth and
within 3σ. Prints a Markdown table.

Run: ``.venv/bin/python bench/bench_survey.py [--seeds 2,3,4,5] [--views 8] [--width 2400]``
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import machine  # noqa: E402
from calibration.plate import NEST_NAMES  # noqa: E402
from calibration.plate_survey import run_survey  # noqa: E402
from fakes.survey_views import render_views  # noqa: E402
from fakes.world import World, WorldParams  # noqa: E402

BIAS = ((0.3, -0.2, 0.1), (-0.25, 0.3, 0.0), (0.2, 0.2, -0.15))


def one(seed: int, views: int, width: int) -> tuple[list[float], list[float], list[float], float, float]:
    w = World(WorldParams(seed=seed, nest_definition_bias_mm=BIAS))
    t0 = time.process_time()
    images, _ = render_views(w, views, (width, width * 2 // 3))
    t1 = time.process_time()
    res = run_survey({f"v{k}": im for k, im in enumerate(images)}, w.plate())
    t2 = time.process_time()
    truth = {n: P + [0, 0, w.params.smr_offset_mm] for n, P in w.nests_ref_true().items()}
    err, ratio, sig = [], [], []
    for n in NEST_NAMES:
        d = np.array(res.plate.nests_ref_nst[n]) - truth[n]
        s = np.array(res.plate.nests_sigma_mm[n])
        err.append(float(np.linalg.norm(d)) * 1000)
        ratio.append(float(np.max(np.abs(d) / s)))
        sig.append(float(np.linalg.norm(s)) * 1000)
    return err, ratio, sig, t1 - t0, t2 - t1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="2,3,4,5")
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--width", type=int, default=2400)
    a = ap.parse_args()
    print(f"plate survey, {a.views} photographs at {a.width}x{a.width * 2 // 3}; {machine()}\n")
    print("| seed | error µm (r, g, b) | max abs(err)/σ | 3-D 1σ µm (r, g, b) "
          "| render s CPU | survey s CPU |")
    print("|---|---|---|---|---|---|")
    worst = 0.0
    for seed in (int(s) for s in a.seeds.split(",")):
        err, ratio, sig, tr, ts = one(seed, a.views, a.width)
        worst = max(worst, max(err))
        fmt = ", ".join
        print(f"| {seed} | {fmt(f'{e:.1f}' for e in err)} | {max(ratio):.2f} "
              f"| {fmt(f'{s:.1f}' for s in sig)} | "
              f"{tr:.1f} | {ts:.1f} |", flush=True)
    print(f"\nworst seat error {worst:.1f} µm (goal ≤ 50)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
