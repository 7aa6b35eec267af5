"""CPU seconds per simulated camera frame (fakes/render.py) for the three kinds of view the closed loops
render: the plate in view (referencing), a floor mark (experiment, measure-mark) and the board an
operator holds under the lens (guided intrinsics); per survey photograph (fakes/survey_views.py); and
the CPU a ``ritad --sim`` process spends until its devices are READY (the camera's ray residuals: computed,
or read from fakes/ray_store.py's folder when an earlier process wrote them).

Run: ``.venv/bin/python bench/bench_render.py [--repeat 3]``; the figure before a change comes from the
same script run against the older tree (``PYTHONPATH=<old checkout>``). Each view is rendered once to
warm the ray cache, then ``--repeat`` times; the median process CPU time (user + sys) is reported.
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import cpu_seconds, machine  # noqa: E402
from fakes.launch import start_ritad  # noqa: E402
from fakes.render import Renderer  # noqa: E402
from fakes.world import World, WorldParams  # noqa: E402


def cpu_per_call(fn, repeat: int) -> float:  # noqa: ANN001 (any zero-argument callable)
    fn()  # warm-up: ray cache, textures
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return statistics.median(times)


def ritad_start_cpu() -> float:
    """CPU seconds of a ``ritad --sim`` process (its own, not the worker's) until every device is READY."""
    with start_ritad(tmp=Path(tempfile.mkdtemp(prefix="bench-render-")), args=["--seed", "3"], timeout=90) as r:
        r.wait_ready(("camera", "tracker", "robot"), timeout=120)
        return cpu_seconds(r.proc.pid)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    world = World(WorldParams(seed=3))
    r = Renderer(world, world.params.reduced_size)
    plate = world.abs_H_rob(world.pose_with_target_in_view(world.plate_yaw_deg + 60.0)) @ world.rob_H_cam
    m = world.params.marks[0]
    mark = world.abs_H_rob(world.pose_with_footprint_at(m.x_mm, m.y_mm, 30.0)) @ world.rob_H_cam
    out = {"plate": cpu_per_call(lambda: r.render(plate), args.repeat),
           "mark": cpu_per_call(lambda: r.render(mark), args.repeat)}
    world.hold_board(z_mm=60.0, tilt_x_deg=12.0)
    out["held board"] = cpu_per_call(lambda: r.render(mark), args.repeat)
    world.hold_board()
    from fakes.survey_views import SurveyRenderer, survey_poses

    s = SurveyRenderer(world, (1800, 1200))
    pose = survey_poses(world, s.model, 1, world.rng("bench"))[0]
    noise = world.rng("bench-noise")
    out["survey photo 1800x1200"] = cpu_per_call(lambda: s.render(pose, noise), args.repeat)
    out["ritad --sim start to devices READY"] = statistics.median(ritad_start_cpu() for _ in range(3))
    print(machine())
    w, h = world.params.reduced_size
    for name, sec in out.items():
        if "ritad" in name:
            print(f"{name}: {sec:.2f} s CPU (median of 3)")
            continue
        size = "" if "survey" in name else f" {w}x{h}, supersampling {world.params.supersampling}"
        print(f"{name}{size}: {sec:.3f} s CPU per frame")


if __name__ == "__main__":
    main()
