"""Foxglove's well-known messages a recording adds beside ritad's own telemetry (docs/operations.md,
"Record and replay"): the robot's pose and each tracker record as ``foxglove.PoseInFrame``, the
journal as ``foxglove.Log``, frames as ``foxglove_msgs/msg/CompressedImage`` on request.

Every builder is a pure function of one bus message; the schemas are Foxglove's published ones
(daemon/ctl/foxglove_schemas). Lengths are metres in these messages, as Foxglove's 3D panel takes
them; ritad's own channels keep their millimetres. Each message's ``timestamp`` is its sample's
time, the same instant as its MCAP log time.
"""
from __future__ import annotations

import math
from typing import Any, Iterator

#: the channels, their Foxglove schema names (the vendored file's stem after ``foxglove.``)
ROBOT_POSE_TOPIC = "/robot/pose"
TRACKER_POSE_TOPIC = "/tracker/pose"
LOG_TOPIC = "/log"
POSE_SCHEMA, LOG_SCHEMA = "PoseInFrame", "Log"
#: frame ids: the base's odometry frame (where its x_mm, y_mm, heading_deg count from) and the tracker's
ODOM_FRAME, TRACKER_FRAME = "odom", "tracker"
#: Python logging's level names → foxglove.LogLevel (Log.json: UNKNOWN 0 … FATAL 5), and back
LOG_LEVELS = {"DEBUG": 1, "INFO": 2, "WARNING": 3, "ERROR": 4, "CRITICAL": 5}
LEVEL_NAMES = {v: k for k, v in LOG_LEVELS.items()}
MM = 1e-3  # metres per millimetre


def stamp(t_ns: int) -> dict[str, int]:
    """A Foxglove time (``sec``, ``nsec``; both non-negative by the schema)."""
    t = max(0, int(t_ns))
    return {"sec": t // 1_000_000_000, "nsec": t % 1_000_000_000}


def _finite(*values: Any) -> bool:
    return all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in values)


#: a PoseInFrame's JSON, formatted directly: at 1 kHz of tracker records ``json.dumps`` of the nested
#: map was half the recorder's time; ``repr`` of a finite float is a valid JSON number
_POSE = ('{{"timestamp":{{"sec":{},"nsec":{}}},"frame_id":"{}","pose":{{"position":{{"x":{!r},"y":{!r},'
         '"z":{!r}}},"orientation":{{"x":{!r},"y":{!r},"z":{!r},"w":{!r}}}}}}}')


def pose_in_frame(t_ns: int, frame_id: str, position: tuple[float, float, float],
                  orientation: tuple[float, float, float, float]) -> bytes:
    """A foxglove.PoseInFrame as JSON bytes (``frame_id``: one of ours, no characters to escape)."""
    t = stamp(t_ns)
    return _POSE.format(t["sec"], t["nsec"], frame_id, *(float(v) for v in position),
                        *(float(v) for v in orientation)).encode()


def robot_pose(state: dict[str, Any], t_ns: int) -> bytes | None:
    """``robot.state``'s odometry pose as a PoseInFrame in ``odom`` (a yaw about z), None without one."""
    x, y, h = state.get("x_mm"), state.get("y_mm"), state.get("heading_deg")
    if not _finite(x, y, h) or x is None or y is None or h is None:  # (None is not finite: for the types)
        return None
    half = math.radians(float(h)) / 2.0  # a rotation by the heading about the floor's normal
    return pose_in_frame(t_ns, ODOM_FRAME, (float(x) * MM, float(y) * MM, 0.0),
                         (0.0, 0.0, math.sin(half), math.cos(half)))


def tracker_poses(packet: dict[str, Any], times: list[int]) -> Iterator[tuple[int, bytes]]:
    """Each valid record (status 0) of a ``tracker.point`` packet as ``(t_ns, PoseInFrame)`` in the
    tracker's frame: a point, so the orientation is the identity. ``times``: each record's time."""
    status = packet.get("status") or [0] * len(times)
    for t, x, y, z, st in zip(times, packet["x"], packet["y"], packet["z"], status):
        if st == 0 and _finite(x, y, z):
            yield t, pose_in_frame(t, TRACKER_FRAME, (x * MM, y * MM, z * MM), (0.0, 0.0, 0.0, 1.0))


def log_entry(record: dict[str, Any], t_ns: int) -> dict[str, Any]:
    """A ``log`` record of ritad's (``level``, ``logger``, ``message``, ``t``) as a foxglove.Log; ``file``
    and ``line`` are required there and not on the bus: empty and 0."""
    return {"timestamp": stamp(t_ns), "level": LOG_LEVELS.get(str(record.get("level")), 0),
            "message": str(record.get("message", "")), "name": str(record.get("logger", "")),
            "file": "", "line": 0}


def log_record(entry: dict[str, Any]) -> dict[str, Any]:
    """The inverse of :func:`log_entry`, for a replay: the bus ``log`` record (``t`` to the ns)."""
    ts = entry.get("timestamp") or {}
    t = int(ts.get("sec", 0)) + int(ts.get("nsec", 0)) / 1e9
    return {"level": LEVEL_NAMES.get(int(entry.get("level", 0)), "NOTSET"), "logger": entry.get("name", ""),
            "message": entry.get("message", ""), "t": t}
