"""Camera benchmarks: render times, SimCamera free-run throughput, GenICam adapter on viky.

Run: ``.venv/bin/python bench/bench_camera.py [--no-full] [--seconds S]``. Prints a
Markdown table and the machine facts. The full-size renderer needs about 1 GB.
"""
from __future__ import annotations

import argparse
import glob
import logging
import os
import sys
import time
from pathlib import Path
from typing import Any, Callable

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import machine  # noqa: E402

from drivers.base import DeviceURL, Frame  # noqa: E402
from drivers.camera_settings import CameraSettings  # noqa: E402
from fakes.camera import SimCamera, renderer_for  # noqa: E402
from fakes.world import World  # noqa: E402
from fakes.worlds import sim_url  # noqa: E402


def timed(fn: Callable[[], Any]) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def bench_render(world: World, label: str, size: tuple[int, int], repeats: int) -> list[tuple[str, str]]:
    """First render including the ray cache, then the mean of ``repeats`` further renders."""
    rng = world.rng("bench.noise")
    holder: dict[str, Any] = {}

    def first() -> None:
        holder["r"] = renderer_for(world, size)
        holder["r"].render(rng=rng)

    t_first = timed(first)
    r = holder["r"]
    t_next = sum(timed(lambda: r.render(rng=rng)) for _ in range(repeats)) / repeats
    w, h = size
    return [(f"render {label} {w}x{h}, first (incl. ray cache)", f"{t_first:.2f} s"),
            (f"render {label} {w}x{h}, next (mean of {repeats})", f"{t_next:.2f} s")]


def rate(cam: Any, frames: list[Frame], seconds: float) -> float:
    """Frames per second that ``pump`` delivers over ``seconds`` of free run."""
    cam.start_stream()
    cam.pump(0.2)  # settle
    frames.clear()
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        cam.pump(0.1)
    fps = len(frames) / (time.perf_counter() - t0)
    cam.stop_stream()
    return fps


def bench_sim_stream(world: World, query: str, label: str, seconds: float) -> tuple[str, str]:
    frames: list[Frame] = []
    cam = SimCamera(sim_url(world, query),
                    emit=lambda topic, f: frames.append(f))
    cam.open()
    try:
        fps = rate(cam, frames, seconds)
    finally:
        cam.close()
    return (f"SimCamera free run, {label}", f"{fps:.0f} frames/s")


def bench_viky(seconds: float) -> tuple[str, str]:
    import genicam

    from drivers.genicam import GenICamCamera

    found = glob.glob(os.path.join(os.path.dirname(genicam.__file__), "**", "viky.cti"), recursive=True)
    if not found:
        return ("GenICam adapter on viky", "viky.cti not found")
    frames: list[Frame] = []
    cam = GenICamCamera(DeviceURL.parse(f"genicam://{found[0]}?serial=0"),
                        emit=lambda topic, f: frames.append(f),
                        settings=CameraSettings(width=800, height=800, frame_rate_hz=200.0))
    cam.open()
    try:
        fps = rate(cam, frames, seconds)
    finally:
        cam.close()
    return ("GenICam adapter free run on viky, 800x800 Mono8 at 200 fps requested",
            f"{fps:.0f} frames/s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--no-full", action="store_true", help="skip the full-size (4024x3036) parts")
    ap.add_argument("--seconds", type=float, default=3.0, help="duration of each throughput run")
    ap.add_argument("--repeats", type=int, default=2, help="renders averaged after the first")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)  # the viky feature warnings are expected here
    world = World()
    rows = bench_render(world, "reduced", tuple(world.params.reduced_size), args.repeats)
    rows.append(bench_sim_stream(world, "size=reduced&prerender=2&fps=10000",
                                 "reduced, prerender=2, fps=10000", args.seconds))
    if not args.no_full:
        rows += bench_render(world, "full", tuple(world.params.full_size), args.repeats)
        rows.append(bench_sim_stream(world, "size=full&prerender=2&fps=10000",
                                     "full 4024x3036, prerender=2, fps=10000", args.seconds))
    rows.append(bench_viky(args.seconds))
    print("| camera benchmark | result |\n|---|---|")
    for name, value in rows:
        print(f"| {name} | {value} |")
    print()
    print(f"- {machine()}")


if __name__ == "__main__":
    main()
