"""The error model of fakes/errors.py applied to one world (its seeded draws and the maths).

:class:`Effects` is built by :class:`fakes.world.World` from ``WorldParams.errors`` and
holds everything drawn once per world: the tracker's systematic pattern for its one
station, the nest seatings, the robot reflector's offset in its rotatable mount, the
inclinometer bias, the target's print distortion and the floor and plate surfaces.
Every draw comes from its own named child generator of the world seed, so switching
one effect off leaves the others' draws unchanged. With every group off nothing is
drawn and every hook returns its input unchanged (the ``ideal`` world).
"""
from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from calibration.frames import apply_H, inv_H
from calibration.plate import NEST_NAMES
from fakes import path_shapes
from fakes.errors import ErrorModel
from fakes.floor import HeightField, contact_tilt, plane_height, plate_on_floor

#: terms of the tracker's systematic pattern over the beam direction (see tracker_measure)
_SYS_TERMS = 7


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


class Effects:
    """The per-world draws of the error model and the hooks the fakes call."""

    def __init__(self, world: Any) -> None:
        """``world``: the fakes.world.World being built (its params and rng; typed Any: world imports us)."""
        self.world = world
        e: ErrorModel = world.params.errors
        self.model = e
        self.active = e.active
        self.settles = e.floor is not None or e.plate is not None
        self._kinks: dict[float, float] = {}  # a kinked move's end offset -> the fraction where it kinks
        if e.tracker is not None:
            # per station: coefficients of the angular pattern (hz, vt) and the range offset
            self.sys_coef = world.rng("errors.tracker.systematic").normal(size=(3, _SYS_TERMS))
        self.nest_offsets: dict[str, np.ndarray] = {}
        if e.reflector is not None:
            self._seat_rng = world.rng("errors.nests.seating")
            self.reseat_nests()
            r = world.rng("errors.reflector.mount")
            phi = r.uniform(0.0, 2.0 * math.pi)
            ecc = e.reflector.mount_eccentricity_mm
            self.mount_offset = (np.array([ecc * math.cos(phi), ecc * math.sin(phi), 0.0])
                                 + e.reflector.smr_centring_mm * _unit(r))
        if e.imu is not None:
            self.imu_bias_rad = np.radians(world.rng("errors.imu.bias").normal(0.0, e.imu.bias_sigma_deg, 2))
        if e.target is not None:
            r = world.rng("errors.target.print")
            s, g = r.normal(0.0, e.target.scale_sigma), r.normal(0.0, e.target.shear_sigma_rad)
            self.print_A = np.array([[1.0 + s, g], [0.0, 1.0 + s]])  # nominal -> true, about the board centre
            # the hand-held intrinsics board is another print of the same kind (fakes/board.py's hook)
            b = world.rng("errors.board.print").normal(0.0, e.target.scale_sigma, 2)
            world.board_print_scale = (1.0 + float(b[0]), 1.0 + float(b[1]))
        self.floor = self.plate_flatness = None
        if e.floor is not None:
            f = e.floor
            slope = world.rng("errors.floor.slope").normal(0.0, f.slope_sigma_mrad * 1e-3, 2)
            rms_mm = f.rms_slope_mrad * 1e-3 * f.correlation_mm  # the field's rms slope is rms / correlation
            self.floor = HeightField(world.rng("errors.floor.waviness"), rms_mm, f.correlation_mm,
                                     (float(slope[0]), float(slope[1])))
        if e.plate is not None:
            self.plate_flatness = HeightField(world.rng("errors.plate.flatness"), e.plate.flatness_rms_mm,
                                              e.plate.flatness_correlation_mm)

    # ------------------------------------------------------------------ surfaces

    def floor_height(self, x: float, y: float) -> float:
        return 0.0 if self.floor is None else float(self.floor(x, y))

    def place_plate(self, abs_H_ref: np.ndarray, centre_abs: np.ndarray) -> np.ndarray:
        """The plate pose on this floor (unchanged on a flat floor)."""
        if self.floor is None:
            return abs_H_ref
        return plate_on_floor(abs_H_ref, centre_abs, self.floor, self.world.params.plate_half_size_mm)

    def support_height(self, x: float, y: float, on_plate: bool) -> float:
        """Surface height under (x, y): the plate's top face (+ flatness) or the floor."""
        if not on_plate:
            return self.floor_height(x, y)
        h = plane_height(self.world.abs_H_ref, x, y)
        return h if self.plate_flatness is None else h + float(self.plate_flatness(x, y))

    def settle(self, pose: Any) -> Any:
        """``pose`` standing on its wheels: the surface's roll, pitch and height added."""
        if not self.settles:
            return pose
        r = self.model.robot
        track, caster = (r.wheel_track_mm, r.caster_x_mm) if r is not None else (400.0, 350.0)
        w = self.world
        roll, pitch, z = contact_tilt(pose.x_mm, pose.y_mm, pose.heading_deg, track, caster,
                                      lambda x, y: w.support_height(x, y))
        return replace(pose, roll_rad=pose.roll_rad + roll, pitch_rad=pose.pitch_rad + pitch, z_mm=z)

    def floor_view_H(self, abs_H_cam: np.ndarray) -> np.ndarray:
        """``abs_H_cam`` lowered by the floor height where the optical axis meets it (renderer)."""
        if self.floor is None:
            return abs_H_cam
        axis, c = abs_H_cam[:3, 2], abs_H_cam[:3, 3]
        foot = c - axis * (c[2] / axis[2])
        out = abs_H_cam.copy()
        out[2, 3] -= self.floor_height(foot[0], foot[1])
        return out

    # ------------------------------------------------------------------ reflectors

    def reseat_nests(self) -> None:
        """New seatings of the SMRs in the three nests (centring direction and nest repeatability)."""
        ref = self.model.reflector
        if ref is None:
            return
        rng = self._seat_rng
        self.nest_offsets = {n: ref.smr_centring_mm * _unit(rng) + rng.normal(0.0, ref.nest_reseat_mm, 3)
                             for n in NEST_NAMES}

    def robot_reflector(self, abs_H_rob: np.ndarray) -> np.ndarray:
        """ACS centre of the robot's SMR: its mount turns toward the tracker, the offset turns with it."""
        P = abs_H_rob[:3, 3]
        if self.model.reflector is None:
            return P
        R = abs_H_rob[:3, :3]
        d = R.T @ (self.world.abs_H_trk[:3, 3] - P)
        b = math.atan2(d[1], d[0])
        cb, sb = math.cos(b), math.sin(b)
        m = self.mount_offset
        return P + R @ np.array([cb * m[0] - sb * m[1], sb * m[0] + cb * m[1], m[2]])

    # ------------------------------------------------------------------ tracker

    def tracker_measure(self, pos_trk: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Noisy tracker readings (tracker frame, mm) of true positions ``pos_trk`` (..., 3).

        Random part in spherical coordinates (range σ_r, two transverse σ_t), plus the
        station's systematic part: a smooth angular pattern over the beam direction
        (a transverse error ∝ distance) and a range error ∝ distance.
        """
        t = self.model.tracker
        assert t is not None
        P = np.asarray(pos_trk, dtype=float)
        flat = P.reshape(-1, 3)
        r = np.linalg.norm(flat, axis=1)
        hz = np.arctan2(flat[:, 1], flat[:, 0])
        vt = np.arccos(np.clip(flat[:, 2] / r, -1.0, 1.0))
        e_r = flat / r[:, None]
        e_hz = np.column_stack([-np.sin(hz), np.cos(hz), np.zeros_like(hz)])
        e_vt = np.column_stack([np.cos(vt) * np.cos(hz), np.cos(vt) * np.sin(hz), -np.sin(vt)])
        k, D_m = t.mpe_to_sigma, r / 1000.0
        # squares of the terms sum to 4 in every direction: unit variance over stations everywhere
        basis = np.column_stack([np.ones_like(hz), np.cos(hz), np.sin(hz), np.cos(2 * hz), np.sin(2 * hz),
                                 np.cos(vt), np.sin(vt)]) / 2.0
        pattern = basis @ self.sys_coef.T  # (n, 3): range, hz, vt; unit variance over stations
        z = rng.standard_normal(flat.shape)
        d_r = k * t.range_a_mm * z[:, 0] + k * t.range_b_mm_per_m * D_m * pattern[:, 0]
        if t.random_share_b > 0:  # part of the b term random per reading (drawn only then: same streams)
            share = t.random_share_b
            pattern = math.sqrt(1.0 - share) * pattern + math.sqrt(share) * rng.standard_normal(pattern.shape)
        d_h = k * t.transverse_a_mm * z[:, 1] + k * t.transverse_b_mm_per_m * D_m * pattern[:, 1]
        d_v = k * t.transverse_a_mm * z[:, 2] + k * t.transverse_b_mm_per_m * D_m * pattern[:, 2]
        out = flat + d_r[:, None] * e_r + d_h[:, None] * e_hz + d_v[:, None] * e_vt
        return out.reshape(P.shape)

    def tracker_measure_abs(self, pos_abs: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """:meth:`tracker_measure` for ACS positions (the simulation harness works in ACS)."""
        H = self.world.abs_H_trk
        return apply_H(H, self.tracker_measure(apply_H(inv_H(H), pos_abs), rng))

    # ------------------------------------------------------------------ base and target

    def inclinometer(self, roll_rad: float, pitch_rad: float,
                     rng: np.random.Generator) -> tuple[float, float]:
        """What the base's inclinometer reads for a true roll/pitch (rad)."""
        imu = self.model.imu
        if imu is None:
            return roll_rad, pitch_rad
        n = np.radians(rng.normal(0.0, imu.noise_sigma_deg, 2))
        return (float(roll_rad + self.imu_bias_rad[0] + n[0]), float(pitch_rad + self.imu_bias_rad[1] + n[1]))

    def slip(self, rng: np.random.Generator) -> float:
        """Relative distance error of one move from wheel slip (0 without the robot group)."""
        r = self.model.robot
        return float(rng.normal(0.0, r.slip_sigma)) if r is not None and r.slip_sigma > 0 else 0.0

    def bend(self, dist_mm: float, rng: np.random.Generator, shape: str | None = None) -> tuple[float, float]:
        """(lateral mm at the end, heading change in degrees) of a straight move that bends.

        ``shape``: the robot's ``path_shape`` unless an experiment overrides it (SimConfig.path_shape).
        Every shape's size comes from one curvature κ per move (fakes/path_shapes.py): the arc ends
        κd²/2 to the side and turns the heading by κd, the S turns it back (0).
        """
        r = self.model.robot
        if r is None:
            return 0.0, 0.0
        shape = shape or r.path_shape
        kappa = rng.normal(0.0, 2.0 * r.lateral_sigma_mm / r.lateral_ref_mm ** 2)
        if shape in ("arc", "s"):  # the first two shapes, as they always were (their draws unchanged)
            turn = 0.0 if shape == "s" else float(math.degrees(kappa * dist_mm))
            return float(kappa * dist_mm ** 2 / 2.0), turn
        at = path_shapes.kink_at(shape, rng)
        side, turn_rad = path_shapes.end(shape, kappa * dist_mm, at)
        lateral = float(side * dist_mm)
        if at is not None:  # the kink's point goes with the move, which bend_profile knows by its end offset
            if len(self._kinks) >= 4096:  # the oldest moves are long done
                del self._kinks[next(iter(self._kinks))]
            self._kinks[lateral] = at
        return lateral, float(math.degrees(turn_rad))

    def bend_profile(self, f: Any, lateral_mm: float, dist_mm: float, shape: str | None = None
                     ) -> tuple[np.ndarray, np.ndarray]:
        """Along a bent move at fractions ``f``: the sideways offset from the chord (mm, left +, small angles)
        and the heading's departure from an even turn (rad), for a move ending ``lateral_mm`` to the side."""
        f = np.asarray(f, dtype=float)
        r = self.model.robot
        shape = shape or (r.path_shape if r is not None else "arc")
        if shape == "s":  # curvature +2κ then −2κ: y = 2f², then 1 − 2(1 − f)²
            y = np.where(f <= 0.5, 2.0 * f * f, 1.0 - 2.0 * (1.0 - f) ** 2) * lateral_mm
            return y - f * lateral_mm, 4.0 * lateral_mm / dist_mm * np.minimum(f, 1.0 - f)
        if shape == "arc":
            return (f * f - f) * lateral_mm, np.zeros_like(f)  # one arc: y = f²
        at = None
        if shape in ("kink", "kink-end"):
            if lateral_mm not in self._kinks:
                raise ValueError(f"a {shape} move ending {lateral_mm!r} mm to the side was not drawn by "
                                 "bend()")
            at = self._kinks[lateral_mm]
        return path_shapes.profile(shape, f, lateral_mm, dist_mm, at)

    def board_true(self, P_ref: np.ndarray) -> np.ndarray:
        """Where the printed board's nominal points (PCS) really are (scale and shear of the print)."""
        if self.model.target is None:
            return P_ref
        c = self.world.board_centre_ref()
        out = np.array(P_ref, dtype=float, copy=True)
        out[..., :2] = (out[..., :2] - c[:2]) @ self.print_A.T + c[:2]
        return out

    def board_nominal(self, qx: np.ndarray, qy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Nominal board coordinates printed at the true PCS point (qx, qy) (renderer texture lookup)."""
        if self.model.target is None:
            return qx, qy
        c = self.world.board_centre_ref()
        Ai = np.linalg.inv(self.print_A)
        dx, dy = qx - c[0], qy - c[1]
        return Ai[0, 0] * dx + Ai[0, 1] * dy + c[0], Ai[1, 0] * dx + Ai[1, 1] * dy + c[1]

    def truth(self) -> dict[str, Any]:
        """The drawn values, JSON-able, for sim.truth (empty for the ideal world)."""
        if not self.active:
            return {}
        out: dict[str, Any] = {"magnitudes": self.model.summary()}
        if self.model.reflector is not None:
            out["nest_offsets_mm"] = {n: v.tolist() for n, v in self.nest_offsets.items()}
            out["mount_offset_mm"] = self.mount_offset.tolist()
        if self.model.imu is not None:
            out["imu_bias_deg"] = np.degrees(self.imu_bias_rad).tolist()
        if self.model.target is not None:
            out["print_A"] = self.print_A.tolist()
        if self.floor is not None:
            out["floor_slope"] = self.floor.slope.tolist()
        return out


__all__ = ["Effects"]
