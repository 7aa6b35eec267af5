"""Benchmark of the vision half of the calibration core and the image renderer.

Each stage group runs in its own child process so its peak RSS is its own:

* render: ray cache and one render at the reduced (1000×750) and full (4024×3036)
  sizes, and the corner accuracy of the rendered image against the true projections;
* pose: ``estimate_cam_H_ref`` (detection + IPPE + LM) on the full-size image, with
  this project's marker identification and with OpenCV's, plus ``make_scs`` and
  locating a dot mark; the console's live detection (``camera.detect``: the newest frame
  area-reduced to the search width the operator picked, then the corners) at each width;
* marks: whole-image search (no prior) for a dot and a cross at 4024×3036, coarse to
  fine and at full resolution, median and p95 over several mark placements, and how
  far apart the two results are.

Run: ``.venv/bin/python bench/bench_vision.py [--repeats N] [--mark-repeats N]``
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

from bench.common import machine, pct  # noqa: E402


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


#: the search widths the console offers for camera.detect (daemon/console/static/index.html; 0: full)
LIVE_WIDTHS = (640, 1000, 2000, 0)


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
    t_ocv, _ = _timed(lambda: pose_from_corners(*detect_corners(img, plate, fast=False), model, plate),
                      repeats)
    t_scs, scs = _timed(lambda: make_scs(model, pose.cam_H_ref), repeats)
    from daemon.ritad.detect import _downscaled

    live = {w: _timed(lambda: detect_corners(_downscaled(img, w)[0], plate), repeats) for w in LIVE_WIDTHS}
    # a synthetic dot in the middle of the image, for the locator's timing only
    dot = np.full((size[1], size[0]), 180, np.uint8)
    c = np.array(size) / 2 + 0.3
    r_px = 0.4 / scs.gsd_mm
    x0, y0 = int(c[0]) - 100, int(c[1]) - 100
    yy, xx = np.mgrid[y0:y0 + 200, x0:x0 + 200]
    dot[y0:y0 + 200, x0:x0 + 200][(xx - c[0]) ** 2 + (yy - c[1]) ** 2 < r_px ** 2] = 30
    t_dot, _ = _timed(lambda: locate_mark(dot, "dot", approx_uv=c + 2, size_px=r_px), repeats)
    from calibration.frames import inv_H, rotation_angle

    true = inv_H(world.abs_H_cam()) @ world.abs_H_ref

    def foot(cam_H_ref: np.ndarray) -> np.ndarray:
        ref_H_cam = inv_H(cam_H_ref)
        C, d = ref_H_cam[:3, 3], ref_H_cam[:3, 2]
        return (C - C[2] / d[2] * d)[:2]

    q.put({"fast": t_fast, "opencv": t_ocv, "scs": t_scs, "dot": t_dot, "rss": _rss_mb(),
           "live": {w: (t, len(ids)) for w, (t, (ids, _)) in live.items()},
           "n": pose.n_corners, "ratio": pose.ambiguity_ratio,
           "rot": float(np.degrees(rotation_angle(pose.cam_H_ref[:3, :3].T @ true[:3, :3]))),
           "foot": float(np.linalg.norm(foot(pose.cam_H_ref) - foot(true))) * 1000})


def marks_group(size: tuple[int, int], repeats: int, q: mp.Queue) -> None:
    """Child: whole-image mark search, coarse to fine vs full resolution, on rendered marks."""
    from calibration.frames import apply_H, inv_H
    from calibration.marks import locate_mark
    from fakes.render import Renderer, world_camera_model
    from fakes.world import World

    world = World()
    renderer = Renderer(world, size)
    model = world_camera_model(world, size)
    rng = np.random.default_rng(12)
    out: dict[str, Any] = {}
    for mark in world.params.marks:
        times: dict[bool, list[float]] = {True: [], False: []}
        diffs, errs = [], []
        placed = 0
        while placed < 3:  # three random placements of the mark that keep it well inside the image
            off = rng.uniform([-28.0, -20.0], [28.0, 20.0])
            world.set_robot(world.pose_with_footprint_at(mark.x_mm + off[0], mark.y_mm + off[1],
                                                         float(rng.uniform(-180, 180))))
            truth = model.project(apply_H(inv_H(world.abs_H_cam()), [mark.x_mm, mark.y_mm, 0.0])[None])[0]
            size_px = mark.size_mm * model.f / world.abs_H_cam()[2, 3]
            if not (4 * size_px < truth[0] < size[0] - 4 * size_px
                    and 4 * size_px < truth[1] < size[1] - 4 * size_px):
                continue
            placed += 1
            img = renderer.render(rng=rng)
            uv = {}
            for c2f in (True, False):
                for _ in range(repeats if c2f else max(1, repeats // 4)):
                    t = time.perf_counter()
                    uv[c2f] = locate_mark(img, mark.kind, size_px=size_px, coarse_to_fine=c2f).uv
                    times[c2f].append(time.perf_counter() - t)
            diffs.append(float(np.linalg.norm(uv[True] - uv[False])))
            errs.append(float(np.linalg.norm(uv[True] - truth)))
        out[mark.kind] = {"c2f": times[True], "full": times[False], "diff": max(diffs), "err": max(errs),
                          "size_px": size_px}
    out["rss"] = _rss_mb()
    q.put(out)


def _run(target: Any, *args: Any) -> dict[str, Any]:
    """Run ``target`` in a spawned child and return what it reports."""
    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    p = ctx.Process(target=target, args=(*args, q))
    p.start()
    out = q.get(timeout=900)
    p.join(timeout=60)
    return out


def _render_and_pose_rows(repeats: int) -> list[tuple[str, str, str]]:
    """The render and pose groups (the full-size render is shared through a temp file)."""
    from fakes.world import WorldParams

    p = WorldParams()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        full_img = str(Path(tmp) / "full.npy")
        for size, save in ((p.reduced_size, None), (p.full_size, full_img)):
            r = _run(render_group, size, repeats if save is None else 1, save)
            label = f"{size[0]}×{size[1]}, SS={p.supersampling}"
            rows += [(f"ray cache ({label})", f"{r['cache']:.2f} s", ""),
                     (f"render ({label})", f"{r['render']:.2f} s", f"peak RSS {r['rss']:.0f} MB"),
                     (f"corner accuracy vs truth ({size[0]}×{size[1]})", f"{r['rms']:.4f} px RMS",
                      f"{r['n']} corners, max abs bias {r['bias']:.4f} px")]
        r = _run(pose_group, full_img, p.full_size, repeats)
        rows += [("estimate_cam_H_ref 4024×3036 (detection + IPPE + LM)", f"{r['fast']:.2f} s",
                  f"{r['n']} corners, ambiguity {r['ratio']:.0f}, peak RSS {r['rss']:.0f} MB"),
                 ("  same with OpenCV's marker identification", f"{r['opencv']:.2f} s", ""),
                 ("  cam_H_ref vs truth 4024×3036", f"{r['rot']:.5f}°",
                  f"footprint error {r['foot']:.2f} µm"),
                 *[(f"live detection (camera.detect), search width {w or 'full'}", f"{t:.2f} s",
                    f"{n} corners") for w, (t, n) in r["live"].items()],
                 ("make_scs", f"{r['scs'] * 1000:.1f} ms", ""),
                 ("locate_mark dot 4024×3036", f"{r['dot'] * 1000:.1f} ms", "")]
    return rows


def main() -> None:
    """Run the stage groups and print the Markdown table and the machine facts."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--mark-repeats", type=int, default=20, help="timed searches per mark placement")
    ap.add_argument("--marks-only", action="store_true", help="run only the mark search group")
    args = ap.parse_args()
    from fakes.world import WorldParams

    rows = [] if args.marks_only else _render_and_pose_rows(args.repeats)
    r = _run(marks_group, WorldParams().full_size, args.mark_repeats)
    for kind in ("dot", "cross"):
        m = r[kind]
        ms = {k: (statistics.median(m[k]) * 1000, pct(m[k], 95) * 1000) for k in ("c2f", "full")}
        rows += [(f"whole-image {kind} search 4024×3036, coarse to fine (n={len(m['c2f'])})",
                  f"{ms['c2f'][0]:.1f} ms",
                  f"p95 {ms['c2f'][1]:.1f} ms; goal ≤ 60 ms; mark {m['size_px']:.0f} px"),
                 (f"  same at full resolution (n={len(m['full'])})", f"{ms['full'][0]:.1f} ms",
                  f"p95 {ms['full'][1]:.1f} ms"),
                 (f"  coarse to fine vs full resolution, {kind}", f"{m['diff']:.4f} px max",
                  f"vs truth {m['err']:.3f} px max (3 placements)")]
    print("| Stage | Time (median) | Notes |\n|---|---|---|")
    for row in rows:
        print(f"| {' | '.join(row)} |")
    print(f"\nMachine: {machine()}")


if __name__ == "__main__":
    main()
