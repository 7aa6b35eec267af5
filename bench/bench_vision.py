"""Benchmark of the vision half of the calibration core and the image renderer.

Each stage group runs in its own child process so its peak RSS is its own:

* render: ray cache and one render at the reduced (1000×750) and full (4024×3036)
  sizes, and the corner accuracy of the rendered image against the true projections;
* pose: ``estimate_cam_H_ref`` (detection + IPPE + LM) on the full-size image, with
  this project's marker identification and with OpenCV's, plus ``make_scs`` and
  locating a dot mark.

Run: ``.venv/bin/python bench/bench_vision.py [--repeats N]``
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import machine  # noqa: E402


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _timed(fn: Any, repeats: int) -> tuple[float, Any]:
    """Median wall time of ``fn`` over ``repeats`` calls, and its last result."""
    times, out = [], None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def render_group(size: tuple[int, int], repeats: int, save: str | None, q: mp.Queue) -> None:
    """Child: ray cache, render and corner accuracy at ``size``; optionally save the image."""
    from calibration.target import detect_corners
    from fakes.render import Renderer, true_corner_projections
    from fakes.world import World

    world = World()
    t = time.perf_counter()
    r = Renderer(world, size)
    t_cache = time.perf_counter() - t
    t_render, img = _timed(lambda: r.render(rng=np.random.default_rng(0)), repeats)
    ids, uv = detect_corners(img, world.plate())
    tids, tuv = true_corner_projections(world, size)
    truth = dict(zip(tids.tolist(), tuv))
    d = uv - np.array([truth[int(i)] for i in ids])
    if save:
        np.save(save, img)
    q.put({"cache": t_cache, "render": t_render, "rss": _rss_mb(), "n": len(ids),
           "rms": float(np.sqrt(np.mean(np.sum(d ** 2, axis=1)))), "bias": np.abs(d.mean(axis=0)).max()})


def pose_group(path: str, size: tuple[int, int], repeats: int, q: mp.Queue) -> None:
    """Child: cam_H_ref, SCS and mark timings on the saved full-size image."""
    from calibration.marks import locate_mark
    from calibration.scs import make_scs
    from calibration.target import detect_corners, estimate_cam_H_ref, pose_from_corners
    from fakes.render import world_camera_model
    from fakes.world import World

    world = World()
    img = np.load(path)
    model = world_camera_model(world, size)
    plate = world.plate()
    estimate_cam_H_ref(img, model, plate)  # warm the board/detector caches
    t_fast, pose = _timed(lambda: estimate_cam_H_ref(img, model, plate), repeats)
    t_ocv, _ = _timed(lambda: pose_from_corners(*detect_corners(img, plate, fast=False), model, plate), repeats)
    t_scs, scs = _timed(lambda: make_scs(model, pose.cam_H_ref), repeats)
    # a synthetic dot in the middle of the image, for the locator's timing only
    dot = np.full((size[1], size[0]), 180, np.uint8)
    c = np.array(size) / 2 + 0.3
    r_px = 0.4 / scs.gsd_mm
    x0, y0 = int(c[0]) - 100, int(c[1]) - 100
    yy, xx = np.mgrid[y0:y0 + 200, x0:x0 + 200]
    dot[y0:y0 + 200, x0:x0 + 200][(xx - c[0]) ** 2 + (yy - c[1]) ** 2 < r_px ** 2] = 30
    t_dot, _ = _timed(lambda: locate_mark(dot, "dot", approx_uv=c + 2, size_px=r_px), repeats)
    from calibration.frames import inv_H, rotation_error_deg

    true = inv_H(world.abs_H_cam()) @ world.abs_H_ref

    def foot(cam_H_ref: np.ndarray) -> np.ndarray:
        ref_H_cam = inv_H(cam_H_ref)
        C, d = ref_H_cam[:3, 3], ref_H_cam[:3, 2]
        return (C - C[2] / d[2] * d)[:2]

    q.put({"fast": t_fast, "opencv": t_ocv, "scs": t_scs, "dot": t_dot, "rss": _rss_mb(),
           "n": pose.n_corners, "ratio": pose.ambiguity_ratio,
           "rot": rotation_error_deg(pose.cam_H_ref[:3, :3], true[:3, :3]),
           "foot": float(np.linalg.norm(foot(pose.cam_H_ref) - foot(true))) * 1000})


def _run(target: Any, *args: Any) -> dict[str, Any]:
    """Run ``target`` in a spawned child and return what it reports."""
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    p = ctx.Process(target=target, args=(*args, q))
    p.start()
    out = q.get(timeout=900)
    p.join(timeout=60)
    return out


def main() -> None:
    """Run the stage groups and print the Markdown table and the machine facts."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    from fakes.world import WorldParams

    p = WorldParams()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        full_img = str(Path(tmp) / "full.npy")
        for size, save in ((p.reduced_size, None), (p.full_size, full_img)):
            r = _run(render_group, size, args.repeats if save is None else 1, save)
            label = f"{size[0]}×{size[1]}, SS={p.supersampling}"
            rows += [(f"ray cache ({label})", f"{r['cache']:.2f} s", ""),
                     (f"render ({label})", f"{r['render']:.2f} s", f"peak RSS {r['rss']:.0f} MB"),
                     (f"corner accuracy vs truth ({size[0]}×{size[1]})", f"{r['rms']:.4f} px RMS",
                      f"{r['n']} corners, max abs bias {r['bias']:.4f} px")]
        r = _run(pose_group, full_img, p.full_size, args.repeats)
        rows += [("estimate_cam_H_ref 4024×3036 (detection + IPPE + LM)", f"{r['fast']:.2f} s",
                  f"{r['n']} corners, ambiguity {r['ratio']:.0f}, peak RSS {r['rss']:.0f} MB"),
                 ("  same with OpenCV's marker identification", f"{r['opencv']:.2f} s", ""),
                 ("  cam_H_ref vs truth 4024×3036", f"{r['rot']:.5f}°", f"footprint error {r['foot']:.2f} µm"),
                 ("make_scs", f"{r['scs'] * 1000:.1f} ms", ""),
                 ("locate_mark dot 4024×3036", f"{r['dot'] * 1000:.1f} ms", "")]
    print("| Stage | Time (median) | Notes |\n|---|---|---|")
    for row in rows:
        print(f"| {' | '.join(row)} |")
    print(f"\nMachine: {machine()}")


if __name__ == "__main__":
    main()
