"""Shared helpers for the benchmark scripts: machine facts, percentiles, a full-size referencing
dataset folder; ritad via fakes/launch.py."""
from __future__ import annotations

import os
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fakes.launch import RitadProcess, start_ritad  # noqa: E402  (the shared "ritad up" helper)


def machine() -> str:
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, "
            f"{platform.system()} {platform.release()}, {time.strftime('%Y-%m-%d', time.gmtime())}")


def pct(values: list[float], q: float) -> float:
    v = sorted(values)
    return v[min(len(v) - 1, int(round(q / 100 * (len(v) - 1))))] if v else float("nan")


#: the camera's full image size (width, height)
FULL = (4024, 3036)


def write_referencing_folder(root: Path, size: tuple[int, int] = FULL, seed: int = 5) -> None:
    """A referencing dataset as the worker writes it, from one simulated visit with a rendered image."""
    import json

    import cv2

    from fakes.simulate import SimConfig, Simulation
    from fakes.world import World, WorldParams

    world = World(WorldParams(seed=seed))
    sim = Simulation(world, SimConfig(seed=seed, render=True, size=size, repetitions=1, directions=1))
    obs = sim.calibration()
    root.mkdir(parents=True)
    cv2.imwrite(str(root / "run0.png"), obs.image)

    def point(p) -> dict:
        return {"abs_xyz": [float(v) for v in p]}
    header = {"shape": [size[1], size[0]], "dtype": "|u1"}
    state = {"schema": 1, "job": "bench", "procedure": "referencing",
             "obs": {"plate": world.plate().to_dict(), "camera_model": sim.model.to_dict(), "sigma_t_mm": 0.010,
                     "nests": {n: point(p) for n, p in zip(("red", "green", "blue"), obs.abs_P_nests)},
                     "runs": [{"tag": "run0", "image": "run0.png", "header": header,
                               "P0": point(obs.abs_P_rob0), "P1": point(obs.abs_P_rob1)}]}}
    (root / "state.json").write_text(json.dumps(state))
    (root / "run0.json").write_text(json.dumps({"camera": header, "image_file": "run0.png"}))
    (root / "dataset.json").write_text(json.dumps({"schema": 1, "kind": "procedure:referencing", "meta": {},
                                                   "entries": [{"name": "run0", "json": "run0.json",
                                                                "image": "run0.png"}]}))


__all__ = ["FULL", "ROOT", "RitadProcess", "machine", "pct", "start_ritad", "write_referencing_folder"]
