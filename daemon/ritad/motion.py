"""Robot motions that complete on the controller's DONE/FAULT event, not on the command's reply.

The base acknowledges a move at once and reports its end as a ``robot.event``; a motion
with ``wait`` is a Future that the next DONE completes (FAULT fails it) or its timeout expires
(daemon/ritad/timeouts.py: one thread for every timeout).
"""
from __future__ import annotations

import threading
from concurrent.futures import Future
from typing import Any, Callable

from daemon.bus.protocol import CommandError, ErrorCode
from daemon.ritad.futures import chain
from daemon.ritad.timeouts import Timeouts
from drivers.base import Robot

#: a motion: run with the robot adapter in its owner thread
RobotJob = Callable[[Robot], Any]
#: submit a job to the robot's runner: fn(robot) -> Future
SubmitRobot = Callable[[RobotJob], Future]


class MotionWaiters:
    """Futures of motions in progress; ``on_event`` is fed every robot.event."""

    def __init__(self, submit: SubmitRobot, timeouts: Timeouts | None = None) -> None:
        self._submit = submit
        # ritad passes its own; alone (tests, tools) the waiters have one of their own
        self._timeouts = timeouts if timeouts is not None else Timeouts("motion-timeouts")
        self._lock = threading.Lock()
        self._waiters: list[Future] = []

    def on_event(self, payload: Any) -> None:
        """Complete every waiting motion on DONE, fail it on FAULT; other events pass by."""
        event = payload.get("event") if isinstance(payload, dict) else None
        if event not in ("DONE", "FAULT"):
            return
        with self._lock:
            waiters, self._waiters = self._waiters, []
        for fut in waiters:
            if event == "DONE":
                fut.set_result({"event": "DONE", **payload})
            else:
                fut.set_exception(CommandError(ErrorCode.DEVICE_ERROR, f"robot FAULT: {payload}"))

    def abort(self, message: str) -> None:
        """Fail every motion waiting for its end with ``stopped`` (a latched STOP ended it)."""
        with self._lock:
            waiters, self._waiters = self._waiters, []
        for fut in waiters:
            if not fut.done():
                fut.set_exception(CommandError(ErrorCode.STOPPED, message))

    def _forget(self, fut: Future) -> bool:
        with self._lock:
            if fut not in self._waiters:
                return False
            self._waiters.remove(fut)
            return True

    def start(self, fn: RobotJob, wait: bool, timeout: float) -> Future:
        """Start a motion; with ``wait`` the Future completes at its end (or fails after ``timeout`` s)."""
        if not wait:
            return chain(self._submit(fn), lambda _: {"started": True})
        done: Future = Future()
        with self._lock:
            self._waiters.append(done)

        def started(f: Future) -> None:
            if f.exception() is not None and self._forget(done):
                done.set_exception(f.exception())

        def expire() -> None:
            if self._forget(done):
                done.set_exception(CommandError(ErrorCode.TIMEOUT,
                                                f"robot motion not done after {timeout:.0f} s"))

        self._submit(fn).add_done_callback(started)
        pending = self._timeouts.call_later(timeout, expire)
        done.add_done_callback(lambda _: pending.cancel())
        return done
