"""Waiting for a directly driven robot base to finish its motion, for tests and benchmarks that hold a
``SerialRobot`` themselves. ritad never waits so: its motions end on the base's DONE/FAULT event
(daemon/ritad/motion.py), so this is no product API."""
from __future__ import annotations

import time

from drivers.base import DeviceError, DeviceTimeout, RobotState
from drivers.robot import SerialRobot

#: s between STATUS polls; the pump in between reads (and publishes) the base's events
POLL_S = 0.05


def wait_idle(robot: SerialRobot, timeout: float) -> RobotState:
    """Poll STATUS until the base is IDLE; its final state. DeviceTimeout when it is still moving after
    ``timeout`` s, DeviceError (code ``robot_fault``) when the motion ended in a FAULT."""
    deadline = time.monotonic() + timeout
    while True:
        state = robot.status()
        if state.state == "FAULT":
            raise DeviceError(f"robot base FAULT: {state.fault or 'no reason given'}", code="robot_fault")
        if state.state == "IDLE":
            return state
        if time.monotonic() >= deadline:
            raise DeviceTimeout(f"robot base still moving after {timeout:.3g} s")
        robot.pump(min(POLL_S, deadline - time.monotonic()))
