"""What the installer of a simulated Rita leaves in its data dir: ``sim/plate.json``,
``sim/camera_model.json``, ``sim/nests.json`` and ``sim/board.json`` (the hand-held
intrinsics board, as its maker's file would come).

On a real robot these come from the plate's survey, the camera's intrinsic
calibration and a rough look at where the nests stand; issue #14 will produce them
with the product's own procedures. Until then the simulated world, which defines
the plate and the camera, plays the installer: ``ritad --sim`` writes them at start
so README's "Using it" runs as written: ritad calls :func:`start` by name (config-driven,
``daemon/ritad/registry.py``) with its ``[sim]`` section and data dir. The product never reads them by itself: the
operator passes them (``ritactl fetch sim`` then ``ritactl calibrate --plate ...``).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from drivers.base import DeviceURL
from fakes.camera import parse_size
from fakes import worlds
from fakes.world import World

FOLDER = "sim"
NEST_ERROR_MM = 3.0  # "roughly here": what an operator reads off a tape measure


def camera_size(world: World, camera_url: str) -> tuple[int, int]:
    """The image size of the configured camera (a simulated one's ``size`` option; else reduced)."""
    url = DeviceURL.parse(camera_url)
    return parse_size(url, world) if url.scheme == "sim" else tuple(world.params.reduced_size)  # type: ignore


def installed_files(world: World, size: tuple[int, int]) -> dict[str, Any]:
    """``{file name: JSON object}`` of the installer's definition files for this world."""
    trk_H_abs = np.linalg.inv(world.abs_H_trk)
    rng = world.rng("installer.nests")
    nests = {}
    for name, p_abs in world.nests_abs().items():
        rough = p_abs + rng.normal(0.0, NEST_ERROR_MM, 3)
        nests[name] = [round(float(v), 1) for v in trk_H_abs[:3, :3] @ rough + trk_H_abs[:3, 3]]
    from calibration.board import DEFAULT_BOARD  # the board the simulated operator holds (fakes/board.py)

    return {"plate.json": world.plate().to_dict(), "board.json": dict(DEFAULT_BOARD),
            "camera_model.json": {"K": world.camera_matrix(size).tolist(), "dist": world.dist_coeffs().tolist(),
                                  "size": list(size)},
            "nests.json": nests}


def install(world: World, data_dir: Path, camera_url: str) -> list[Path]:
    """Write the installer's files into ``data_dir/sim`` (atomically) and return their paths."""
    from daemon.bus.storage import atomic_write_json

    files = installed_files(world, camera_size(world, camera_url))
    return [atomic_write_json(data_dir / FOLDER / name, obj) for name, obj in files.items()]


def start(sim: Mapping[str, Any], data_dir: str, camera_url: str) -> tuple[str, World]:
    """ritad's sim factory: a fresh world from ``[sim]``, installer files in ``data_dir``.

    The world is registered under the resolved data dir, which one ritad at a time owns
    (its instance lock), so two ritads in one process (tests) never share a world.
    """
    world = World(worlds.params_from(sim))
    data = Path(data_dir)
    install(world, data, camera_url)
    return worlds.register(world, str(data.resolve())), world


__all__ = ["FOLDER", "NEST_ERROR_MM", "camera_size", "install", "installed_files", "start"]
