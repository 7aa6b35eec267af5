"""The simulated operator's eye and hands, for the demo and the tests.

A real operator points the tracker's beam at the robot's reflector by eye (or guides it
there by hand) before the tracker can find and lock onto it. The simulated operator
does the same from the world: it reads where the reflector is (``sim.truth``, the only
place the world is visible from outside ritad) and points the beam a few millimetres
off, as a hand would. The product then has to find, lock and measure the reflector
itself; nothing read here reaches a calculation of the product.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

HAND_ERROR_MM = (3.0, -2.0, 1.0)  # where the operator's pointing lands, off the reflector


def lock_on_robot(c: Any) -> dict[str, Any]:
    """Point the tracker near the robot's reflector, find it, and return one measurement."""
    world = c.call("sim.truth")  # the operator's eye: where the robot stands
    abs_H_trk = np.array(world["abs_H_trk"])
    p_abs = np.array(world["abs_H_rob"])[:3, 3] + HAND_ERROR_MM
    p_trk = np.linalg.inv(abs_H_trk) @ [*p_abs, 1.0]
    c.call("tracker.aim", timeout=60, x=float(p_trk[0]), y=float(p_trk[1]), z=float(p_trk[2]))
    c.call("tracker.find", timeout=60)
    return c.call("tracker.measure", timeout=60)




MARK_READING_ERROR_MM = (1.5, -1.0)  # the operator's reading of a mark's position off the floor drawing


def rough_mark(c: Any, index: int = 0) -> tuple[str, list[float]]:
    """A floor mark's name and the rough ACS x, y the operator gives the experiment (1.8 mm off)."""
    mark = c.call("sim.truth")["marks"][index]  # the operator's eye on the floor drawing
    return mark["name"], [mark["x_mm"] + MARK_READING_ERROR_MM[0], mark["y_mm"] + MARK_READING_ERROR_MM[1]]


def main(argv: list[str] | None = None) -> int:
    """``python -m fakes.operator intrinsics``: run ``ritactl intrinsics``' job with the simulated
    operator holding the board as each prompt asks (README's "Using it" on ``ritad --sim``)."""
    from daemon.bus.client import Client
    from fakes.board import run_intrinsics

    ap = argparse.ArgumentParser(prog="python -m fakes.operator", description=main.__doc__)
    ap.add_argument("task", choices=["intrinsics"])
    ap.add_argument("--endpoint", default=os.environ.get("RITA_ENDPOINT"), help="default: $RITA_ENDPOINT")
    ap.add_argument("--board", default="sim/board.json", help="the board file (ritactl fetch sim)")
    ap.add_argument("--seed", type=int, default=1, help="how the operator's hands scatter")
    a = ap.parse_args(argv)
    if not a.endpoint:
        ap.error("no endpoint: give --endpoint or set RITA_ENDPOINT")
    try:
        board = json.loads(Path(a.board).read_text())
    except (OSError, ValueError) as exc:
        print(f"fakes.operator: cannot read the board file {a.board}: {exc}", file=sys.stderr)
        return 5
    with Client(a.endpoint, timeout=10) as c:
        r = run_intrinsics(c, {"board": board}, seed=a.seed, timeout=600)
    if r.get("failed"):
        print(f"intrinsics failed: {r.get('error')}", file=sys.stderr)
        return 2
    print(f"intrinsics verdict={r['verdict']} "
          f"({len(r['_prompts'])} prompts answered by the simulated operator)")
    for m in r.get("messages", []):
        print(f"  - {m}")
    return {"ok": 0, "warn": 1}.get(r["verdict"], 2)


__all__ = ["HAND_ERROR_MM", "MARK_READING_ERROR_MM", "lock_on_robot", "main", "rough_mark"]


if __name__ == "__main__":
    sys.exit(main())
