"""The latched stop: one meaning for every STOP, whoever sends it.

``robot.stop`` (any key, viewers included) engages the latch in the ROUTER thread, so no later
request can slip a motion in between, and with it the robot's motion gate (drivers/motion_gate.py):
the halt is requested of the robot's owner thread before anything is written to disk, and it reaches
the base whatever the link does (first after the HELLO of every connect while latched). While latched
every motion command is refused with ``stopped``, also a motion already queued in the robot's runner
(``guard`` runs again in the owner thread, and the gate refuses the line). Only an operator's
``robot.release`` clears it. The latch survives a daemon restart (a file in the data dir, written
afterwards in the latch's own thread): a restarted ritad starts latched and halts the base first.
"""
from __future__ import annotations

import json
import logging
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any, Callable

from daemon.bus.protocol import CommandError, ErrorCode
from daemon.bus.storage import atomic_write_json
from daemon.bus.names import Topic
from drivers.motion_gate import MotionGate

log = logging.getLogger(__name__)

#: the latch's file in the data dir
LATCH_FILE = "stop_latch.json"


class StopLatch:
    """Latched / released, who latched it and why; publishes ``robot.latch`` on every change."""

    def __init__(self, publish: Callable[[str, Any], None], path: Path | None = None) -> None:
        self._publish = publish
        self._path = path
        self._lock = threading.Lock()
        self.latched = False
        self.by = ""
        self.reason = ""
        self.since_ns: int | None = None
        self.refused = 0
        self._load()
        #: the robot's motion gate (ritad hands it to the robot adapter); latched at start, it owes the
        #: base a halt
        self.gate = MotionGate(latched=self.latched)
        # a snapshot and its publication in one step: the last one published is the newest
        self._pub_lock = threading.Lock()
        self.gate.on_halted(self._announce)
        # the file is written in order, off the command thread
        self._writer = ThreadPoolExecutor(max_workers=1, thread_name_prefix="latch-file")

    def _load(self) -> None:
        try:
            st = (json.loads(self._path.read_text())
                  if self._path is not None and self._path.exists() else None)
        except (OSError, ValueError) as exc:  # unreadable: fail safe, stay stopped
            st = {"latched": True, "by": "ritad", "reason": f"latch file unreadable ({exc})"}
        if isinstance(st, dict) and st.get("latched"):
            self.latched, self.by = True, str(st.get("by", "?"))
            self.reason = str(st.get("reason", ""))
            self.since_ns = int(st.get("since_ns") or time.time_ns())
            log.warning("robot stop latched since an earlier run (by %s): motion refused until "
                        "`ritactl robot release`", self.by)

    def snapshot(self) -> dict[str, Any]:
        with self._lock:
            snap = {"latched": self.latched, "by": self.by, "since_ns": self.since_ns, "reason": self.reason,
                    "refused": self.refused}
        return {**snap, "halt_pending": self.gate.pending}

    def _announce(self) -> None:
        with self._pub_lock:
            self._publish(Topic.ROBOT_LATCH, self.snapshot())

    def _changed(self) -> Future:
        """Publish now; write the file in the latch's thread (the Future is done once it is on disk), or here
        once that thread has ended (a STOP while the daemon stops)."""
        self._announce()
        try:
            return self._writer.submit(self._persist)
        except RuntimeError:  # the writer is shut down: the latch must still reach the disk
            self._persist()
            done: Future = Future()
            done.set_result(None)
            return done

    def _persist(self) -> None:
        if self._path is None:
            return
        try:  # the newest state, whatever the order of the requests that queued the writes
            atomic_write_json(self._path, self.snapshot())
        except OSError as exc:  # the latch still holds in memory
            log.error("cannot persist the stop latch to %s: %s", self._path, exc)

    def engage(self, by: str, reason: str = "robot.stop") -> tuple[Future, Future]:
        """Latch (again): a second STOP re-stamps who and when, and still halts the base. Returns the halt
        (done when the base acknowledged a STOP) and the file write (done when the latch is on disk)."""
        halted = self.gate.engage()  # first: the robot's owner writes STOP at its next read slice
        with self._lock:
            self.latched, self.by, self.reason, self.since_ns = True, by, reason, time.time_ns()
        log.warning("robot STOP by %s (%s): motion latched off until `ritactl robot release`", by, reason)
        return halted, self._changed()

    def close(self) -> None:
        """Finish the file writes queued (the daemon's stop)."""
        self._writer.shutdown(wait=True)

    def release(self, by: str) -> bool:
        """Clear the latch; returns whether it was latched."""
        with self._lock:
            was = self.latched
            self.latched, self.reason, self.since_ns = False, "", None
            self.by = by if was else self.by
        self.gate.release()
        if was:
            log.warning("robot stop released by %s: motion allowed again", by)
            self._changed()
        return was

    def message(self, cmd: str) -> str:
        when = time.strftime("%H:%M:%S", time.localtime((self.since_ns or 0) / 1e9))
        return (f"{cmd} refused: the robot is stopped (latched by {self.by} at {when}); "
                f"an operator clears it with `ritactl robot release` or the console's Release")

    def guard(self, cmd: str, by: str) -> None:
        """Raise ``stopped`` when latched, counting and publishing the refusal (the command server logs it,
        once per command and sender per minute with the count)."""
        if not self.latched:
            return
        msg = self.message(cmd)
        with self._lock:
            self.refused += 1
        self._publish(Topic.ROBOT_REFUSED, {"cmd": cmd, "by": by, "message": msg})
        raise CommandError(ErrorCode.STOPPED, msg)
