"""Sanity check of the simulated error profiles against the paper (issue #15, not a tuning loop).

Runs today's product (no compensation) through the rendering-free simulation protocol
(fakes/simulate.py: calibration on the plate, 8 directions × 5 over mark M1, PnP on
projected corners + 0.05 px, marks + 0.05 px) on worlds of one profile, optionally with
error groups switched off, and prints the paper's metrics (median / p95 over seeds)
next to the paper's glass-plate figures. docs/accuracy.md records its output.

Run: ``.venv/bin/python bench/profile_sanity.py [--profile paper] [--seeds 10] [--off floor robot]
[--budget]`` (``--budget``: one row per error group switched off).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from calibration.measure import measure_mark  # noqa: E402
from calibration.metrics import experiment_metrics  # noqa: E402
from calibration.referencing import reference, rob_H_cam_error  # noqa: E402
from calibration.scs import make_scs  # noqa: E402
from fakes import profiles  # noqa: E402
from fakes.errors import GROUPS  # noqa: E402
from fakes.simulate import SimConfig, Simulation  # noqa: E402
from fakes.world import World, WorldParams  # noqa: E402

#: the paper's glass-plate experiment (Table "target_direction_metrics")
PAPER = {"enclosing": 0.747, "pairwise": 0.215}
COLUMNS = ("enclosing diameter", "pairwise cluster means", "max dev. in cluster", "abs. error RMS",
           "rob_H_cam t_xy")


def run(profile: str, seed: int, off: tuple[str, ...] = ()) -> list[float]:
    """One calibration + 8×5 validation; the metrics of COLUMNS in mm (the last two against truth)."""
    p = profiles.apply(profile, WorldParams(seed=seed))
    world = World(p.with_(errors=p.errors.without(*off)))
    sim = Simulation(world, SimConfig(seed=seed, pnp_sigma_px=0.05))
    obs = sim.calibration()
    res = reference(sim.model, sim.plate, obs.abs_P_nests, obs.abs_P_rob0, obs.abs_P_rob1, cam_ref=obs.cam_ref,
                    mc_samples=0)
    scs = make_scs(sim.model, res.cam_H_ref)
    val = sim.validation()
    pts = np.array([measure_mark(o.uv, scs, res.rob_H_scn, o.abs_P_prev, o.abs_P_at).abs_P
                    for o in val.observations])
    v = np.array([o.abs_P_at - o.abs_P_prev for o in val.observations])
    m = experiment_metrics(pts, np.degrees(np.arctan2(v[:, 1], v[:, 0])))
    err = np.linalg.norm(pts[:, :2] - val.mark_abs[:2], axis=1)
    return [m.enclosing_diameter_mm, m.pairwise_mean_mm, max(c.max_from_mean_mm for c in m.clusters),
            float(np.sqrt(np.mean(err ** 2))), rob_H_cam_error(res.rob_H_cam, world.rob_H_cam)["t_xy_mm"]]


def row(label: str, profile: str, seeds: int, off: tuple[str, ...]) -> str:
    a = np.array([run(profile, 100 + s, off) for s in range(seeds)])
    med, p95 = np.median(a, axis=0), np.percentile(a, 95, axis=0)
    return f"| {label} | " + " | ".join(f"{x:.3f} / {y:.3f}" for x, y in zip(med, p95)) + " |"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--profile", default="paper", choices=list(profiles.PROFILES))
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--off", nargs="*", default=[], choices=GROUPS, help="error groups to switch off")
    ap.add_argument("--budget", action="store_true", help="also one row per error group switched off")
    args = ap.parse_args()
    t0 = time.perf_counter()
    print(f"Profile {args.profile}, no compensation, 8 directions × 5, {args.seeds} seeds (100…), "
          f"median / p95 in mm; the paper: enclosing {PAPER['enclosing']}, pairwise {PAPER['pairwise']}\n")
    print("| Case | " + " | ".join(COLUMNS) + " |\n|---|" + "---:|" * len(COLUMNS))
    print(row(args.profile + "".join(f" −{g}" for g in args.off), args.profile, args.seeds, tuple(args.off)))
    if args.budget:
        for g in GROUPS:
            if getattr(profiles.apply(args.profile, WorldParams()).errors, g) is not None:
                print(row(f"… without {g}", args.profile, args.seeds, (*args.off, g)))
    print(f"\n({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
