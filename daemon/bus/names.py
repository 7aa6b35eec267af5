"""The bus's fixed vocabularies, defined once: roles, device kinds, telemetry topics and job states.

``StrEnum`` members compare equal to their text, so they go on the wire (msgpack, JSON) as the
strings docs/protocol.md lists; code names them by member so a typo is an AttributeError at
import, not a topic nobody receives. Drivers sit below the bus library and emit their topics as
text; a test checks that every topic they emit is a :class:`Topic`.
"""
from __future__ import annotations

from enum import StrEnum


class Role(StrEnum):
    """What a key may do, in rising rank: each role may do everything of the ones before it."""

    VIEWER = "viewer"
    OPERATOR = "operator"
    ADMIN = "admin"


#: the roles as plain text, lowest first (argparse choices, messages)
ROLES: tuple[str, ...] = tuple(r.value for r in Role)


class Kind(StrEnum):
    """The robot's devices, one owner thread and one ``[devices]`` URL each (in the config's order)."""

    CAMERA = "camera"
    TRACKER = "tracker"
    ROBOT = "robot"


KINDS: tuple[str, ...] = tuple(k.value for k in Kind)


class Topic(StrEnum):
    """Telemetry topics (docs/protocol.md, Telemetry); frames go on their own socket."""

    DAEMON_HEALTH = "daemon.health"
    DAEMON_STATE = "daemon.state"
    DAEMON_COMMAND = "daemon.command"
    TRACKER_POINT = "tracker.point"
    TRACKER_EVENT = "tracker.event"
    ROBOT_STATE = "robot.state"
    ROBOT_ODOMETRY = "robot.odometry"
    ROBOT_INCL = "robot.incl"
    ROBOT_EVENT = "robot.event"
    ROBOT_LATCH = "robot.latch"
    ROBOT_REFUSED = "robot.refused"
    CAMERA_FRAME = "camera.frame"
    CAMERA_LINK = "camera.link"
    CALIB_PROGRESS = "calib.progress"
    CALIB_PROMPT = "calib.prompt"
    CALIB_RESULT = "calib.result"
    LOG = "log"


class JobState(StrEnum):
    """A calibration job's state (``calib.jobs``, ``calib.result``; state.json's ``status`` uses those a
    worker writes: running, done, failed, cancelled, stopped)."""

    QUEUED = "queued"
    RUNNING = "running"
    WAITING = "waiting"      # a prompt awaits the operator's answer
    DONE = "done"
    FAILED = "failed"
    CANCELLED = "cancelled"
    STOPPED = "stopped"      # the robot's STOP ended its run; resumable after robot.release
