"""State and geometry of the fake AT901 (no networking; see ``fakes.tracker``).

The state outlives client connections (a real tracker stays initialised when a
client reconnects); ``reset()`` models a controller reboot.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.emscon.codec import MEAS_VALUE
from drivers.emscon.enums import (ES_AngleUnit, ES_LengthUnit, ES_MeasMode, ES_TargetType)

#: length unit -> value of 1 mm in that unit
LENGTH_PER_MM = {ES_LengthUnit.Meter: 1e-3, ES_LengthUnit.Millimeter: 1.0, ES_LengthUnit.Micron: 1e3,
                 ES_LengthUnit.Foot: 1 / 304.8, ES_LengthUnit.Yard: 1 / 914.4, ES_LengthUnit.Inch: 1 / 25.4}
#: angle unit -> value of 1 degree in that unit
ANGLE_PER_DEG = {ES_AngleUnit.Radian: math.pi / 180, ES_AngleUnit.Degree: 1.0, ES_AngleUnit.Gon: 400 / 360}

#: reflectors the fake claims to know: (id, name, target type, surface offset mm)
REFLECTORS = ((0, "RRR 1.5in", ES_TargetType.RRR15, 19.05), (1, "RRR 0.5in", ES_TargetType.RRR05, 6.35),
              (2, "CatEye", ES_TargetType.CatsEye, 0.0))

#: beam direction of the bird bath (home) position, tracker frame
BIRDBATH_DIR = np.array([0.0, -1.0, -1.0]) / math.sqrt(2.0)


@dataclass
class TrackerState:
    """Everything a client can set or observe; survives reconnects."""

    initialized: bool = False
    units: dict[str, int] = field(default_factory=lambda: {
        "length_unit": 1, "angle_unit": 1, "temperature_unit": 0, "pressure_unit": 0, "humidity_unit": 0})
    coord_sys_type: int = 0
    meas_mode: int = ES_MeasMode.Stationary
    meas_time_ms: int = 1000
    use_adm: int = 0
    time_separation_ms: int = 100
    number_of_points: int = 0
    environment: tuple[float, float, float] = (20.0, 1013.25, 50.0)
    search_radius_mm: float = 50.0
    search_timeout_ms: int = 2000
    reflector_id: int = 0
    orientation: tuple[float, ...] = (0.0,) * 6  # station orientation: val1-3, rot1-3
    transformation: tuple[float, ...] = (0.0,) * 6 + (1.0,)  # val1-3, rot1-3, scale
    settings: dict[str, int] = field(default_factory=lambda: {
        "weather_monitor_status": 2, "apply_transformation_params": 0,
        "apply_station_orientation_params": 0, "keep_last_position": 1, "send_unsolicited_messages": 1,
        "send_reflector_position_data": 0, "try_measurement_mode": 0, "has_nivel": 0,
        "has_video_camera": 0})
    direction: np.ndarray = field(default_factory=lambda: BIRDBATH_DIR.copy())
    locked: str | None = None  # name of the world reflector the beam follows

    def length_unit(self) -> float:
        return LENGTH_PER_MM.get(self.units["length_unit"], 1.0)

    def angle_unit(self) -> float:
        return ANGLE_PER_DEG.get(self.units["angle_unit"], 1.0)


class TrackerModel:
    """Pointing, lock-on and noisy measurements of the world's reflectors."""

    def __init__(self, world: Any, sigma_mm: float | None = None) -> None:
        self.world = world
        self.sigma_mm = world.params.tracker_sigma_mm if sigma_mm is None else float(sigma_mm)
        if not self.sigma_mm >= 0:
            raise ValueError(f"tracker sigma_mm={sigma_mm!r} must be >= 0")
        self.rng = world.rng("tracker.noise")
        # the stream's own generator: how many records a stream holds depends on timing, and single
        # measurements must not (their noise stays the same whatever was streamed before)
        self.stream_rng = world.rng("tracker.stream")
        self.state = TrackerState()

    def reset(self) -> None:
        """Controller reboot: uninitialised, default settings."""
        self.state = TrackerState()

    # ------------------------------------------------------------------ geometry

    def reflectors(self) -> dict[str, np.ndarray]:
        return self.world.reflectors_trk()

    def locked_position(self) -> np.ndarray | None:
        """Current true position of the locked reflector (it may move with the robot)."""
        name = self.state.locked
        if name is None:
            return None
        pos = self.reflectors().get(name)
        if pos is None:
            self.state.locked = None
            return None
        self.state.direction = pos / np.linalg.norm(pos)
        return pos

    def point_to(self, target_mm: np.ndarray) -> float:
        """Turn the beam toward ``target_mm``; return the turn angle in degrees."""
        norm = float(np.linalg.norm(target_mm))
        if norm < 1e-9:
            return 0.0
        new = np.asarray(target_mm, dtype=float) / norm
        angle = math.degrees(math.acos(max(-1.0, min(1.0, float(new @ self.state.direction)))))
        self.state.direction = new
        self.state.locked = None
        return angle

    def nearest_to_point(self, target_mm: np.ndarray) -> str | None:
        """The reflector within the search radius of a 3-D point (GoPosition with distance)."""
        best, best_d = None, self.state.search_radius_mm
        for name, pos in self.reflectors().items():
            d = float(np.linalg.norm(pos - target_mm))
            if d <= best_d:
                best, best_d = name, d
        return best

    def nearest_to_beam(self, approx_distance_mm: float) -> str | None:
        """The reflector nearest to the beam line, within the search radius.

        The search is a spiral around the beam at the approximate distance, so the
        radius is compared with each reflector's distance from the beam line; the
        approximate distance only rules out reflectors behind the tracker.
        """
        d = self.state.direction
        best, best_d = None, self.state.search_radius_mm
        for name, pos in self.reflectors().items():
            along = float(pos @ d)
            if along <= 0 or approx_distance_mm <= 0:
                continue
            perp = float(np.linalg.norm(pos - along * d))
            if perp <= best_d:
                best, best_d = name, perp
        return best

    def lock(self, name: str) -> None:
        self.state.locked = name
        self.locked_position()

    def hz_vt_deg(self) -> tuple[float, float]:
        """Beam direction as horizontal angle and zenith angle (degrees)."""
        x, y, z = self.state.direction
        return math.degrees(math.atan2(y, x)) % 360.0, math.degrees(math.acos(max(-1.0, min(1.0, z))))

    # ------------------------------------------------------------------ measuring

    def measure_point(self) -> np.ndarray | None:
        """One noisy reading of the locked reflector (mm, tracker frame), or None if unlocked."""
        pos = self.locked_position()
        if pos is None:
            return None
        if self.world.effects.model.tracker is not None:  # AT901 error model replaces the isotropic σ
            return self.world.effects.tracker_measure(pos, self.rng)
        return pos + self.rng.normal(0.0, self.sigma_mm, 3)

    def measure_records(self, n: int, t0_s: float, dt_s: float,
                        origin_s: float | None = None) -> np.ndarray | None:
        """``n`` continuous records, the first at time ``t0_s`` (s since server start at monotonic
        ``origin_s``).

        With ``origin_s``, the robot's reflector is measured where the robot was at each
        record's time (``World.robot_at``), so a stream taken while it drives follows its path.
        """
        pos = self.locked_position()
        if pos is None:
            return None
        rec = np.zeros(n, MEAS_VALUE)
        at = np.repeat(pos[None, :], n, axis=0)
        if origin_s is not None and self.state.locked == "robot":
            at = np.array([self.world.robot_reflector_trk_at(origin_s + t0_s + dt_s * i) for i in range(n)])
        if self.world.effects.model.tracker is not None:
            xyz = self.world.effects.tracker_measure(at, self.stream_rng)
        else:
            xyz = at + self.stream_rng.normal(0.0, self.sigma_mm, (n, 3))
        xyz = xyz * self.state.length_unit()
        rec["val1"], rec["val2"], rec["val3"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        t = t0_s + dt_s * np.arange(n)
        sec = np.floor(t)
        rec["time1"] = sec.astype(np.int64) % (1 << 31)
        rec["time2"] = np.minimum(((t - sec) * 1e6).round(), 999_999).astype(np.int64)
        return rec
