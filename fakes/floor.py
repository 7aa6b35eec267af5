"""Floor and plate surfaces of the simulated world, and how the robot's wheels sit on them.

The floor is a global slope plus a smooth, seeded, Gaussian-correlated random height
field (fakes/errors.py ``FloorErrors``). The plate rests on the floor: its plane is the
least-squares plane of the floor under its footprint, plus its own flatness field.
The robot stands on three contacts fixed in its frame (paper §Robot: left and right
drive wheel and the front caster); its roll, pitch and height follow from the
surface under them, so the tilt repeats with position and heading.

Heights are in mm, ACS z up (the levelled tracker's vertical).
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

from calibration.frames import make_H

#: random Fourier components of a height field (enough for a near-Gaussian field)
N_WAVES = 64


class HeightField:
    """h(x, y) = Σ a·cos(k·p + φ), k ~ N(0, I/ℓ²): covariance σ² exp(−r²/2ℓ²), rms slope σ/ℓ per axis."""

    def __init__(self, rng: np.random.Generator, rms_mm: float, correlation_mm: float,
                 slope: tuple[float, float] = (0.0, 0.0)) -> None:
        if not (rms_mm >= 0 and correlation_mm > 0):
            raise ValueError(f"height field: rms_mm={rms_mm!r} must be >= 0, "
                             f"correlation_mm={correlation_mm!r} > 0")
        self.k = rng.normal(0.0, 1.0 / correlation_mm, (N_WAVES, 2))
        self.phase = rng.uniform(0.0, 2.0 * math.pi, N_WAVES)
        self.amp = rms_mm * math.sqrt(2.0 / N_WAVES)
        self.slope = np.asarray(slope, dtype=float)

    def __call__(self, x: np.ndarray | float, y: np.ndarray | float) -> np.ndarray:
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        arg = np.multiply.outer(x, self.k[:, 0]) + np.multiply.outer(y, self.k[:, 1]) + self.phase
        return self.amp * np.cos(arg).sum(axis=-1) + self.slope[0] * x + self.slope[1] * y


def fitted_plane(height: Callable[[np.ndarray, np.ndarray], np.ndarray], centre: np.ndarray,
                 half_mm: float, n: int = 11) -> tuple[float, float, float]:
    """Least-squares plane z = z0 + gx·(x−cx) + gy·(y−cy) of ``height`` over a square around ``centre``."""
    u = np.linspace(-half_mm, half_mm, n)
    X, Y = np.meshgrid(u, u)
    Z = height(X + centre[0], Y + centre[1])
    A = np.column_stack([np.ones(X.size), X.ravel(), Y.ravel()])
    z0, gx, gy = np.linalg.lstsq(A, Z.ravel(), rcond=None)[0]
    return float(z0), float(gx), float(gy)


def plate_on_floor(abs_H_ref: np.ndarray, centre_abs: np.ndarray, floor: Callable[..., np.ndarray],
                   half_mm: float) -> np.ndarray:
    """The flat-floor plate pose tilted and raised onto the floor's fitted plane under it.

    ``centre_abs`` is the board centre on the top face of the flat-floor plate, so its z
    is the plate thickness; the plate keeps that thickness along its new normal.
    """
    z0, gx, gy = fitted_plane(floor, centre_abs, half_mm)
    n = np.array([-gx, -gy, 1.0]) / math.sqrt(gx * gx + gy * gy + 1.0)
    # rotation taking +z to n about the horizontal axis z × n (Rodrigues)
    axis = np.cross([0.0, 0.0, 1.0], n)
    s, c = float(np.linalg.norm(axis)), float(n[2])
    R_tilt = np.eye(3)
    if s > 1e-15:
        k = axis / s
        K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        R_tilt = R_tilt + s * K + (1 - c) * K @ K
    R0, t0 = abs_H_ref[:3, :3], abs_H_ref[:3, 3]
    centre_ref = R0.T @ (centre_abs - t0)
    top = np.array([centre_abs[0], centre_abs[1], z0]) + n * centre_abs[2]
    R = R_tilt @ R0
    return make_H(R, top - R @ centre_ref, "abs_H_ref")


def plane_height(abs_H_ref: np.ndarray, x: float, y: float) -> float:
    """Height of the plate's top face (PCS z = 0) above the ACS point (x, y)."""
    n, p = -abs_H_ref[:3, 2], abs_H_ref[:3, 3]
    return float(p[2] - (n[0] * (x - p[0]) + n[1] * (y - p[1])) / n[2])


def contact_tilt(x: float, y: float, heading_deg: float, track_mm: float, caster_x_mm: float,
                 height: Callable[[float, float], float]) -> tuple[float, float, float]:
    """(roll, pitch, z) of a robot whose reflector is above (x, y): the plane of its three contacts.

    Contacts in the robot frame: drive wheels at (0, ±track/2), caster at (caster_x, 0).
    With the plane z = z0 + gx·u + gy·v in heading-aligned axes (u forward, v left), the
    frame convention of World.abs_H_rob (Rz·Ry(pitch)·Rx(roll)) gives pitch = −atan(gx),
    roll = asin(gy/√(1+gx²+gy²)); z is the plane's height under the reflector.
    """
    a = math.radians(heading_deg)
    ca, sa = math.cos(a), math.sin(a)
    hw = track_mm / 2.0
    h_left = height(x - sa * hw, y + ca * hw)
    h_right = height(x + sa * hw, y - ca * hw)
    h_caster = height(x + ca * caster_x_mm, y + sa * caster_x_mm)
    gy = (h_left - h_right) / track_mm
    gx = (h_caster - (h_left + h_right) / 2.0) / caster_x_mm
    norm = math.sqrt(1.0 + gx * gx + gy * gy)
    return math.asin(gy / norm), -math.atan(gx), (h_left + h_right) / 2.0


__all__ = ["HeightField", "N_WAVES", "contact_tilt", "fitted_plane", "plane_height", "plate_on_floor"]
