"""The simulated operator's eye and hands, for the demo and the tests.

A real operator points the tracker's beam at the robot's reflector by eye (or guides it
there by hand) before the tracker can find and lock onto it. The simulated operator
does the same from the world: it reads where the reflector is (``sim.truth``, the only
place the world is visible from outside ritad) and points the beam a few millimetres
off, as a hand would. The product then has to find, lock and measure the reflector
itself; nothing read here reaches a calculation of the product.
"""
from __future__ import annotations

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


__all__ = ["HAND_ERROR_MM", "lock_on_robot"]
