"""What the installer of a simulated Rita leaves in its data dir: ``sim/plate.json`` (the
plate's *design* file, as its maker delivers it: nominal nest seats, target and survey patches),
``sim/nests.json`` (where the nests roughly stand, in tracker coordinates: a tape measure's
reading) and ``sim/board.json`` (the hand-held intrinsics board, as its maker's file would come).

Nothing here is a measured result: the camera model comes from the guided intrinsics
(``ritactl intrinsics``) and the surveyed seats from ``ritactl plate survey`` on the
photographs of ``sim.survey_images``, as on a real robot. ``ritad --sim`` writes these files at
start so README's "Using it" runs as written: ritad calls :func:`start` by name (config-driven,
``daemon/ritad/registry.py``) with its ``[sim]`` section and data dir. The product never reads
them by itself: the operator passes them (``ritactl fetch sim`` then ``ritactl ... --plate``).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np

from fakes import worlds
from fakes.world import World

FOLDER = "sim"
NEST_ERROR_MM = 3.0  # "roughly here": what an operator reads off a tape measure


def installed_files(world: World) -> dict[str, Any]:
    """``{file name: JSON object}`` of the installer's definition files for this world."""
    trk_H_abs = np.linalg.inv(world.abs_H_trk)
    rng = world.rng("installer.nests")
    nests = {}
    for name, p_abs in world.nests_abs().items():
        rough = p_abs + rng.normal(0.0, NEST_ERROR_MM, 3)
        nests[name] = [round(float(v), 1) for v in trk_H_abs[:3, :3] @ rough + trk_H_abs[:3, 3]]
    from calibration.board import DEFAULT_BOARD  # the board the simulated operator holds (fakes/board.py)

    return {"plate.json": world.plate().to_dict(), "board.json": dict(DEFAULT_BOARD), "nests.json": nests}


def install(world: World, data_dir: Path) -> list[Path]:
    """Write the installer's files into ``data_dir/sim`` (atomically) and return their paths."""
    from daemon.bus.storage import atomic_write_json

    files = installed_files(world)
    return [atomic_write_json(data_dir / FOLDER / name, obj) for name, obj in files.items()]


def start(sim: Mapping[str, Any], data_dir: str) -> tuple[str, World]:
    """ritad's sim factory: a fresh world from ``[sim]``, installer files in ``data_dir``.

    The world is registered under the resolved data dir, which one ritad at a time owns
    (its instance lock), so two ritads in one process (tests) never share a world.
    """
    world = World(worlds.params_from(sim))
    data = Path(data_dir)
    install(world, data)
    return worlds.register(world, str(data.resolve())), world


__all__ = ["FOLDER", "NEST_ERROR_MM", "install", "installed_files", "start"]
