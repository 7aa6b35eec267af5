"""Simulation protocol harness (docs/accuracy.md, "Reference figures") on the shared simulated world.

Generates what the real procedure would observe, plus the truth to score it:

* a calibration visit: the robot on the plate at P0 with the target centre under the
  camera, an image (ray-cast by :class:`fakes.render.Renderer`, or rendering-free:
  the exact ``cam_H_ref`` or a PnP on projected corners with pixel noise), the
  reflector after a straight move of d (P1), and the three nests, all with tracker
  noise σ_t per coordinate;
* a validation run: ψ_k = 360°·k/N (+ N(0, 0.5°)) × repetitions, the mark within ±3 mm
  of the footprint centre, P_prev = P_at − d·heading, tracker noise, the mark's pixel
  position (rendered and located, or projected truth + 0.05 px noise).

Stress options: lateral path deviation between the heading positions, robot tilt at
use (optionally reported by the base), and the plate-definition nest bias of the
world itself (``WorldParams.nest_definition_bias_mm``). This is the one calibration
module that imports ``fakes``.
"""
from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from calibration.camera_model import CameraModel
from calibration.frames import apply_H, inv_H
from calibration.plate import NEST_NAMES, Plate
from fakes.path_shapes import SHAPES
from fakes.world import FloorMark, RobotPose, World


@dataclass
class SimConfig:
    """Every knob of one simulated experiment (mm, degrees, pixels)."""

    sigma_t_mm: float = 0.010
    move_mm: float = 200.0  # d: distance between the two heading positions
    directions: int = 8
    repetitions: int = 5
    heading_jitter_deg: float = 0.5
    mark_window_mm: float = 3.0  # the mark lands within ± this of the footprint centre
    render: bool = False
    size: tuple[int, int] = (1000, 750)
    mark_sigma_px: float = 0.05  # rendering-free mark localisation noise
    pnp_sigma_px: float = 0.0  # rendering-free calibration: 0 = exact cam_H_ref, else PnP on noisy corners
    path_sigma_mm: float = 0.0  # lateral deviation of P1 / P_prev
    tilt_sigma_mrad: float = 0.0  # robot roll and pitch at each validation stop
    report_tilt: bool = False  # the base reports its roll/pitch (inclinometer)
    mark: str = "M1"
    seed: int = 0
    pixel_format: str = "Mono8"  # rendered images: Mono8, or e.g. BayerRG8 (the colour sensor, fakes.colour)
    stream_points: int = 21  # tracker stream samples along each validation approach (error model only)
    imu_readings: int = 10  # inclinometer readings averaged at a standstill (1 s at 10 Hz)
    # this experiment's path shape (fakes/path_shapes.py), None: the world's (RobotErrors.path_shape); another
    # one is a robot whose path changed between experiments (after its weight was learned)
    path_shape: str | None = None

    def __post_init__(self) -> None:
        for name in ("sigma_t_mm", "mark_sigma_px", "pnp_sigma_px", "path_sigma_mm", "tilt_sigma_mrad",
                     "heading_jitter_deg", "mark_window_mm"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"SimConfig.{name} must be a finite value >= 0, got {v}")
        if self.path_shape is not None and self.path_shape not in SHAPES:
            raise ValueError(f"SimConfig.path_shape={self.path_shape!r} (known: {', '.join(SHAPES)})")
        if self.move_mm <= 0 or self.directions < 1 or self.repetitions < 1:
            raise ValueError(f"SimConfig: move_mm={self.move_mm}, directions={self.directions}, "
                             f"repetitions={self.repetitions} must all be positive")


@dataclass
class CalibrationObs:
    """One simulated referencing visit: observations plus truth."""

    heading_deg: float
    abs_P_nests: np.ndarray  # (3, 3) measured, red/green/blue
    abs_P_rob0: np.ndarray
    abs_P_rob1: np.ndarray
    cam_ref: Any  # exact 4x4 cam_H_ref, a CamRefPose, or None when ``image`` is set
    image: np.ndarray | None
    abs_H_rob_true: np.ndarray
    cam_H_ref_true: np.ndarray
    pixel_format: str = "Mono8"  # of ``image`` (a Bayer image is the raw mosaic)
    imu_deg: tuple[float, float] | None = None  # the inclinometer's roll, pitch at P0 (``report_tilt``)
    imu_sigma_deg: float | None = None  # that mean's 1σ from the readings' spread, as the worker states it


@dataclass
class MarkObs:
    """One validation stop: where the mark was seen and where the reflector was."""

    direction: int
    heading_deg: float  # true heading
    uv: np.ndarray  # (2,) located pixel position
    abs_P_prev: np.ndarray
    abs_P_at: np.ndarray
    roll_deg: float | None  # as reported by the base (None: no inclinometer)
    pitch_deg: float | None
    abs_H_rob_true: np.ndarray
    uv_true: np.ndarray
    # with the world's error model and ``SimConfig.stream_points``: the inclinometer at the previous
    # stop, and the tracker's stream along the approach with a reading of the inclinometer per point
    prev_roll_deg: float | None = None
    prev_pitch_deg: float | None = None
    stream: np.ndarray | None = None  # (N, 3) measured reflector positions, P_prev → P_at
    stream_tilt_deg: np.ndarray | None = None  # (N, 2) roll, pitch as reported


@dataclass
class ValidationSet:
    """All stops of one validation run and the true mark position (ACS)."""

    mark_abs: np.ndarray
    observations: list[MarkObs] = field(default_factory=list)


def _key(name: str) -> int:
    return int.from_bytes(hashlib.sha256(name.encode()).digest()[:4], "little")


class Simulation:
    """Calibration and validation observations drawn from one :class:`World`."""

    def __init__(self, world: World, config: SimConfig | None = None) -> None:
        self.world = world
        self.cfg = config or SimConfig()
        self.model = CameraModel(world.camera_matrix(self.cfg.size), world.dist_coeffs(), self.cfg.size)
        self.plate: Plate = world.plate()
        self._renderer: Any = None
        marks = {m.name: m for m in world.params.marks}
        if self.cfg.mark not in marks:
            raise ValueError(f"SimConfig.mark={self.cfg.mark!r} is not a world mark ({sorted(marks)})")
        self.mark: FloorMark = marks[self.cfg.mark]

    def rng(self, name: str) -> np.random.Generator:
        """Independent generator per stream, from the config seed and the world seed."""
        return np.random.default_rng([self.cfg.seed, self.world.params.seed, _key(name)])

    @property
    def renderer(self) -> Any:
        """The world's ray-cast renderer, built on first use (the ray cache is costly)."""
        if self._renderer is None:
            from drivers.pixel_formats import lookup
            from fakes.colour import ColourRenderer
            from fakes.render import Renderer

            colour = lookup(self.cfg.pixel_format).colour
            self._renderer = (ColourRenderer if colour else Renderer)(self.world, self.cfg.size)
        return self._renderer

    def camera_image(self, abs_H_cam: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """The rendered image in the configured pixel format, as the camera delivers it."""
        from fakes.colour import sensor_image

        return sensor_image(self.renderer, self.cfg.pixel_format, abs_H_cam, rng)

    def _tracker(self, P: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        if self.world.effects.model.tracker is not None:  # the world's AT901 model replaces sigma_t_mm
            return self.world.effects.tracker_measure_abs(np.asarray(P, dtype=float), rng)
        return np.asarray(P, dtype=float) + rng.normal(0.0, self.cfg.sigma_t_mm, size=np.shape(P))

    def _stop(self, pose: RobotPose, rng: np.random.Generator) -> tuple[RobotPose, np.ndarray, np.ndarray]:
        """With the world's error model: the robot settled on its wheels after a move of d to ``pose``.

        The move bends (fakes/errors.py RobotErrors: an arc, or an S) and ends at ``pose``
        ``bend`` to the side with the heading turned by δ (the S: 0), so the chord from the
        previous stop runs bend/d off the start heading (the arc: heading − δ/2);
        the config's ``path_sigma_mm`` adds an independent sideways offset of the previous
        stop. Returns the settled pose and the true reflector centres at both stops.
        """
        w, d = self.world, self.cfg.move_mm
        bend, turn = w.effects.bend(d, rng, self.cfg.path_shape)
        head = pose.heading_deg + turn
        a = math.radians(head - turn + math.degrees(math.atan2(bend, d)))  # the chord: bend/d off the start
        lateral = rng.normal(0.0, self.cfg.path_sigma_mm) if self.cfg.path_sigma_mm else 0.0
        prev = w.settle(RobotPose(pose.x_mm - d * math.cos(a) - lateral * math.sin(a),
                                  pose.y_mm - d * math.sin(a) + lateral * math.cos(a), head - turn))
        at = w.settle(RobotPose(pose.x_mm, pose.y_mm, head, pose.roll_rad, pose.pitch_rad))
        self._last_path = self._path(prev, at, turn, bend)
        return at, w.robot_reflector_abs(w.abs_H_rob(prev)), w.robot_reflector_abs(w.abs_H_rob(at))

    def _path(self, prev: RobotPose, at: RobotPose, turn_deg: float, bend_mm: float) -> list[RobotPose]:
        """Settled poses along the bent move prev → at, ends included (the shape: Effects.bend_profile).

        A circular arc that ends ``bend_mm`` to the side lies ``bend_mm·t·(1 − t)`` to the
        right of the chord for a left turn (to second order), ``t`` the fraction travelled.
        """
        n = max(2, self.cfg.stream_points)
        c = np.array([at.x_mm - prev.x_mm, at.y_mm - prev.y_mm])
        left = np.array([-c[1], c[0]]) / max(float(np.linalg.norm(c)), 1e-9)
        ts = np.linspace(0.0, 1.0, n)
        side, dh = self.world.effects.bend_profile(ts, bend_mm, self.cfg.move_mm, self.cfg.path_shape)
        out = []
        for t, s, h in zip(ts, side, dh):
            x, y = np.array([prev.x_mm, prev.y_mm]) + t * c + s * left
            out.append(self.world.settle(RobotPose(float(x), float(y), prev.heading_deg + turn_deg * t
                                                   + math.degrees(h))))
        out[0], out[-1] = prev, at
        return out

    # ------------------------------------------------------------------ calibration

    def calibration(self, heading_deg: float | None = None, stream: str = "calib") -> CalibrationObs:
        """A referencing visit at ``heading_deg`` (default: random) with the target centre in view."""
        w, cfg = self.world, self.cfg
        rng = self.rng(stream)
        if heading_deg is None:
            heading_deg = float(rng.uniform(-180.0, 180.0))
        pose0 = w.settle(w.pose_with_target_in_view(heading_deg))
        a = math.radians(heading_deg)
        lateral = rng.normal(0.0, cfg.path_sigma_mm) if cfg.path_sigma_mm else 0.0
        # (0, 0) without the error model
        bend, turn = w.effects.bend(cfg.move_mm, self.rng(stream + "-bend"), cfg.path_shape)
        lateral += bend
        pose1 = w.settle(RobotPose(pose0.x_mm + cfg.move_mm * math.cos(a) - lateral * math.sin(a),
                                   pose0.y_mm + cfg.move_mm * math.sin(a) + lateral * math.cos(a),
                                   heading_deg + turn))
        abs_H_rob0 = w.abs_H_rob(pose0)
        if not (w.on_plate(pose0.x_mm, pose0.y_mm) and w.on_plate(pose1.x_mm, pose1.y_mm)):
            raise ValueError(f"calibration at heading {heading_deg:.1f}°: the robot would leave the plate")
        abs_H_cam = abs_H_rob0 @ w.rob_H_cam
        cam_H_ref_true = inv_H(abs_H_cam) @ w.abs_H_ref
        nests_true = np.array([w.nests_seated_abs()[n] for n in NEST_NAMES])
        abs_P_nests = self._tracker(nests_true, rng)
        P0 = self._tracker(w.robot_reflector_abs(abs_H_rob0), rng)
        P1 = self._tracker(w.robot_reflector_abs(w.abs_H_rob(pose1)), rng)
        image = None
        cam_ref: Any = cam_H_ref_true
        if cfg.render:
            image = self.camera_image(abs_H_cam, self.rng(stream + "-image"))
            cam_ref = None
        elif cfg.pnp_sigma_px > 0:
            from calibration.target import pose_from_corners
            from fakes.render import true_corner_projections

            ids, uv = true_corner_projections(w, cfg.size, abs_H_cam)
            uv = uv + self.rng(stream + "-corners").normal(0.0, cfg.pnp_sigma_px, size=uv.shape)
            cam_ref = pose_from_corners(ids, uv, self.model, self.plate)
        imu = imu_sd = None
        if cfg.report_tilt:
            r = self._readings(pose0, self.rng(stream + "-imu"))
            imu = float(r[:, 0].mean()), float(r[:, 1].mean())
            # daemon/compute/inputs.py: hypot of the two spreads / sqrt(2n)
            imu_sd = float(np.hypot(*r.std(axis=0)) / math.sqrt(2 * len(r)))
        return CalibrationObs(heading_deg, abs_P_nests, P0, P1, cam_ref, image, abs_H_rob0, cam_H_ref_true,
                              cfg.pixel_format, imu, imu_sd)

    # ------------------------------------------------------------------ validation

    def validation(self, stream: str = "validation", psi0_deg: float = 0.0) -> ValidationSet:
        """The N-direction × repetitions run over the configured mark."""
        w, cfg = self.world, self.cfg
        rng = self.rng(stream)
        M = np.array([self.mark.x_mm, self.mark.y_mm, w.effects.floor_height(self.mark.x_mm, self.mark.y_mm)])
        imu_rng = self.rng(stream + "-imu")
        out = ValidationSet(M)
        for k in range(cfg.directions):
            for r in range(cfg.repetitions):
                psi = psi0_deg + 360.0 * k / cfg.directions + rng.normal(0.0, cfg.heading_jitter_deg)
                tx, ty = M[:2] + rng.uniform(-cfg.mark_window_mm, cfg.mark_window_mm, size=2)
                pose = w.pose_with_footprint_at(tx, ty, psi)
                if cfg.tilt_sigma_mrad:
                    pose.roll_rad, pose.pitch_rad = rng.normal(0.0, cfg.tilt_sigma_mrad * 1e-3, size=2)
                if w.on_plate(pose.x_mm, pose.y_mm):
                    raise ValueError(f"validation stop at ({pose.x_mm:.0f}, {pose.y_mm:.0f}) is on the "
                                     "plate; move the mark away from it")
                extra: dict[str, Any] = {}
                if w.effects.active:
                    pose, P_prev_true, P_at_true = self._stop(pose, rng)
                    abs_H_rob = w.abs_H_rob(pose)
                    extra = self._stream(self._last_path, f"{stream}-{k}-{r}")
                else:
                    abs_H_rob = w.abs_H_rob(pose)
                    a = math.radians(psi)
                    heading, left = (np.array([math.cos(a), math.sin(a), 0.0]),
                                     np.array([-math.sin(a), math.cos(a), 0.0]))
                    lateral = rng.normal(0.0, cfg.path_sigma_mm) if cfg.path_sigma_mm else 0.0
                    P_at_true = abs_H_rob[:3, 3]
                    P_prev_true = P_at_true - cfg.move_mm * heading + lateral * left
                P_at = self._tracker(P_at_true, rng)
                P_prev = self._tracker(P_prev_true, rng)
                abs_H_cam = abs_H_rob @ w.rob_H_cam
                uv_true = self.model.project(apply_H(inv_H(abs_H_cam), M)[None, :])[0]
                uv = self._locate(abs_H_cam, uv_true, rng, f"{stream}-{k}-{r}")
                roll = pitch = None
                if cfg.report_tilt:
                    roll, pitch = self._standstill_tilt(pose, imu_rng)
                out.observations.append(MarkObs(k, pose.heading_deg, uv, P_prev, P_at, roll, pitch, abs_H_rob,
                                                uv_true, **extra))
        return out

    def _stream(self, path: list[RobotPose], name: str) -> dict[str, Any]:
        """The tracker's stream along ``path`` and, with ``report_tilt``, the inclinometer per point."""
        w, rng = self.world, self.rng(name + "-stream")
        P = np.array([self._tracker(w.robot_reflector_abs(w.abs_H_rob(q)), rng) for q in path])
        out: dict[str, Any] = {"stream": P}
        if self.cfg.report_tilt:
            tilt = np.degrees([w.effects.inclinometer(q.roll_rad, q.pitch_rad, rng) for q in path])
            prev = self._standstill_tilt(path[0], rng)
            out.update(stream_tilt_deg=tilt, prev_roll_deg=prev[0], prev_pitch_deg=prev[1])
        return out

    def _readings(self, pose: RobotPose, rng: np.random.Generator) -> np.ndarray:
        """``imu_readings`` inclinometer readings (n, 2) at a stop (degrees), as the worker takes them."""
        return np.degrees([self.world.effects.inclinometer(pose.roll_rad, pose.pitch_rad, rng)
                           for _ in range(max(1, self.cfg.imu_readings))])

    def _standstill_tilt(self, pose: RobotPose, rng: np.random.Generator) -> tuple[float, float]:
        """The mean of ``imu_readings`` inclinometer readings at a stop (degrees), as the worker takes it."""
        r = self._readings(pose, rng)
        return float(r[:, 0].mean()), float(r[:, 1].mean())

    def _locate(self, abs_H_cam: np.ndarray, uv_true: np.ndarray, rng: np.random.Generator, name: str
                ) -> np.ndarray:
        if not self.cfg.render:
            return uv_true + rng.normal(0.0, self.cfg.mark_sigma_px, size=2)
        from calibration.image import to_grey
        from calibration.marks import locate_mark

        image = to_grey(self.camera_image(abs_H_cam, self.rng(name)), self.cfg.pixel_format)
        # the mark's size in pixels is known from its size and the camera height, as on the robot
        size_px = self.mark.size_mm * self.model.f / self.world.params.cam_height_mm
        return np.asarray(locate_mark(image, kind=self.mark.kind, size_px=size_px).uv, dtype=float).reshape(2)

    # ------------------------------------------------------------------ truth

    def true_bias(self, rob_H_scn: np.ndarray, scs: Any) -> np.ndarray:
        """Robot-frame xy error of a calibration's mark mapping at the footprint centre (mm)."""
        w = self.world
        p = w.params
        rob_P = np.array([*p.cam_footprint_mm, -p.reflector_height_mm])
        uv = self.model.project(apply_H(inv_H(w.rob_H_cam), rob_P)[None, :])
        scn_xy = scs.image_to_scn(uv)[0]
        est = apply_H(rob_H_scn, np.array([scn_xy[0], scn_xy[1], 0.0]))
        return (est - rob_P)[:2]
