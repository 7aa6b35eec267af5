"""Benchmark of the guided intrinsics against its acceptance line, on rendered recipe views.

For each case (image size, the lens's k3, seed) it renders the 12 recipe views as the
simulated operator holds them (fakes/board.py), calibrates with no initial guess and
scores against the world's true model (scoring only): |Δf|/f, the principal point error
scaled to the full 4024-px width, each parameter's error in units of its reported σ, and
the k3 decision. Goals: |Δf|/f ≤ 0.1 %, principal point ≤ 1.5 px at full size, every
|error| ≤ 3σ.

Run: ``.venv/bin/python bench/bench_intrinsics.py [--size full|reduced|WxH] [--k3 K] [--seeds N]``
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import machine  # noqa: E402

from calibration.board import DEFAULT_BOARD, Board  # noqa: E402
from calibration.intrinsics import PARAM_NAMES, calibrate_intrinsics  # noqa: E402
from fakes.board import recipe_images  # noqa: E402
from fakes.render import Renderer, world_camera_model  # noqa: E402
from fakes.world import World, WorldParams  # noqa: E402


def one_case(size: tuple[int, int], k3: float, seed: int) -> dict:
    p = WorldParams(seed=seed)
    world = World(p.with_(distortion=p.distortion[:4] + (k3,)))
    t0 = time.perf_counter()
    images = recipe_images(world, Renderer(world, size), np.random.default_rng(seed),
                           np.random.default_rng(seed + 1000))
    t1 = time.perf_counter()
    model, report = calibrate_intrinsics(images, Board.from_dict(DEFAULT_BOARD), size)
    t2 = time.perf_counter()
    true = world_camera_model(world, size)  # scoring only
    err = np.r_[model.K[0, 0] - true.K[0, 0], model.K[1, 1] - true.K[1, 1], model.K[0, 2] - true.K[0, 2],
                model.K[1, 2] - true.K[1, 2], model.dist - true.dist]
    z = {n: (e / report["std"][n] if report["std"][n] else 0.0) for n, e in zip(PARAM_NAMES, err)}
    return {"df_pct": 100 * abs(model.f - true.f) / true.f,
            "pp_full_px": float(np.hypot(err[2], err[3]) * p.full_size[0] / size[0]),
            "max_z": max(abs(v) for v in z.values()), "worst": max(z, key=lambda n: abs(z[n])),
            "k3_fitted": report["k3"]["fitted"], "F": report["k3"]["F"], "rms_px": report["rms_px"],
            "verdict_findings": report["findings"] + report["warnings"],
            "render_s": t1 - t0, "calib_s": t2 - t1}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="full", help="full, reduced or WxH (default full)")
    ap.add_argument("--k3", type=float, action="append",
                    help="true k3 of the lens (repeatable; default 0 and -0.01)")
    ap.add_argument("--seeds", type=int, default=1, help="seeds per k3 (default 1)")
    a = ap.parse_args()
    p = WorldParams()
    size = {"full": p.full_size, "reduced": p.reduced_size}.get(a.size) or tuple(map(int, a.size.split("x")))
    print(f"# intrinsics at {size[0]}x{size[1]}; {machine()}")
    print("| k3 | seed | |Δf|/f % | pp @full px | max |err|/σ (param) | k3 fitted (F) | rms px | findings | "
          "render s | calib s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for k3 in a.k3 or [0.0, -0.01]:
        for seed in range(1, a.seeds + 1):
            r = one_case(size, k3, seed)
            print(f"| {k3:g} | {seed} | {r['df_pct']:.4f} | {r['pp_full_px']:.2f} "
                  f"| {r['max_z']:.2f} ({r['worst']}) "
                  f"| {r['k3_fitted']} ({r['F']:.1f}) | {r['rms_px']:.3f} | {len(r['verdict_findings'])} | "
                  f"{r['render_s']:.0f} | {r['calib_s']:.1f} |", flush=True)


if __name__ == "__main__":
    main()
