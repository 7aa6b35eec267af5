"""Compensations of a real robot's error sources at use (docs/accuracy.md).

Each compensation is switchable (:class:`Compensation`) and every result names the ones
applied. None of them changes the paper's equations; they change their inputs:

* **tilt** — the base's inclinometer gives roll and pitch at every stop. Its mounting
  offset is calibrated at referencing, where the robot stands on the plate whose normal
  the tracker measured (:func:`imu_offset_deg`): reading − plate tilt. At use the tilt
  (reading − offset) rotates the robot frame about its own axes, and the approach
  direction is taken between *ground points* (the reflector moved down the robot's
  tilted z axis by the reflector height): the reflector sits ~0.35 m above the floor,
  so 1 mrad of tilt moves it 0.35 mm sideways, which bends a 200 mm chord by 1.7 mrad.
* **heading_fit** — the chord P_prev→P_at is off the final heading by half the path's
  turn; the end tangent of a curve fitted to the tracker's stream along the approach
  (calibration/bend_fit.py) turns it by the share of the fitted slope an earlier experiment
  showed to make its marks agree (calibration/heading_weight.py; without one, by the whole
  slope when the stop's own bend is significant).

Each result also says how well its heading is known beyond the two tracker points
(``Applied.sigma_heading_rad``, for :func:`calibration.measure.measure_mark`; from what:
``heading_sigma_basis``).
* **mount** — the reflector mount's eccentricity, measured by the referencing's reversal
  (calibration/mount.py): fixed relative to the line of sight to the tracker, so the same in
  ACS at every heading; subtracted from the stop's tracker points when the data showed it.
* **bias** — the robot-frame bias b of an earlier 8-direction experiment
  (calibration/metrics.py ``fit_bias``: cluster means M_k = M + R(ψ_k)·b) is removed
  from ``rob_H_scn`` (:func:`apply_bias`). Right for what is fixed in the robot frame
  (calibration error of rob_H_cam, an inclinometer offset left after the plate); wrong
  for what is fixed in ACS (the reflector mount's eccentricity toward the tracker stays).

Angles follow the world's and :func:`calibration.measure.robot_pose_at`'s convention
``R = R_z(ψ) · R_y(pitch) · R_x(roll)``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping

import numpy as np

from calibration.bend_fit import MIN_FIT_POINTS, bend_fit, chord_sigma, fit_heading_sigma
from calibration.checks import stream_ends_check, stream_tilt_check
from calibration.frames import check_H, rot_x, rot_y, rot_z
from calibration.heading_weight import MODELS, HeadingWeight, weighted_slope
from calibration.imu_mount import body_tilt, rot2
from calibration.measure import CHORD_HEADING_SIGMA_RAD
from calibration.mount import MountOffset
from calibration.registration import as_points

#: the compensations built into :func:`compensate`, in the order results list them
BUILT_IN = ("tilt", "heading_fit", "bias", "mount")

#: a compensation added by registration (:func:`register`): it applies itself to the stop's
#: :class:`Applied` (its name appended to ``applied``) or says in ``skipped`` why not. It runs after the
#: built-in ones, so it sees what they applied, and reads its inputs from the calibration document.
Step = Callable[["Applied", "Stop", Mapping[str, Any]], None]
#: the registered compensations, in the order they run and results list them
STEPS: dict[str, Step] = {}


def register(name: str) -> Callable[[Step], Step]:
    """Decorator: ``step`` is the compensation ``name`` (docs/architecture.md, "Add a compensation")."""
    def add(step: Step) -> Step:
        if name in BUILT_IN or name in STEPS:
            raise ValueError(f"compensation {name!r} is registered twice")
        STEPS[name] = step
        return step
    return add


def names_known() -> tuple[str, ...]:
    """Every compensation name, built in and registered, in the order results list them."""
    return BUILT_IN + tuple(STEPS)


@dataclass(frozen=True)
class Compensation:
    """Which compensations to apply (all off = the paper's method)."""

    tilt: bool = False
    heading_fit: bool = False
    bias: bool = False
    mount: bool = False
    registered: frozenset[str] = frozenset()  # the registered ones (STEPS) asked for

    @classmethod
    def parse(cls, value: Any) -> "Compensation":
        """From a config/params value: None/False/"none", True/"all", or names (list or comma string)."""
        if value is None or value is False or value == "none" or value == []:
            return cls()
        known = names_known()
        names = list(known) if value is True or value == "all" else \
            [s.strip() for s in value.split(",")] if isinstance(value, str) else list(value)
        unknown = [n for n in names if n not in known]
        if unknown:
            raise ValueError(f"unknown compensation(s) {unknown} "
                             f"(known: {', '.join(known)}, or 'all'/'none')")
        chosen = {n: True for n in names if n in BUILT_IN}
        return cls(**chosen, registered=frozenset(n for n in names if n in STEPS))

    def names(self) -> list[str]:
        return [n for n in BUILT_IN if getattr(self, n)] + [n for n in STEPS if n in self.registered]


def tilt_of_pose(abs_H_rob: np.ndarray) -> tuple[float, float]:
    """(roll, pitch) in degrees of a robot pose, ``R = R_z(ψ)·R_y(pitch)·R_x(roll)``."""
    R = check_H(abs_H_rob, "abs_H_rob")[:3, :3]
    pitch = -math.asin(max(-1.0, min(1.0, float(R[2, 0]))))
    roll = math.atan2(float(R[2, 1]), float(R[2, 2]))
    return math.degrees(roll), math.degrees(pitch)


def imu_offset_deg(abs_H_rob_ref: np.ndarray, roll_deg: float, pitch_deg: float) -> tuple[float, float]:
    """Inclinometer offset: its reading on the plate minus the plate-derived tilt of the robot."""
    for name, a in (("roll_deg", roll_deg), ("pitch_deg", pitch_deg)):
        if not np.isfinite(a) or abs(a) > 10:
            raise ValueError(f"imu_offset_deg: {name}={a} is not a plausible inclinometer reading "
                             f"(|a| <= 10°)")
    roll_ref, pitch_ref = tilt_of_pose(abs_H_rob_ref)
    return roll_deg - roll_ref, pitch_deg - pitch_ref


def body_z(heading_deg: float, roll_deg: float, pitch_deg: float) -> np.ndarray:
    """The robot's z axis in ACS for a heading and a tilt."""
    R = rot_z(math.radians(heading_deg)) @ rot_y(math.radians(pitch_deg)) @ rot_x(math.radians(roll_deg))
    return R[:, 2]


def ground_point(abs_P_refl: Any, heading_deg: float, roll_deg: float, pitch_deg: float,
                 height_mm: float) -> np.ndarray:
    """The point ``height_mm`` below the reflector along the robot's tilted z axis (on the floor)."""
    P = as_points(abs_P_refl, "abs_P_refl", 1)[0]
    return P - height_mm * body_z(heading_deg, roll_deg, pitch_deg)


def reflector_height_mm(rob_H_scn: np.ndarray) -> float:
    """Reflector height above the surface the robot stands on: the SCS plane's distance in RCS."""
    H = check_H(rob_H_scn, "rob_H_scn")
    h = -float(H[:3, 3] @ H[:3, 2])
    if not 0.0 < h < 5000.0:
        raise ValueError(f"reflector_height_mm: the SCS plane lies {h:.1f} mm below the reflector; "
                         "expected a positive height (is rob_H_scn from a referencing result?)")
    return h


def ground_chord(abs_P_prev: Any, abs_P_at: Any, tilt_prev: tuple[float, float], tilt_at: tuple[float, float],
                 height_mm: float, reverse: bool = False) -> np.ndarray:
    """An equivalent ``abs_P_prev`` whose chord to ``abs_P_at`` runs between the two ground points.

    ``reverse``: the move ran backwards, so the robot's x axis (which orients the tilt) is
    the travel's opposite; the equivalent point then lies ahead of the travel, so that
    ``abs_P_at − result`` is still the robot's x axis.
    """
    P_prev = as_points(abs_P_prev, "abs_P_prev", 1)[0]
    P_at = as_points(abs_P_at, "abs_P_at", 1)[0]
    sign = -1.0 if reverse else 1.0
    v = P_at - P_prev
    for _ in range(2):  # the heading only orients the tilt: one refinement takes its error to 2nd order
        heading = math.degrees(math.atan2(sign * v[1], sign * v[0]))
        v = (ground_point(P_at, heading, *tilt_at, height_mm)
             - ground_point(P_prev, heading, *tilt_prev, height_mm))
    return P_at - sign * v


def forward_prev(abs_P_prev: Any, abs_P_at: Any, reverse: bool) -> np.ndarray:
    """The approach's start as the paper's equations want it: ``P_at − result`` along the robot's x axis."""
    P_prev = as_points(abs_P_prev, "abs_P_prev", 1)[0]
    P_at = as_points(abs_P_at, "abs_P_at", 1)[0]
    return 2.0 * P_at - P_prev if reverse else P_prev


def apply_bias(rob_H_scn: np.ndarray, b_mm: Any) -> np.ndarray:
    """``rob_H_scn`` with the robot-frame bias b (RCS x, y, mm) removed from what it maps."""
    H = check_H(rob_H_scn, "rob_H_scn").copy()
    b = np.asarray(b_mm, dtype=float).reshape(-1)
    if b.shape != (2,) or not np.all(np.isfinite(b)):
        raise ValueError(f"apply_bias: b must be 2 finite values (mm), got {b.tolist()}")
    if np.hypot(*b) > 5.0:
        raise ValueError(f"apply_bias: |b| = {np.hypot(*b):.3f} mm is not a plausible calibration bias "
                         f"(<= 5 mm)")
    H[:2, 3] -= b
    return H


@dataclass
class Stop:
    """What one stop provides: the approach's two reflector points, tilt readings, the stream."""

    abs_P_prev: np.ndarray
    abs_P_at: np.ndarray
    tilt_prev: tuple[float, float] | None = None  # inclinometer roll, pitch (deg) as read
    tilt_at: tuple[float, float] | None = None
    stream: np.ndarray | None = None  # (N, 3) reflector positions along the approach, in time order
    stream_tilt: np.ndarray | None = None  # (N, 2) readings per stream point
    reverse: bool = False  # the final move ran backwards (MOVE < 0): the robot's x axis is P_prev − P_at


@dataclass
class Applied:
    """The inputs of :func:`calibration.measure.measure_mark` after compensation, and the record."""

    abs_P_prev: np.ndarray  # an equivalent previous point: the heading is P_at − abs_P_prev
    abs_P_at: np.ndarray  # the stop's point as measure_mark takes it (the mount's offset removed)
    roll_deg: float | None
    pitch_deg: float | None
    rob_H_scn: np.ndarray
    applied: list[str]
    skipped: dict[str, str]
    #: the heading's 1σ beyond the two tracker points (rad) and where it comes from ("chord", "heading_fit")
    sigma_heading_rad: float = CHORD_HEADING_SIGMA_RAD
    heading_source: str = "chord"
    #: what it rests on: "a_priori" (the chord's 250 µrad path deviation), "stop_fit" (the chord, from the
    #: stop's own fit), "fit" (the fit's σ), "weight" (the weight's σ); the last three with the end's misfit
    heading_sigma_basis: str = "a_priori"
    #: ACS xy covariance (mm²) the reflector mount leaves in the mark (calibration/mount.py), None: no
    #: estimate
    cov_mount_xy_mm2: np.ndarray | None = None
    #: heading_fit asked for: the chord's equivalent previous point and, per bend model whose fit succeeded
    #: (calibration/heading_weight.py MODELS), the whole fitted slope's (point, slope, its stated σ in rad),
    #: whatever was applied; an experiment learns the weight from them
    chord_P_prev: np.ndarray | None = None
    fits: dict[str, tuple[np.ndarray, float, float]] = field(default_factory=dict)


def _standstill_tilts(stop: Stop) -> tuple[tuple[float, float], tuple[float, float]]:
    """``(tilt_prev, tilt_at)`` of a stop whose tilt is compensated (:func:`compensate` checked both are
    there)."""
    if stop.tilt_prev is None or stop.tilt_at is None:
        raise ValueError("the tilt is compensated at a stop without both inclinometer readings (tilt_prev, "
                         "tilt_at)")
    return stop.tilt_prev, stop.tilt_at


def _ground_stream(stop: Stop, offset: tuple[float, float], height_mm: float, yaw_deg: float = 0.0
                   ) -> np.ndarray:
    """The stream's points moved down the tilted z axis, with the inclinometer read along the stream."""
    tilt_prev, tilt_at = _standstill_tilts(stop)
    P = as_points(stop.stream, "stream")
    s = np.linalg.norm(P[:, :2] - P[0, :2], axis=1)
    t = (np.asarray(stop.stream_tilt, dtype=float) - np.asarray(offset)) @ rot2(yaw_deg).T
    if t.shape != (len(P), 2):
        raise ValueError(f"stream_tilt must be (N, 2) = ({len(P)}, 2) readings, got {t.shape}")
    # the floor's tilt changes smoothly along a 0.2 m move, the inclinometer's noise is white: the
    # tilt is the line between the two standstill means (10 readings each) plus one quadratic bump
    # fitted to the readings taken while moving, which keeps the shape and averages the noise
    t0 = np.asarray(body_tilt(tilt_prev, offset, yaw_deg))
    t1 = np.asarray(body_tilt(tilt_at, offset, yaw_deg))
    L = max(float(s[-1]), 1e-9)
    line = t0 + np.outer(s / L, t1 - t0)
    g = s * (s - L)
    a = (g @ (t - line)) / max(float(g @ g), 1e-18)
    t = line + np.outer(g, a)
    v = (P[0] - P[-1]) if stop.reverse else (P[-1] - P[0])  # the robot's x axis orients the tilt
    heading = math.degrees(math.atan2(v[1], v[0]))
    return np.array([ground_point(p, heading, float(r), float(q), height_mm) for p, (r, q) in zip(P, t)])


#: why heading_fit is skipped when the tilt is compensated but was not read along the stream
NO_STREAM_TILT = ("the inclinometer was not read along the stream: the reflector's lean (tilt × height, "
                  "which the floor changes along the move) would read as a bend; the ground chord is used")


#: why heading_fit is skipped when the tilt is not compensated but the floor's tilt changes along the move
LEAN_NOT_COMPENSATED = ("the tilt is not compensated and the reflector's lean changes by {lean:.0f} µm "
                        "across the move (inclinometer {d:.4f}° × {h:.0f} mm): a bend fit would read the "
                        "lean as a turn; the chord is used")


def _tilt_applied(out: Applied, stop: Stop, P_prev: np.ndarray, P_at: np.ndarray, offset: tuple[float, float],
                  height: float, yaw: float) -> None:
    tilt_prev, tilt_at = _standstill_tilts(stop)
    at, prev = body_tilt(tilt_at, offset, yaw), body_tilt(tilt_prev, offset, yaw)
    out.roll_deg, out.pitch_deg = at
    out.abs_P_prev = ground_chord(P_prev, P_at, prev, at, height, stop.reverse)
    out.applied.append("tilt")


def _heading_fit(out: Applied, stop: Stop, P_prev: np.ndarray, P_at: np.ndarray, offset: tuple[float, float],
                 height: float, anchor_sigma_mm: float, yaw: float, weight: HeadingWeight | None) -> None:
    """The end tangent of the stream's bend: the calibration's learned ``weight`` of the fitted slope
    (calibration/heading_weight.py), or without one the whole slope only when the bend is shown
    (calibration/bend_fit.py)."""
    use_tilt = "tilt" in out.applied
    pts = _ground_stream(stop, offset, height, yaw) if use_tilt else as_points(stop.stream, "stream")
    sign = -1.0 if stop.reverse else 1.0
    if use_tilt:  # into the frame of the equivalent chord: the ground point at the stop sits at P_at
        v = sign * (P_at - P_prev)
        at = body_tilt(_standstill_tilts(stop)[1], offset, yaw)
        pts = pts + (P_at - ground_point(P_at, math.degrees(math.atan2(v[1], v[0])), *at, height))
    start = P_at - sign * (P_at - out.abs_P_prev)  # the travel's start of the (ground) chord
    try:
        fits = {m: bend_fit(pts, start, P_at, anchor_sigma_mm, min_degree=d) for m, d in MODELS.items()}
    except ValueError as exc:  # too few points between the stops: the chord stays
        out.skipped["heading_fit"] = str(exc)
        return
    length = float(np.linalg.norm((P_at - out.abs_P_prev)[:2]))
    u = sign * (P_at - out.abs_P_prev)[:2] / length
    n = np.array([-u[1], u[0]])

    def prev_at(slope: float) -> np.ndarray:  # the equivalent previous point of the chord turned by slope
        t = (u + slope * n) / np.hypot(1.0, slope)
        return np.asarray(P_at - sign * length * np.array([t[0], t[1], 0.0]))

    out.chord_P_prev = out.abs_P_prev
    out.fits = {m: (prev_at(f.slope_rad), f.slope_rad, f.sigma_rad) for m, f in fits.items()
                if f.shape != "other"}
    fit = fits[weight.model if weight is not None else "lowest"]
    if weight is not None:
        slope, sigma, why = weighted_slope(weight, fit.slope_rad)
        why = weight.why if not weight.applied else (fit.why if fit.shape == "other" else why)
        if why:
            _chord_kept(out, fit, why, anchor_sigma_mm, length)
            return
        # the population's σ, and what this stop's fitted path misses at its end (a kink there)
        out.abs_P_prev = prev_at(slope)
        out.sigma_heading_rad = float(np.hypot(sigma, fit.end_lack_of_fit_rad))
        out.heading_sigma_basis = "weight"
    elif not fit.significant:
        _chord_kept(out, fit, fit.why, anchor_sigma_mm, length)
        return
    else:
        out.abs_P_prev = P_at - sign * length * fit.direction
        sigma = fit_heading_sigma(fit.sigma_rad, anchor_sigma_mm, length)
        out.sigma_heading_rad = float(np.hypot(sigma, fit.end_lack_of_fit_rad))
        out.heading_sigma_basis = "fit"
    out.applied.append("heading_fit")
    out.heading_source = "heading_fit"


def _chord_kept(out: Applied, fit: Any, why: str, anchor_sigma_mm: float, length: float) -> None:
    """The chord kept at a fitted stop: its heading σ raised to its fit's own (bend_fit.chord_sigma)."""
    out.skipped["heading_fit"] = why
    own = chord_sigma(fit, anchor_sigma_mm, length)
    if own > out.sigma_heading_rad:
        out.sigma_heading_rad, out.heading_sigma_basis = own, "stop_fit"


def _lean_change_um(stop: Stop, height: float) -> tuple[float, float] | None:
    """How far the reflector's lean moves it sideways across the move (µm), from the two standstill readings,
    and the change of roll (deg) that leans it; None without both readings."""
    if stop.tilt_prev is None or stop.tilt_at is None:
        return None
    d = abs(stop.tilt_at[0] - stop.tilt_prev[0])  # roll leans the reflector across the travel
    return math.radians(d) * height * 1000.0, d


def _stream_tilt_why(stop: Stop) -> str | None:
    """Why the tilt along the stream cannot be used for the bend fit (None: it can)."""
    if stop.stream_tilt is None:
        return NO_STREAM_TILT
    tilt_prev, tilt_at = _standstill_tilts(stop)
    return stream_tilt_check(stop.stream_tilt, tilt_prev, tilt_at, 0.0)


def _mount_applied(comp: Compensation, stop: Stop, mount: MountOffset | None, abs_t_trk: Any,
                   skipped: dict[str, str]) -> tuple[Stop, np.ndarray | None]:
    """The stop with the mount's offset removed from its tracker points when ``comp.mount`` and the data allow
    (else the stop unchanged and the reason in ``skipped``), and the covariance the offset leaves."""
    if mount is None:
        if comp.mount:
            skipped["mount"] = "the calibration holds no reflector mount offset"
        return stop, None
    if abs_t_trk is None:
        if comp.mount:
            skipped["mount"] = ("the stop's points carry no abs_H_trk: the offset cannot be turned to this "
                                "line of sight")
        return stop, None
    P_at = as_points(stop.abs_P_at, "abs_P_at", 1)[0]
    apply = comp.mount and mount.significant
    if comp.mount and not apply:
        skipped["mount"] = mount.why
    cov = mount.cov_abs_xy(P_at, abs_t_trk, apply)
    if not apply:
        return stop, cov
    stream = None if stop.stream is None else mount.corrected(as_points(stop.stream, "stream"), abs_t_trk)
    return replace(stop,
                   abs_P_prev=mount.corrected(as_points(stop.abs_P_prev, "abs_P_prev", 1)[0], abs_t_trk),
                   abs_P_at=mount.corrected(P_at, abs_t_trk), stream=stream), cov


def compensate(comp: Compensation, stop: Stop, rob_H_scn: np.ndarray, *,
               imu_offset: tuple[float, float] | None = None, bias_b_mm: Any = None,
               anchor_sigma_mm: float = 0.010, imu_yaw_deg: float = 0.0, mount: MountOffset | None = None,
               abs_t_trk: Any = None, heading_weight: HeadingWeight | None = None,
               calibration: Mapping[str, Any] | None = None) -> Applied:
    """Apply ``comp`` to one stop; a compensation without its input, or one the data contradict, is skipped
    and says why. ``abs_P_prev`` of the result always gives the robot's x axis (``stop.reverse`` honoured).
    ``mount`` and ``abs_t_trk`` (the tracker's ACS position): the calibration's reflector mount offset;
    ``heading_weight``: the calibration's learned share of the fitted bend (None: each stop's own test);
    ``calibration``: the calibration document, where the registered compensations read their inputs."""
    skipped: dict[str, str] = {}
    stop, cov_mount = _mount_applied(comp, stop, mount, abs_t_trk, skipped)
    P_at = as_points(stop.abs_P_at, "abs_P_at", 1)[0]
    P_prev = as_points(stop.abs_P_prev, "abs_P_prev", 1)[0]
    out = Applied(forward_prev(P_prev, P_at, stop.reverse), P_at, None, None, check_H(rob_H_scn, "rob_H_scn"),
                  [], skipped, cov_mount_xy_mm2=cov_mount)
    if comp.mount and "mount" not in skipped:
        out.applied.append("mount")
    tilt_ok = stop.tilt_at is not None and stop.tilt_prev is not None and imu_offset is not None
    offset = imu_offset if imu_offset is not None else (0.0, 0.0)
    needs_height = (comp.tilt and tilt_ok) or (comp.heading_fit and stop.tilt_at is not None)
    height = reflector_height_mm(rob_H_scn) if needs_height else 0.0
    if comp.tilt:
        if not tilt_ok:
            out.skipped["tilt"] = ("no inclinometer offset in the calibration" if imu_offset is None
                                   else "the base reported no tilt at this stop")
        else:
            _tilt_applied(out, stop, P_prev, P_at, offset, height, imu_yaw_deg)
    if comp.heading_fit:
        lean = None if "tilt" in out.applied else _lean_change_um(stop, height)
        if stop.stream is None or len(stop.stream) == 0:
            out.skipped["heading_fit"] = "no tracker stream was recorded along the approach"
        elif len(stop.stream) < MIN_FIT_POINTS:
            out.skipped["heading_fit"] = (f"the stream along the approach holds {len(stop.stream)} points "
                                          f"(the fit needs >= {MIN_FIT_POINTS})")
        elif (why := stream_ends_check(stop.stream, P_prev, P_at, anchor_sigma_mm)) is not None:
            out.skipped["heading_fit"] = why
        elif "tilt" in out.applied and (why := _stream_tilt_why(stop)) is not None:
            out.skipped["heading_fit"] = why
        elif lean is not None and lean[0] > 3.0 * anchor_sigma_mm * 1000.0:
            out.skipped["heading_fit"] = LEAN_NOT_COMPENSATED.format(lean=lean[0], d=lean[1], h=height)
        else:
            _heading_fit(out, stop, P_prev, P_at, offset, height, anchor_sigma_mm, imu_yaw_deg,
                         heading_weight)
    if comp.bias:
        _bias_applied(out, bias_b_mm)
    for name, step in STEPS.items():
        if name in comp.registered:
            step(out, stop, calibration or {})
    return out


def _bias_applied(out: Applied, bias_b_mm: Any) -> None:
    """The bias compensation: the calibration's robot-frame bias added to ``out.rob_H_scn``, or why not."""
    if bias_b_mm is None:
        out.skipped["bias"] = "the calibration holds no robot-frame bias (run an experiment and store it)"
        return
    try:
        out.rob_H_scn = apply_bias(out.rob_H_scn, bias_b_mm)
        out.applied.append("bias")
    except ValueError as exc:  # a stored b that cannot be a calibration bias: measure without it
        out.skipped["bias"] = str(exc)
