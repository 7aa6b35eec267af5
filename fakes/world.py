"""The simulated world: one ground truth shared by every fake device.

Frames (millimetres, right-handed, as in the paper):

* ACS (``abs``): floor plane z = 0, z up.
* tracker (``trk``): the laser tracker's own frame; ``abs_H_trk`` places it in ACS.
  The fake tracker reports coordinates in this frame, like the real one.
* PCS (``ref``): the referencing plate. Origin at the ChArUco board's first corner,
  x along board columns, y along board rows, z *into* the plate (the OpenCV board
  frame). The target surface is the plate's top face, ``plate_thickness_mm`` above
  the floor.
* RCS (``rob``): origin at the robot's reflector (SMR) centre, x = driving direction,
  z = normal of the support plane (up), ``reflector_height_mm`` above the support.
* CCS (``cam``): OpenCV camera frame (x right, y down, z along the optical axis).

Every parameter lives in :class:`WorldParams`; all randomness comes from named child
generators of one seed (:meth:`World.rng`), so each fake is deterministic on its own,
whatever order the others draw in. The world is shared between threads (tracker
server, robot pty loop, camera renderer): state changes go through ``self.lock``.
"""
from __future__ import annotations

import hashlib
import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from calibration.frames import apply_H, inv_H, make_H, rot_x, rot_y, rot_z
from fakes.effects import Effects
from fakes.errors import ErrorModel

if TYPE_CHECKING:
    from calibration.plate import Plate

NEST_NAMES = ("red", "green", "blue")


@dataclass
class FloorMark:
    """A mark printed on the floor (ACS xy, mm)."""

    name: str
    x_mm: float
    y_mm: float
    kind: str = "dot"  # "dot" (dark disc) or "cross" (checker X-junction)
    size_mm: float = 0.4  # dot radius, or half-size of the cross square


@dataclass
class WorldParams:
    """Every knob of the simulated world. Defaults: docs/accuracy.md, "The nominal world"."""

    seed: int = 1

    # --- referencing plate (truth) ---
    board_cols: int = 40
    board_rows: int = 30
    square_mm: float = 2.0
    marker_mm: float = 1.5
    aruco_dict: str = "DICT_5X5_1000"
    nest_side_mm: float = 400.0  # equilateral triangle of the three nests
    smr_offset_mm: float = 19.05  # delta: SMR centre above the nest seat plane (1.5" SMR)
    plate_thickness_mm: float = 19.0
    plate_half_size_mm: float = 550.0  # square plate around the board centre
    plate_xy_mm: tuple[float, float] = (1000.0, 800.0)  # board centre in ACS
    plate_yaw_deg: float | None = None  # None: drawn from the seed
    #: error of the plate *definition* (nominal nest PCS coords) vs truth, mm, per nest
    nest_definition_bias_mm: tuple[tuple[float, float, float], ...] = ((0, 0, 0),) * 3
    #: survey patches near the nests (calibration/patches.py, docs/operations.md "Plate survey")
    survey_patches: bool = True

    # --- robot and camera mount (truth) ---
    reflector_height_mm: float = 350.0
    cam_footprint_mm: tuple[float, float] = (200.0, 50.0)  # in RCS xy
    cam_height_mm: float = 30.0  # optical centre above the support plane
    cam_yaw_deg: float = 17.0
    cam_tilt_deg: tuple[float, float] = (1.2, -0.8)  # off-nadir about camera x / y

    # --- camera intrinsics (full sensor; the reduced size scales them) ---
    full_size: tuple[int, int] = (4024, 3036)
    reduced_size: tuple[int, int] = (1000, 750)
    full_focal_px: float = 470.0 * 4024 / 1000
    principal_offset_px: tuple[float, float] = (1.6 * 4.024, -1.0 * 4.024)
    distortion: tuple[float, float, float, float, float] = (-0.12, 0.03, 4e-4, -3e-4, 0.0)

    # --- imaging (fakes/render.py) ---
    psf_sigma_px: float = 0.7  # at the reduced size; scales with resolution
    read_noise_dn: float = 1.5
    shot_gain: float = 0.05
    black_dn: float = 25.0
    white_dn: float = 215.0
    vignetting: float = 0.25
    supersampling: int = 3

    # --- tracker ---
    tracker_sigma_mm: float = 0.010
    tracker_xyz_mm: tuple[float, float, float] = (-2500.0, 1500.0, 1200.0)  # station in ACS
    tracker_yaw_deg: float = 30.0

    # --- robot drive and floor ---
    start_pose: tuple[float, float, float] | None = None  # x, y, heading_deg; None: on the plate
    drive_scale_error: float = 0.0  # relative error of travelled distance
    drive_heading_sigma_deg: float = 0.0  # heading error per move/turn
    drive_lateral_sigma_mm: float = 0.0  # lateral path deviation per move
    floor_tilt_sigma_mrad: float = 0.0  # random roll/pitch of the robot at each stop
    base_has_inclinometer: bool = False

    #: error model (fakes/errors.py); the default, every effect off, is the ideal world
    errors: ErrorModel = field(default_factory=ErrorModel)

    marks: tuple[FloorMark, ...] = field(
        default_factory=lambda: (FloorMark("M1", 2200.0, 1400.0, "dot", 0.4),
                                 FloorMark("M2", 2600.0, 1100.0, "cross", 0.6)))

    def with_(self, **changes: Any) -> "WorldParams":
        return replace(self, **changes)


@dataclass
class RobotPose:
    """Ground-truth pose of the robot's support point (under the reflector)."""

    x_mm: float
    y_mm: float
    heading_deg: float
    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    #: support-plane height under the reflector; None: the flat support (plate or floor)
    z_mm: float | None = None


class World:
    """Ground truth plus the mutable robot pose; safe to share between threads."""

    def __init__(self, params: WorldParams | None = None) -> None:
        self.params = p = params or WorldParams()
        self.lock = threading.RLock()
        self.effects = Effects(self)
        yaw = p.plate_yaw_deg
        if yaw is None:
            yaw = float(self.rng("plate").uniform(-180.0, 180.0))
        self.plate_yaw_deg = yaw
        # abs_H_ref: PCS z points into the plate, so flip about x; the board centre sits
        # at plate_xy on the top face.
        R = rot_z(math.radians(yaw)) @ rot_x(math.pi)
        centre_ref = np.array([p.board_cols * p.square_mm / 2, p.board_rows * p.square_mm / 2, 0.0])
        t = np.array([*p.plate_xy_mm, p.plate_thickness_mm]) - R @ centre_ref
        self.abs_H_ref = self.effects.place_plate(make_H(R, t, "abs_H_ref"), R @ centre_ref + t)
        self.abs_H_trk = make_H(rot_z(math.radians(p.tracker_yaw_deg)), p.tracker_xyz_mm, "abs_H_trk")
        self.rob_H_cam = self._true_rob_H_cam()
        self.held_board: Any = None  # a fakes.board.HeldBoard while the operator holds one (sim.hold_board)
        if p.start_pose is None:
            self.robot = self.pose_with_target_in_view(heading_deg=yaw + 60.0)
        else:
            self.robot = RobotPose(*p.start_pose)
        self.robot = self.settle(self.robot)
        #: recent (monotonic time, pose) of the robot, so a tracker stream sees it where it was when
        #: each record was taken, not where it is when the packet goes out (the base moves between)
        self.robot_track: deque[tuple[float, RobotPose]] = deque([(time.monotonic(), self.robot)],
                                                                 maxlen=2000)
        #: the base's pose as a function of time during a motion (fakes/robot_base.py ``FakeBase.pose_at``),
        #: asked first by robot_at: the track only holds the poses the base set when it was ticked
        self.pose_source: Callable[[float], RobotPose | None] | None = None

    # ------------------------------------------------------------------ randomness

    def rng(self, name: str) -> np.random.Generator:
        """A generator for one consumer, independent of every other consumer."""
        return self.rng_for(self.params.seed, name)

    @staticmethod
    def rng_for(seed: int, name: str) -> np.random.Generator:
        """:meth:`rng` before a world exists (profiles draw their parameters from the seed)."""
        key = int.from_bytes(hashlib.sha256(name.encode()).digest()[:4], "little")
        return np.random.default_rng(np.random.SeedSequence([seed, key]))

    # ------------------------------------------------------------------ plate

    def board_centre_ref(self) -> np.ndarray:
        p = self.params
        return np.array([p.board_cols * p.square_mm / 2, p.board_rows * p.square_mm / 2, 0.0])

    def nests_ref_true(self) -> dict[str, np.ndarray]:
        """True SMR centres in PCS when seated in each nest (z = −delta: above the surface)."""
        p = self.params
        c = self.board_centre_ref()
        r = p.nest_side_mm / math.sqrt(3.0)
        out = {}
        # red, green, blue counter-clockwise in PCS xy; PCS z points down, so seen from
        # above they run clockwise and (Pb−Pr)×(Pg−Pr) points up in ACS.
        for name, a in zip(NEST_NAMES, (90.0, 210.0, 330.0)):
            out[name] = c + np.array([r * math.cos(math.radians(a)), r * math.sin(math.radians(a)),
                                      -p.smr_offset_mm])
        return out

    def nests_ref_nominal(self) -> dict[str, np.ndarray]:
        """Nest positions as the plate *definition* states them (truth + definition bias)."""
        bias = np.asarray(self.params.nest_definition_bias_mm, dtype=float)
        return {n: P + bias[i] for i, (n, P) in enumerate(self.nests_ref_true().items())}

    def plate(self, plate_id: str = "SIM-PLATE-1") -> "Plate":
        """The plate definition a user would load: nominal nest seats (may carry a bias)."""
        from calibration.plate import Plate

        p = self.params
        seats = {n: (P + [0, 0, p.smr_offset_mm]).tolist() for n, P in self.nests_ref_nominal().items()}
        return Plate(plate_id, p.board_cols, p.board_rows, p.square_mm, p.marker_mm, p.aruco_dict,
                     seats, p.smr_offset_mm, notes="simulated plate", patches=self.patch_layout())

    def patch_layout(self) -> list[dict[str, Any]]:
        """The survey patches as printed (a design value, exact in this world), or [] without them."""
        from calibration.patches import default_patches

        p = self.params
        if not p.survey_patches:
            return []
        first = (p.board_cols * p.board_rows) // 2  # after the main board's marker ids
        return [q.to_dict() for q in default_patches(self.nests_ref_true(), self.board_centre_ref(), first)]

    def nests_abs(self) -> dict[str, np.ndarray]:
        return {n: apply_H(self.abs_H_ref, P) for n, P in self.nests_ref_true().items()}

    def on_plate(self, x_mm: float, y_mm: float) -> bool:
        """Is the floor point (x, y) covered by the plate?"""
        q = apply_H(inv_H(self.abs_H_ref), [x_mm, y_mm, self.params.plate_thickness_mm])
        c = self.board_centre_ref()
        h = self.params.plate_half_size_mm
        return bool(abs(q[0] - c[0]) <= h and abs(q[1] - c[1]) <= h)

    # ------------------------------------------------------------------ robot

    def _true_rob_H_cam(self) -> np.ndarray:
        p = self.params
        R = (rot_z(math.radians(p.cam_yaw_deg)) @ rot_x(math.pi)
             @ rot_x(math.radians(p.cam_tilt_deg[0])) @ rot_y(math.radians(p.cam_tilt_deg[1])))
        # place the optical centre so that the optical axis hits the floor at the footprint
        h = p.cam_height_mm
        axis = R[:, 2]
        foot = np.array([*p.cam_footprint_mm, -p.reflector_height_mm])
        centre = foot - axis * (h / -axis[2])
        return make_H(R, centre, "rob_H_cam")

    def support_height(self, x_mm: float, y_mm: float) -> float:
        if self.effects.settles:
            return self.effects.support_height(x_mm, y_mm, self.on_plate(x_mm, y_mm))
        return self.params.plate_thickness_mm if self.on_plate(x_mm, y_mm) else 0.0

    def settle(self, pose: RobotPose) -> RobotPose:
        """``pose`` on its wheels: roll, pitch and height from the surface (unchanged when flat)."""
        return self.effects.settle(pose)

    def robot_reflector_abs(self, abs_H_rob: np.ndarray) -> np.ndarray:
        """Where the robot's SMR centre really is (the RCS origin plus its mount offset)."""
        return self.effects.robot_reflector(abs_H_rob)

    def nests_seated_abs(self) -> dict[str, np.ndarray]:
        """Reflector centres as seated in the nests now (true seats plus seating offsets)."""
        off = self.effects.nest_offsets
        return {n: P + off[n] if n in off else P for n, P in self.nests_abs().items()}

    def abs_H_rob(self, pose: RobotPose | None = None) -> np.ndarray:
        """True robot pose: reflector origin, x = heading, z = support normal."""
        with self.lock:
            r = pose or self.robot
            R = rot_z(math.radians(r.heading_deg)) @ rot_y(r.pitch_rad) @ rot_x(r.roll_rad)
            z = self.support_height(r.x_mm, r.y_mm) if r.z_mm is None else r.z_mm
            ground = np.array([r.x_mm, r.y_mm, z])
            return make_H(R, ground + R @ [0, 0, self.params.reflector_height_mm], "abs_H_rob")

    def abs_H_cam(self) -> np.ndarray:
        return self.abs_H_rob() @ self.rob_H_cam

    def pose_with_target_in_view(self, heading_deg: float) -> RobotPose:
        """A pose on the plate at ``heading_deg`` whose camera footprint is the board centre."""
        target = apply_H(self.abs_H_ref, self.board_centre_ref())
        return self.pose_with_footprint_at(target[0], target[1], heading_deg)

    def pose_with_footprint_at(self, x_mm: float, y_mm: float, heading_deg: float) -> RobotPose:
        fx, fy = self.params.cam_footprint_mm
        a = math.radians(heading_deg)
        return RobotPose(x_mm - (math.cos(a) * fx - math.sin(a) * fy),
                         y_mm - (math.sin(a) * fx + math.cos(a) * fy), heading_deg)

    def set_robot(self, pose: RobotPose) -> None:
        with self.lock:
            self.robot = pose
            self.robot_track.append((time.monotonic(), pose))

    def robot_at(self, t: float) -> RobotPose:
        """The robot's pose at monotonic time ``t``: from the base's motion when one covers ``t``
        (:attr:`pose_source`), else linear between the poses the base set around it."""
        source = self.pose_source
        if source is not None and (pose := source(t)) is not None:
            return pose
        with self.lock:
            track, now = list(self.robot_track), self.robot
        if t >= track[-1][0] or track[-1][1] is not now:  # a pose set directly (tests) is the pose now
            return now
        if t <= track[0][0]:
            return track[0][1]
        i = next(j for j in range(len(track) - 1, 0, -1) if track[j - 1][0] <= t)
        (ta, a), (tb, b) = track[i - 1], track[i]
        f = 0.0 if tb <= ta else (t - ta) / (tb - ta)
        mix = lambda u, v: u + f * (v - u)  # noqa: E731
        z = None if a.z_mm is None or b.z_mm is None else mix(a.z_mm, b.z_mm)
        heading = a.heading_deg + f * math.remainder(b.heading_deg - a.heading_deg, 360.0)  # across ±180°
        return RobotPose(mix(a.x_mm, b.x_mm), mix(a.y_mm, b.y_mm), heading,
                         mix(a.roll_rad, b.roll_rad), mix(a.pitch_rad, b.pitch_rad), z)

    def robot_reflector_trk_at(self, t: float) -> np.ndarray:
        """The robot's reflector in the tracker frame at monotonic time ``t``."""
        return apply_H(inv_H(self.abs_H_trk), self.robot_reflector_abs(self.abs_H_rob(self.robot_at(t))))

    def hold_board(self, **pose: Any) -> dict[str, Any]:
        """The operator holds the calibration board at a pose relative to the camera (fakes/board.py)."""
        from fakes.board import hold

        return hold(self, **pose)

    def reflectors_abs(self) -> dict[str, np.ndarray]:
        """Every reflector the tracker could lock onto (ACS)."""
        with self.lock:
            out = {"robot": self.robot_reflector_abs(self.abs_H_rob())}
        out.update(self.nests_seated_abs())
        return out

    def reflectors_trk(self) -> dict[str, np.ndarray]:
        trk_H_abs = inv_H(self.abs_H_trk)
        return {n: apply_H(trk_H_abs, P) for n, P in self.reflectors_abs().items()}

    # ------------------------------------------------------------------ camera

    def camera_matrix(self, size: tuple[int, int]) -> np.ndarray:
        """Intrinsics for an image of ``size`` (same field of view as the full sensor)."""
        p = self.params
        s = size[0] / p.full_size[0]
        f = p.full_focal_px * s
        cx = (size[0] - 1) / 2 + p.principal_offset_px[0] * s
        cy = (size[1] - 1) / 2 + p.principal_offset_px[1] * s
        return np.array([[f, 0, cx], [0, f, cy], [0, 0, 1.0]])

    def dist_coeffs(self) -> np.ndarray:
        return np.array(self.params.distortion, dtype=float)

    def truth(self) -> dict[str, Any]:
        """Ground truth for reports and tests (lists, JSON-able)."""
        with self.lock:
            out = {
                "rob_H_cam": self.rob_H_cam.tolist(),
                "abs_H_ref": self.abs_H_ref.tolist(),
                "abs_H_trk": self.abs_H_trk.tolist(),
                "abs_H_rob": self.abs_H_rob().tolist(),
                "nests_abs": {k: v.tolist() for k, v in self.nests_abs().items()},
                "marks": [{"name": m.name, "x_mm": m.x_mm, "y_mm": m.y_mm, "kind": m.kind}
                          for m in self.params.marks],
            }
            if self.effects.active:  # the ideal world's truth stays as it was
                out["errors"] = self.effects.truth()
                out["robot_reflector_abs"] = self.robot_reflector_abs(self.abs_H_rob()).tolist()
                out["nests_seated_abs"] = {k: v.tolist() for k, v in self.nests_seated_abs().items()}
                for m in out["marks"]:
                    m["z_mm"] = self.effects.floor_height(m["x_mm"], m["y_mm"])
            return out
