"""Synthetic 8-direction experiments for heading_fit's weight, with path shapes of several kinds.

Built here, not by the simulator (fakes/): every final move of length L ends on the mark's stop with
a lateral path e(s) of its own (zero at both ends), noisy anchors and stream, a robot-frame bias and,
optionally, an ACS offset of the mark per direction (the floor under the robot differs by direction,
so a direction's stops share it). Shapes: ``straight``, ``arc``, ``late`` (a bend in the last 30 % of
the move), ``early`` (in the first 30 %), ``s-curve``, ``kink`` (the heading turns at 90 % of the move).
"""
from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from calibration.compensation import Compensation, Stop, compensate
from calibration.heading_weight import NOT_LEARNED, HeadingWeight, stop_marks
from calibration.weight_cv import design

L = 200.0
R_MARK = np.array([200.0, 50.0])  # the mark in the robot frame (the camera footprint), mm
B_TRUE = np.array([0.03, -0.02])
M_TRUE = np.array([1000.0, 2000.0])
RAD = 250e-6  # the chord's heading error scale, 1σ (docs/accuracy.md: 50 µm over 200 mm)


def _ramp(s: np.ndarray, a: float, b: float) -> np.ndarray:
    """0 before a·L, a parabola from there to b·L, then a line: a bend confined to [a, b] of the move."""
    x = np.clip((s / L - a) / (b - a), 0.0, 1.0)
    return np.where(s / L < b, x ** 2 * (b - a) / 2, (s / L - b) + (b - a) / 2) * L


def shape(kind: str, rng: np.random.Generator, lean: float = 0.0) -> Callable[[np.ndarray], np.ndarray]:
    """The lateral offset e(s) of one move, zero at both ends; its end slope has a σ of ≈ RAD about ``lean``
    (rad: a direction's moves bend alike, the floor's slope there)."""
    if kind == "straight":
        return lambda s: 0.0 * s
    if kind == "arc":
        k = rng.normal(2 * lean / L, 2 * RAD / L)
        return lambda s: k * s * (s - L) / 2
    if kind == "s-curve":
        a = rng.normal(0.0, RAD * L / (2 * np.pi))
        return lambda s: a * np.sin(2 * np.pi * s / L)
    lo, hi = {"late": (0.7, 1.0), "early": (0.0, 0.3), "kink": (0.89, 0.91)}[kind]
    # the turn within [lo, hi]; the chord is off by its share (lo + hi) / 2
    c = rng.normal(lean, RAD) / ((lo + hi) / 2)
    return lambda s: c * (_ramp(s, lo, hi) - s * float(_ramp(np.array([L]), lo, hi)[0]) / L)


def _rot(a: float) -> np.ndarray:
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def experiment(kind: str, seed: int, weight: HeadingWeight = NOT_LEARNED, *, n_stream: int = 150,
               sigma_stream: float = 0.015, sigma_anchor: float = 0.010, floor_mm: float = 0.0,
               lean_rad: float = 0.0,
               n_dirs: int = 8, reps: int = 5) -> dict[str, Any]:
    """{stops (stop marks), heads, groups, chord_err, used_err (rad), sigma (the stated heading σ per stop),
    applied (each stop's compensation)} of one experiment; ``floor_mm``: 1σ of a per-direction ACS offset of
    the mark seen; ``lean_rad``: 1σ of a per-direction mean end slope of the moves."""
    rng = np.random.default_rng(seed)
    out: dict[str, list[Any]] = {k: [] for k in ("stops", "heads", "groups", "chord_err", "used_err", "sigma",
                                                 "applied")}
    for k in range(n_dirs):
        floor, lean = rng.normal(0.0, floor_mm, 2), rng.normal(0.0, lean_rad)
        for _ in range(reps):
            e = shape(kind, rng, lean)
            psi_c = math.radians(360.0 / n_dirs * k) + rng.normal(0.0, 0.01)
            h = 1e-3
            psi_true = psi_c + float(e(np.array([L]))[0] - e(np.array([L - h]))[0]) / h
            P_at = M_TRUE - _rot(psi_true) @ (R_MARK - B_TRUE)
            u, n = np.array([math.cos(psi_c), math.sin(psi_c)]), np.array([-math.sin(psi_c), math.cos(psi_c)])
            s = np.linspace(0.0, L, n_stream)
            noise = rng.normal(0.0, sigma_stream, (n_stream, 2))
            xy = P_at - L * u + np.outer(s, u) + np.outer(e(s), n) + noise
            noisy = [P_at - L * u + rng.normal(0.0, sigma_anchor, 2), P_at + rng.normal(0.0, sigma_anchor, 2)]
            stop = Stop(*(np.append(p, 0.0) for p in noisy), stream=np.column_stack([xy, np.zeros(n_stream)]))
            a = compensate(Compensation(heading_fit=True), stop, np.eye(4), heading_weight=weight)
            # the floor moves the mark seen
            rob_P = np.append(_rot(psi_true).T @ (M_TRUE + floor - P_at) + B_TRUE, 0.0)
            out["stops"].append(stop_marks(a, rob_P))
            v, c = a.abs_P_at - a.abs_P_prev, noisy[1] - noisy[0]
            out["heads"].append(math.degrees(math.atan2(v[1], v[0])))
            out["groups"].append(k)
            out["chord_err"].append(math.atan2(c[1], c[0]) - psi_true)
            out["used_err"].append(math.atan2(v[1], v[0]) - psi_true)
            out["sigma"].append(a.sigma_heading_rad)
            out["applied"].append(a)
    return {k: (v if k in ("stops", "applied") else np.array(v)) for k, v in out.items()}


def model_marks(w_true: float, noise_mm: float, seed: int) -> tuple[np.ndarray, ...]:
    """(chord marks, marks with the whole fitted slope, headings, slopes) built exactly by heading_weight's
    model, P_k = M + R(ψ_k)·b − w·Δ_k + noise, 8 × 5 stops (Δ_k: a 300 µrad slope over the lever arm L), so
    that the weight's z is set by w and the noise."""
    rng = np.random.default_rng(seed)
    psi = np.repeat(45.0 * np.arange(8), 5) + rng.normal(0.0, 0.5, 40)
    slopes = rng.normal(0.0, 300e-6, 40)
    delta = np.column_stack([-np.sin(np.radians(psi)), np.cos(np.radians(psi))]) * (L * slopes)[:, None]
    P = (design(psi, delta) @ [*M_TRUE, *B_TRUE, w_true]).reshape(-1, 2) + rng.normal(0.0, noise_mm, (40, 2))
    return P, P + delta, psi, slopes


def rms(x: Any) -> float:
    """RMS of angle errors (rad), wrapped to (−π, π]."""
    return float(np.sqrt(np.mean(np.square(np.angle(np.exp(1j * np.asarray(x)))))))
