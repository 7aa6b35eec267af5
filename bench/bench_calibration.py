"""Benchmark of the calibration core on simulated data.

Times one referencing from a full-size 4024×3036 rendered image (the image is
rendered in a child process, so neither its time nor its memory counts), one mark
measurement, and reports the peak RSS of this process. Then it runs the simulation
protocol rendering-free over several seeds for the nominal and the stress cases of
the realism check (docs/accuracy.md, "Acceptance thresholds": tracker noise alone versus path deviation and
robot tilt) and prints median / p95 of the paper's metrics.

Run: ``.venv/bin/python bench/bench_calibration.py [--seeds N]``
"""
from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import machine  # noqa: E402

from calibration.measure import measure_image, measure_mark  # noqa: E402
from calibration.metrics import experiment_metrics  # noqa: E402
from calibration.referencing import reference, rob_H_cam_error  # noqa: E402
from calibration.scs import make_scs  # noqa: E402
from fakes.simulate import SimConfig, Simulation  # noqa: E402
from fakes.world import World, WorldParams  # noqa: E402

FULL = (4024, 3036)
SEED = 5


def render_child(path: str) -> None:
    """Child process: render the full-size referencing image and the mark image to ``path``."""
    world = World(WorldParams(seed=SEED))
    cfg = SimConfig(seed=SEED, render=True, size=FULL, repetitions=1, directions=1)
    sim = Simulation(world, cfg)
    obs = sim.calibration()
    o = Simulation(world, replace(cfg, render=False)).validation().observations[0]
    mark_img = sim.renderer.render(o.abs_H_rob_true @ world.rob_H_cam, rng=np.random.default_rng(1))
    np.savez(path, calib=obs.image, mark=mark_img, nests=obs.abs_P_nests, P0=obs.abs_P_rob0,
             P1=obs.abs_P_rob1, prev=o.abs_P_prev, at=o.abs_P_at, uv_true=o.uv_true)


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def full_size_timings() -> list[tuple[str, str, str]]:
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "images.npz")
        t0 = time.perf_counter()
        subprocess.run([sys.executable, __file__, "--render-child", path], check=True)
        t_render = time.perf_counter() - t0
        data = dict(np.load(path))
    world = World(WorldParams(seed=SEED))
    sim = Simulation(world, SimConfig(seed=SEED, size=FULL))
    rss0 = rss_mb()
    t0 = time.perf_counter()
    res = reference(sim.model, sim.plate, data["nests"], data["P0"], data["P1"], image=data["calib"])
    t_ref = time.perf_counter() - t0
    from calibration.target import estimate_cam_H_ref

    t0 = time.perf_counter()
    estimate_cam_H_ref(data["calib"], sim.model, sim.plate)
    t_det = time.perf_counter() - t0
    t0 = time.perf_counter()
    scs = make_scs(sim.model, res.cam_H_ref)
    t_scs = time.perf_counter() - t0
    err = rob_H_cam_error(res.rob_H_cam, world.rob_H_cam)
    rows = [("Render 4024×3036 referencing + mark image (child process, excluded)", f"{t_render:.1f} s", "—"),
            ("Referencing from the 4024×3036 image (detect, PnP, SCS, nest fit, MC 200)", f"{t_ref:.2f} s",
             "≤ 2 s"),
            ("  of which ChArUco detection + PnP alone (estimate_cam_H_ref, timed again)",
             f"{t_det:.2f} s", "—"),
            ("  make_scs (timed again)", f"{t_scs * 1000:.0f} ms", "—"),
            ("  rob_H_cam error: t_xy / t_z / rotation",
             f"{err['t_xy_mm'] * 1000:.1f} µm / {err['t_z_mm'] * 1000:.1f} µm / {err['rot_deg']:.4f}°", "—"),
            ("  corners / reprojection RMS / verdict",
             f"{res.n_corners} / {res.rms_px:.3f} px / {res.verdict}", "—")]
    uv = data["uv_true"]
    try:
        import calibration.marks  # noqa: F401

        size_mm = world.params.marks[0].size_mm
        prior = uv + [12.0, -9.0]  # a prior within a few px, e.g. from a coarse pass or the previous stop
        for label, approx in (("whole image", None), ("window around a prior 15 px off", prior)):
            t0 = time.perf_counter()
            m = measure_image(data["mark"], scs, res.rob_H_scn, data["prev"], data["at"], kind="dot",
                              approx_uv=approx, mark_size_mm=size_mm,
                              cov_rob_H_scn=res.uncertainty.cov_rob_H_scn)
            t_mark = time.perf_counter() - t0
            rows.append((f"One mark measurement, 4024×3036, search {label} (locate + ACS + covariance)",
                         f"{t_mark * 1000:.0f} ms", "≤ 0.25 s"))
        rows.append(("  mark localisation error vs truth", f"{np.linalg.norm(m.uv - uv):.3f} px", "—"))
    except ImportError:
        rows.append(("One mark measurement: calibration.marks not available", "—", "≤ 0.25 s"))
    t0 = time.perf_counter()
    for _ in range(20):
        m = measure_mark(uv, scs, res.rob_H_scn, data["prev"], data["at"],
                         cov_rob_H_scn=res.uncertainty.cov_rob_H_scn)
    t_geom = (time.perf_counter() - t0) / 20
    mark = np.array([world.params.marks[0].x_mm, world.params.marks[0].y_mm])
    rows.append(("Mark mapping only (image→ACS + covariance, mean of 20)", f"{t_geom * 1000:.1f} ms", "—"))
    rows.append(("  mark error vs truth / predicted σ",
                 f"{np.linalg.norm(m.abs_P[:2] - mark) * 1000:.1f} µm / {m.std_mm * 1000:.1f} µm", "—"))
    rows.append(("Peak RSS of this process (before referencing → after)", f"{rss0:.0f} → {rss_mb():.0f} MB",
                 "≤ 1 GB"))
    return rows


CASES = {
    "σ_t 10 µm": {},
    "σ_t 10 µm + path 50 µm": {"path_sigma_mm": 0.05},
    "σ_t 10 µm + tilt 0.5 mrad": {"tilt_sigma_mrad": 0.5},
    "σ_t 10 µm + path 50 µm + tilt 0.5 mrad": {"path_sigma_mm": 0.05, "tilt_sigma_mrad": 0.5},
    "… same, tilt reported by the base": {"path_sigma_mm": 0.05, "tilt_sigma_mrad": 0.5, "report_tilt": True},
}


def protocol_stats(seeds: int) -> list[list[str]]:
    out = []
    for name, kw in CASES.items():
        rows = []
        for s in range(seeds):
            world = World(WorldParams(seed=1000 + s))
            sim = Simulation(world, SimConfig(seed=1000 + s, pnp_sigma_px=0.05, **kw))
            obs = sim.calibration()
            res = reference(sim.model, sim.plate, obs.abs_P_nests, obs.abs_P_rob0, obs.abs_P_rob1,
                            cam_ref=obs.cam_ref, mc_samples=0)
            scs = make_scs(sim.model, res.cam_H_ref)
            val = sim.validation()
            pts = np.array([measure_mark(o.uv, scs, res.rob_H_scn, o.abs_P_prev, o.abs_P_at,
                                         roll_deg=o.roll_deg, pitch_deg=o.pitch_deg).abs_P
                            for o in val.observations])
            v = np.array([o.abs_P_at - o.abs_P_prev for o in val.observations])
            m = experiment_metrics(pts, np.degrees(np.arctan2(v[:, 1], v[:, 0])))
            e = rob_H_cam_error(res.rob_H_cam, world.rob_H_cam)
            rows.append([m.pairwise_mean_mm, m.enclosing_diameter_mm,
                         max(c.max_from_mean_mm for c in m.clusters),
                         float(np.linalg.norm(np.array(m.all.mean) - val.mark_abs[:2])), m.fit.b_norm_mm,
                         e["t_xy_mm"], e["rot_deg"]])
        a = np.array(rows)
        med, p95 = np.median(a, axis=0), np.percentile(a, 95, axis=0)
        out.append([name] + [f"{x:.3f}/{y:.3f}" for x, y in zip(med[:-1], p95[:-1])]
                   + [f"{med[-1]:.4f}/{p95[-1]:.4f}"])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20, help="seeds per protocol case (default 20)")
    ap.add_argument("--render-child", metavar="PATH", help=argparse.SUPPRESS)
    ap.add_argument("--skip-full", action="store_true", help="skip the full-size image timings")
    args = ap.parse_args()
    if args.render_child:
        render_child(args.render_child)
        return
    print("# Calibration benchmark\n")
    print(machine() + "\n")
    if not args.skip_full:
        print("| Step | Measured | Goal |\n|---|---:|---:|")
        for r in full_size_timings():
            print(f"| {r[0]} | {r[1]} | {r[2]} |")
        print()
    t0 = time.perf_counter()
    stats = protocol_stats(args.seeds)
    print(f"Simulation protocol, rendering-free (PnP on corners + 0.05 px, marks + 0.05 px), "
          f"8 directions × 5, {args.seeds} seeds, median/p95 in mm ({time.perf_counter() - t0:.1f} s):\n")
    print("| Case | Pairwise mean of cluster means | Enclosing diameter, all | Max dev. in cluster | "
          "Grand-mean error | Fitted abs(b) | rob_H_cam t_xy | rob_H_cam rotation [°] |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for r in stats:
        print("| " + " | ".join(r) + " |")


if __name__ == "__main__":
    main()
