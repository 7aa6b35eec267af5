"""A simulated base's motion in progress and its state at any instant (fakes/robot_base.py)."""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from fakes.robot_stream import INCL_RATE_HZ
from fakes.world import RobotPose, World

#: the inclinometer's output period in robot time (its rate: fakes/robot_stream.py)
IMU_PERIOD_S = 1.0 / INCL_RATE_HZ
#: the wheels' distance apart (mm): a turn on the spot shows as opposite wheel speeds in STATE
TRACK_MM = 400.0


@dataclass
class Motion:
    """One MOVE or TURN in progress: its start and planned end, in truth and odometry."""

    seq: int
    start: RobotPose
    end: RobotPose
    odo_start: tuple[float, float, float]
    odo_end: tuple[float, float, float]
    t0: float
    duration: float
    path: float  # commanded path length (mm, or deg for turns) for the battery model
    fault_at: float | None = None  # fraction at which a simulated stall strikes
    bend_mm: float = 0.0  # sideways offset at the end of the bent path (error model: arc or S)


def wrap_deg(angle: float) -> float:
    """A heading wrapped to [-180, 180] (the protocol's convention)."""
    return math.remainder(angle, 360.0)


def unit_interval(name: str, value: float) -> float:
    """A probability option (0..1), or ValueError naming it."""
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"{name}={value!r} must be within 0..1")
    return value


def motion_state(base: Any, t: float
                 ) -> tuple[tuple[float, float, float], tuple[float, float], tuple[float, float]]:
    """Odometry (x, y, heading), wheel speeds (mm/s of simulated time) and true tilt (rad) of a
    ``FakeBase`` at clock time ``t``: from the motion under way then (its velocity profile), else
    the standstill. The caller holds the base's lock."""
    m = base.motion
    if m is not None and t < m.t0:  # a sample due before the motion that has started since
        return m.odo_start, (0.0, 0.0), (m.start.roll_rad, m.start.pitch_rad)
    pose = base.pose_at(t)
    for m, t_done in ((base.motion, math.inf), base._last_motion):
        if m is None or not m.t0 <= t <= t_done or pose is None:
            continue
        end = 1.0 if m.fault_at is None else m.fault_at  # a stall stops the wheels there
        f = 1.0 if m.duration <= 0.0 else min(end, (t - m.t0) / m.duration)
        odo = tuple(a + f * (b - a) for a, b in zip(m.odo_start, m.odo_end))
        speeds = (0.0, 0.0)
        if f < end and base.time_scale > 0:
            seconds = m.duration / base.time_scale  # the motion's length in simulated time
            (x0, y0, h0), (x1, y1, h1) = m.odo_start, m.odo_end
            v = ((x1 - x0) * math.cos(math.radians(h0)) + (y1 - y0) * math.sin(math.radians(h0))) / seconds
            w = math.radians(h1 - h0) / seconds * TRACK_MM / 2
            speeds = (v - w, v + w)
        return (odo[0], odo[1], odo[2]), speeds, (pose.roll_rad, pose.pitch_rad)
    with base.world.lock:
        pose = base.world.robot
    return base.odometry, (0.0, 0.0), (pose.roll_rad, pose.pitch_rad)


@dataclass
class HostWatchdog:
    """Protocol 3's host watchdog (docs/robot-protocol.md, "Host watchdog"): a motion halts on its own
    when no valid host line came within ``timeout_s``, as a base whose host died must. Off (None) in a
    version-1 or 2 session, whose host does not keep the link alive. A line counts when the fake reads it:
    one that waited in the pty while the fake's own thread was late re-arms the timer, as it would have on
    time on a real base (whose receive interrupt is never late), so a busy test machine halts nothing.
    For the same reason the timer is judged only up to ``read_until``, the time before the port's server
    last read everything waiting: a line still unread then may have arrived in time (a UART's receive
    interrupt would have taken it), so a thread late between its read and its tick halts nothing either."""

    timeout_s: float | None = None
    heard_at: float = -math.inf  # clock time of the last valid host line
    #: clock time up to which every arrived host line was read (the port's server sets it before each read);
    #: None: lines are handed over as they arrive (no server thread in between, or no port: none can come)
    read_until: float | None = None

    def heard(self, now: float) -> None:
        self.heard_at = now

    def expiry(self) -> float | None:
        """The clock time at which a motion under way must halt, None while off."""
        return None if self.timeout_s is None else self.heard_at + self.timeout_s

    def expired(self, now: float) -> float | None:
        """The expiry, when the timer ran out by ``now`` as far as the lines read tell; else None."""
        expiry = self.expiry()
        judged = now if self.read_until is None else min(now, self.read_until)
        return expiry if expiry is not None and judged >= expiry else None


def fraction_at(m: Motion, t: float) -> float:
    """The fraction of motion ``m`` done at clock time ``t`` (linear in time, 0..1)."""
    return 1.0 if m.duration <= 0.0 else min(1.0, max(0.0, (t - m.t0) / m.duration))


def pose_on_path(world: World, m: Motion, f: float) -> RobotPose:
    """The true pose at fraction ``f`` of motion ``m`` (linear in time, on its bent path)."""
    if f >= 1.0:
        return m.end
    s, e = m.start, m.end
    pose = replace(s, x_mm=s.x_mm + f * (e.x_mm - s.x_mm), y_mm=s.y_mm + f * (e.y_mm - s.y_mm),
                   heading_deg=s.heading_deg + f * (e.heading_deg - s.heading_deg))
    if m.bend_mm:  # on the bent path (arc or S), not the chord
        a = math.radians(s.heading_deg)
        side, dh = world.effects.bend_profile(f, m.bend_mm, max(m.path, 1e-9))
        pose = replace(pose, x_mm=pose.x_mm - float(side) * math.sin(a),
                       y_mm=pose.y_mm + float(side) * math.cos(a),
                       heading_deg=pose.heading_deg + math.degrees(float(dh)))
    if world.effects.settles:  # on an uneven surface the tilt changes along the path
        pose = world.settle(replace(pose, roll_rad=0.0, pitch_rad=0.0, z_mm=None))
    return pose


def inclinometer_output(base: Any, pose: RobotPose) -> tuple[float, float]:
    """The inclinometer's output (deg): a new sample every IMU_PERIOD_S of robot time, held between."""
    now = base.clock()
    held = base._imu_held
    if held is not None and base.motion is None and now - held[0] < IMU_PERIOD_S * base.time_scale:
        return held[1]
    rng = base._imu_rng if base.motion is None else base._imu_moving_rng
    r, p = base.world.effects.inclinometer(pose.roll_rad, pose.pitch_rad, rng)
    base._imu_held = (now, (math.degrees(r), math.degrees(p)))
    return base._imu_held[1]
