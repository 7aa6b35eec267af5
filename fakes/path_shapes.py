"""The shapes a simulated move's path deviation takes (fakes/errors.py ``RobotErrors.path_shape``).

Every shape is a heading θ(f) along the move (f the fraction travelled, θ from the start
heading, small angles) and the sideways offset it builds, y(f) = d·∫θ. Its size comes from
one curvature κ drawn per move, σ_κ = 2·σ_lat / d_ref² (fakes/effects.py ``Effects.bend``):
the one arc of the source's 50 µm lateral path deviation over the 0.2 m between the heading
positions (calibration.md §4.4; §7.1's stress option σ_path 50 µm). The source fixes that arc
by two figures, its sideways offset at the end (κd²/2) and, equivalently, its turn (κd, with the
chord κd/2 off the final heading: the 250 µrad of §4.4). Another shape is scaled by that κ so
that **neither** figure exceeds the arc's: the smaller of "the same end offset" and "the same
turn". No shape bends more than the source allows in either reading, and none is tuned to a result.

* ``arc``: one arc (the default world).
* ``s``: left then right, curvature ±2κ over the halves: the same end offset, the heading back
  where it started (turn 0).
* ``early``, ``late``: the arc's curvature concentrated in the first or last :data:`PART` of the
  move, straight elsewhere. ``early`` at the arc's end offset turns 1/(2 − a) = 0.59 of the arc's
  turn; ``late`` at the arc's turn ends a = 0.3 of its offset to the side, and its final heading is
  κd·(1 − a/2) off the chord: 1.7× the arc's κd/2.
* ``kink``: straight, one heading step θ₀ at a random point f₀ ~ U(0, 1), straight again; ``kink-end``:
  f₀ ~ U(1 − :data:`PART_END`, 1), a kink in the last 10 % of the move. θ₀ = κd·min(1, 1/(2(1 − f₀))):
  the arc's end offset where that turns less than the arc, else the arc's turn. The final heading
  is θ₀·f₀ off the chord (≈ the whole turn, κd, for a kink near the end: 2× the arc's).
"""
from __future__ import annotations

from typing import Any

import numpy as np

#: RobotErrors.path_shape values (``arc`` first: the default)
SHAPES = ("arc", "s", "early", "late", "kink", "kink-end")
#: the fraction of the move an ``early`` or ``late`` bend is concentrated in (the first or last 30 %)
PART = 0.3
#: ``kink-end``: the kink falls within the last 10 % of the move
PART_END = 0.1


def kink_at(shape: str, rng: np.random.Generator) -> float | None:
    """The fraction of the move at which a kink falls (drawn per move), None for the other shapes."""
    if shape == "kink":
        return float(rng.uniform(0.0, 1.0))
    if shape == "kink-end":
        return float(rng.uniform(1.0 - PART_END, 1.0))
    return None


def heading(shape: str, f: Any, kappa_d: float, at: float | None = None) -> np.ndarray:
    """θ(f): the heading's departure from the start (rad) at fractions ``f`` for curvature·length κd."""
    f = np.asarray(f, dtype=float)
    a = PART
    if shape == "arc":
        return kappa_d * f
    if shape == "s":  # curvature +2κ to halfway, −2κ after
        return 2.0 * kappa_d * np.minimum(f, 1.0 - f)
    if shape == "early":  # at the arc's end offset: κ' = κ / (a(2 − a))
        return kappa_d / (a * (2.0 - a)) * np.minimum(f, a)
    if shape == "late":  # at the arc's turn: κ' = κ / a
        return kappa_d / a * np.clip(f - (1.0 - a), 0.0, a)
    if shape in ("kink", "kink-end"):
        assert at is not None, "a kink needs the point it falls at"
        return np.where(f >= at, kink_turn(kappa_d, at), 0.0)
    raise ValueError(f"path shape {shape!r} (known: {', '.join(SHAPES)})")


def kink_turn(kappa_d: float, at: float) -> float:
    """θ₀ of a kink at ``at``: the arc's end offset κd/2 = θ₀(1 − f₀), at most the arc's turn κd."""
    return kappa_d * min(1.0, 1.0 / (2.0 * max(1.0 - at, 1e-12)))


def lateral(shape: str, f: Any, kappa_d: float, at: float | None = None) -> np.ndarray:
    """y(f)/d: the sideways offset from the start heading's line per unit move length (θ's exact integral)."""
    f = np.asarray(f, dtype=float)
    a = PART
    if shape == "arc":
        return kappa_d * f * f / 2.0
    if shape == "s":
        return kappa_d * np.where(f <= 0.5, f * f, 0.5 - (1.0 - f) ** 2)
    if shape == "early":
        k = kappa_d / (a * (2.0 - a))
        g = np.minimum(f, a)
        return k * (g * g / 2.0 + a * np.maximum(f - a, 0.0))
    if shape == "late":
        g = np.clip(f - (1.0 - a), 0.0, a)
        return kappa_d / a * g * g / 2.0
    if shape in ("kink", "kink-end"):
        assert at is not None, "a kink needs the point it falls at"
        return kink_turn(kappa_d, at) * np.maximum(f - at, 0.0)
    raise ValueError(f"path shape {shape!r} (known: {', '.join(SHAPES)})")


def end(shape: str, kappa_d: float, at: float | None = None) -> tuple[float, float]:
    """(sideways offset at the end per unit move length, turn in rad) of one move."""
    return float(lateral(shape, 1.0, kappa_d, at)), float(heading(shape, 1.0, kappa_d, at))


def kappa_d_of(shape: str, lateral_mm: float, dist_mm: float, at: float | None = None) -> float:
    """κd back from a move's end offset (every shape's end offset is linear in κd)."""
    unit = float(lateral(shape, 1.0, 1.0, at))
    return 0.0 if unit == 0.0 else lateral_mm / dist_mm / unit


def profile(shape: str, f: Any, lateral_mm: float, dist_mm: float, at: float | None = None
            ) -> tuple[np.ndarray, np.ndarray]:
    """Along a move at fractions ``f``: the offset from the chord (mm, left +) and the heading's departure
    from an even turn (rad) — fakes/effects.py ``Effects.bend_profile``'s contract."""
    f = np.asarray(f, dtype=float)
    kd = kappa_d_of(shape, lateral_mm, dist_mm, at)
    turn = end(shape, kd, at)[1]
    return lateral(shape, f, kd, at) * dist_mm - f * lateral_mm, heading(shape, f, kd, at) - turn * f


__all__ = ["PART", "PART_END", "SHAPES", "end", "heading", "kappa_d_of", "kink_at", "kink_turn", "lateral",
           "profile"]
