"""A simulated base's motion in progress and its state at any instant (fakes/robot_base.py)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from fakes.world import RobotPose

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


def unit_interval(name: str, value: float) -> float:
    """A probability option (0..1), or ValueError naming it."""
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"{name}={value!r} must be within 0..1")
    return value


def motion_state(base: Any, t: float) -> tuple[tuple[float, float, float], tuple[float, float], tuple[float, float]]:
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
