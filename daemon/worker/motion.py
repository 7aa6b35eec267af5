"""How far a motion went: a motion step is done only when the base executed the whole command.

The base reports a motion's end as ``robot.event`` DONE with a ``result``: ``OK`` (the whole
command executed), ``STOPPED`` (cut short by STOP), or ``UNKNOWN`` (the event was lost and the
driver rebuilt it from STATUS); the pose in it, like ``robot.status``'s, is odometry: the
integral of the executed motion (docs/robot-protocol.md). A dataset records a motion as
commanded (``move_mm``), so a step may record it only when the base executed all of it: a move
cut short is never recorded as the commanded one (issue 30). Without an ``OK`` the odometry
decides, and only a lost event whose odometry shows the whole command counts as done.
"""
from __future__ import annotations

import math
from typing import Any

from daemon.worker.job import JobContext, StepFailed

#: how far a completed move's odometry may lie from its command (mm): the base reports odometry to
#: 0.1 µm and integrates the commanded motion, so only rounding separates them
ODOMETRY_TOL_MM = 0.05
#: the same for a turn's odometry heading (degrees; reported to 1e-6°)
HEADING_TOL_DEG = 0.01


class MotionIncomplete(StepFailed):
    """The base ended a motion before executing all of it: the step that commanded it is not done."""

    def __init__(self, message: str, driven: float) -> None:
        super().__init__(message)
        self.driven = driven  # mm along the start heading (a move) or degrees turned (a turn), by odometry


def _wrap_deg(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


def odometry_delta(start: dict[str, Any], end: dict[str, Any]) -> tuple[float, float, float]:
    """(along, across, turned): the odometry displacement from ``start`` to ``end`` (robot.status or DONE
    poses) in mm along and to the left of the start heading, and the heading change in degrees."""
    h = math.radians(float(start["heading_deg"]))
    dx, dy = float(end["x_mm"]) - float(start["x_mm"]), float(end["y_mm"]) - float(start["y_mm"])
    return (dx * math.cos(h) + dy * math.sin(h), -dx * math.sin(h) + dy * math.cos(h),
            _wrap_deg(float(end["heading_deg"]) - float(start["heading_deg"])))


def _has_pose(d: dict[str, Any] | None) -> bool:
    return d is not None and all(isinstance(d.get(k), (int, float)) for k in ("x_mm", "y_mm", "heading_deg"))


def check_motion(kind: str, commanded: float, start: dict[str, Any] | None, done: dict[str, Any] | None,
                 end: dict[str, Any] | None = None) -> None:
    """Raise :class:`MotionIncomplete` unless the motion (``kind`` "move" in mm or "turn" in degrees)
    executed all of ``commanded``.

    ``start``: robot.status before it; ``done``: its DONE event (None when none was seen); ``end``:
    robot.status after it, the pose when the DONE has none. ``OK`` is done; ``STOPPED`` never is;
    otherwise (a lost event) the odometry from ``start`` must show the whole command, on the line
    (a move) or on the spot (a turn).
    """
    result = str((done or {}).get("result") or "no DONE event")
    if result == "OK":
        return
    pose = done if _has_pose(done) else end
    driven = math.nan
    if start is not None and _has_pose(start) and _has_pose(pose):
        assert pose is not None
        along, across, turned = odometry_delta(start, pose)
        if kind == "move":
            driven = along
            whole = abs(along - commanded) <= ODOMETRY_TOL_MM and abs(across) <= ODOMETRY_TOL_MM
        else:
            driven = turned
            whole = (abs(_wrap_deg(turned - commanded)) <= HEADING_TOL_DEG
                     and math.hypot(along, across) <= ODOMETRY_TOL_MM)
        if whole and result != "STOPPED":
            return
    unit = "mm" if kind == "move" else "°"
    went = "an unknown part" if math.isnan(driven) else f"{driven:.1f} {unit}"
    raise MotionIncomplete(f"the base ended the {commanded:.1f} {unit} {kind} after {went} (DONE {result}): "
                           f"the {kind} is not recorded; a resume redoes the step from a defined state",
                           driven)


def confirm_done(ctx: JobContext, kind: str, commanded: float, start: dict[str, Any] | None,
                 done: dict[str, Any] | None, end: dict[str, Any] | None = None) -> None:
    """:func:`check_motion` in a job: a motion a latched STOP cut short ends the job as stopped (Stopped),
    whether the worker heard of the STOP first or of the move's end (DONE STOPPED) first."""
    try:
        check_motion(kind, commanded, start, done, end)
    except MotionIncomplete:
        ctx.check_cancel()
        raise
