"""One owner thread per device: connection state machine, job queue, reconnect with backoff.

The runner is the only thread that touches its adapter. Bus handlers submit jobs
(``submit(fn)`` → Future); between jobs the runner calls ``device.pump`` so stream
data and events flow. ``DeviceLost`` from any call closes the adapter and starts
reconnecting with exponential backoff; the state (DISCONNECTED → CONNECTING →
READY ⇄ BUSY, FAULT with the reason) is published on every change.

Liveness (``alive()``, which gates the systemd watchdog) is the owner thread's own:
it beats at least every ``BEAT_S`` while it waits in backoff, and a blocking call
(a job, an ``open()``) counts as alive until that call's own time limit. So a
switched-off device is a FAULT state, never a reason for systemd to restart ritad.
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any, Callable

from daemon.bus.protocol import CommandError, ErrorCode
from drivers.base import Device, DeviceError, DeviceLost, DeviceState, DeviceTimeout
from daemon.bus.names import Topic
from daemon.ritad.device_clock import DeviceClock

log = logging.getLogger(__name__)

# operator words for the errors a switched-off or unplugged device gives
_PLAIN: tuple[tuple[type[BaseException], str], ...] = (
    (ConnectionRefusedError, "connection refused"), (ConnectionResetError, "connection reset"),
    (TimeoutError, "timed out"), (FileNotFoundError, "not found"), (PermissionError, "permission denied"))


def describe(exc: BaseException) -> str:
    """A device error for the operator: plain words first, then the driver's own message."""
    words = next((w for kind, w in _PLAIN if isinstance(exc, kind)), "")
    text = str(exc) or type(exc).__name__
    return f"{words} ({text})" if words else text

PUMP_S = 0.02  # how long pump may block: bounds job latency while idle
BEAT_S = 0.5  # longest wait between heartbeats while the runner waits in backoff
#: the wait between connect attempts while the device owes a halt (``owes_halt``): a link that comes back
#: must carry the STOP at once, not after a backoff grown while it was down
URGENT_RETRY_S = 0.05


@dataclass
class _Job:
    fn: Callable[[Device], Any]
    future: Future
    timeout: float = 60.0


class DeviceRunner(threading.Thread):
    """Owns one device adapter for its whole life."""

    def __init__(self, kind: str, factory: Callable[[], Device], publish: Callable[[str, Any], None],
                 backoff_min: float = 0.5, backoff_max: float = 30.0, heartbeat_timeout: float = 10.0,
                 open_timeout: float = 120.0, owes_halt: Callable[[], bool] = lambda: False) -> None:
        super().__init__(name=f"device-{kind}", daemon=True)
        self.kind = kind
        self._factory = factory
        self._publish = publish
        self._owes_halt = owes_halt  # the robot's motion gate owes the base a halt: reconnect without backoff
        self._jobs: queue.Queue[_Job] = queue.Queue()
        self._stop_evt = threading.Event()
        self.backoff_min, self.backoff_max = backoff_min, backoff_max
        self.heartbeat_timeout, self.open_timeout = heartbeat_timeout, open_timeout
        self.device: Device | None = None
        self.state = DeviceState.DISCONNECTED
        self.reason = ""
        #: reconnect attempts: one per lost connection plus one per retry after a failed attempt
        self.reconnects = 0
        self._retrying = False
        self.opens = 0
        self.jobs_done = 0
        self.jobs_failed = 0
        self.info: dict[str, Any] = {}
        self.heartbeat = time.monotonic()
        #: end of the time limit of the blocking call in progress (job or open), else None
        self._busy_deadline: float | None = None
        self._last_fault = ""
        #: the device clock's mapping onto the host's, fed by ritad from the device's telemetry
        self.clock = DeviceClock()

    # ------------------------------------------------------------------ API (any thread)

    def submit(self, fn: Callable[[Device], Any], *, timeout: float = 60.0) -> Future:
        """Queue ``fn(device)`` for the owner thread, in arrival order (a robot STOP is no job: the motion
        gate's halt goes out ahead of any job, drivers/motion_gate.py)."""
        fut: Future = Future()
        if self.state not in (DeviceState.READY, DeviceState.BUSY):
            why = f": {self.reason}" if self.reason else ""
            fut.set_exception(CommandError(ErrorCode.NOT_READY, f"{self.kind} is {self.state.value}{why}"))
            return fut
        self._jobs.put(_Job(fn, fut, timeout))
        device = self.device
        if device is not None:
            device.wake()  # the owner picks the job up now, not when its pump times out
        return fut

    def alive(self, stale_after: float | None = None) -> bool:
        """Heartbeat fresh (or in a job or open() within its own time limit)?"""
        now = time.monotonic()
        deadline = self._busy_deadline
        if deadline is not None:
            return now < deadline
        limit = self.heartbeat_timeout if stale_after is None else stale_after
        return self.is_alive() and now - self.heartbeat < limit

    def snapshot(self) -> dict[str, Any]:
        return {"state": self.state.value, "reason": self.reason, "reconnects": self.reconnects,
                "opens": self.opens, "jobs_done": self.jobs_done, "jobs_failed": self.jobs_failed,
                "queued": self._jobs.qsize(), "heartbeat_age_s": round(time.monotonic() - self.heartbeat, 3),
                "info": self.info}

    @property
    def stopping(self) -> bool:
        """The daemon is stopping this runner (a long job may end early: the robot's kit halts the base)."""
        return self._stop_evt.is_set()

    def stop(self, timeout: float = 3.0) -> None:
        self._stop_evt.set()
        if self.ident is not None:  # a runner never started has no thread to wait for
            self.join(timeout)

    # ------------------------------------------------------------------ owner thread

    def _set_state(self, state: DeviceState, reason: str = "") -> None:
        if state is self.state and reason == self.reason:
            return
        self.state, self.reason = state, reason
        if state in (DeviceState.FAULT, DeviceState.DISCONNECTED) and reason and not self._stop_evt.is_set():
            # warn once per distinct reason; retries with the same failure stay at debug level
            level = logging.WARNING if reason != self._last_fault else logging.DEBUG
            self._last_fault = reason
            log.log(level, "%s %s: %s", self.kind, state.value, reason)
        else:
            if state is DeviceState.READY:
                self._last_fault = ""
            log.debug("%s %s", self.kind, state.value)
        self._publish(Topic.DAEMON_STATE, {"device": self.kind, "state": state.value, "reason": reason,
                                       "reconnects": self.reconnects})

    def _fail_queued(self, why: str) -> None:
        while True:
            try:
                job = self._jobs.get_nowait()
            except queue.Empty:
                return
            if not job.future.done():
                job.future.set_exception(CommandError(ErrorCode.NOT_READY, f"{self.kind}: {why}"))

    def _close(self) -> None:
        if self.device is not None:
            try:
                self.device.close()
            except Exception:  # close must not take the runner down
                log.exception("%s: close failed", self.kind)

    def _connect(self) -> bool:
        if self._retrying:
            self.reconnects += 1
        if not (self._retrying and self._owes_halt()):  # retries every 50 ms: FAULT stays, unrepeated
            self._set_state(DeviceState.CONNECTING)
        self._busy_deadline = time.monotonic() + self.open_timeout  # open() blocks: it has its own limit
        try:
            if self.device is None:
                self.device = self._factory()
            self.device.open()
        except Exception as exc:
            self._close()
            self._retrying = True
            self._set_state(DeviceState.FAULT, f"cannot open: {describe(exc)}")
            return False
        finally:
            self._busy_deadline = None
            self.heartbeat = time.monotonic()
        self.opens += 1
        self._retrying = False
        log.info("%s connected (%s)", self.kind, self.device.url.raw)
        try:
            self.info = self.device.info()
        except Exception as exc:
            self.info = {"error": str(exc)}
        self._set_state(DeviceState.READY)
        return True

    def _connected(self) -> Device:
        """The device of a READY or BUSY runner (:meth:`_connect` made it before READY)."""
        if self.device is None:
            raise RuntimeError(f"{self.kind}: the runner is {self.state.value} without a device")
        return self.device

    def _lost(self, exc: BaseException) -> None:
        self._close()
        self.reconnects += 1
        self._set_state(DeviceState.DISCONNECTED, f"connection lost: {exc}")
        self._fail_queued(f"connection lost: {exc}")

    def _run_job(self, job: _Job) -> None:
        if not job.future.set_running_or_notify_cancel():
            return
        self._set_state(DeviceState.BUSY)
        self._busy_deadline = time.monotonic() + job.timeout + 5.0
        try:
            result = job.fn(self._connected())
        except DeviceLost as exc:
            self.jobs_failed += 1
            job.future.set_exception(CommandError(ErrorCode.DEVICE_LOST, f"{self.kind}: {exc}"))
            self._busy_deadline = None
            self._lost(exc)
            return
        except DeviceTimeout as exc:
            self.jobs_failed += 1
            job.future.set_exception(CommandError(ErrorCode.TIMEOUT, f"{self.kind}: {exc}"))
        except DeviceError as exc:
            self.jobs_failed += 1
            job.future.set_exception(CommandError(exc.code, f"{self.kind}: {exc}"))
        except CommandError as exc:
            self.jobs_failed += 1
            job.future.set_exception(exc)
        except ValueError as exc:  # adapters refuse bad arguments with a ValueError naming the value
            self.jobs_failed += 1
            job.future.set_exception(CommandError(ErrorCode.BAD_ARGS, f"{self.kind}: {exc}"))
        except Exception as exc:
            self.jobs_failed += 1
            log.exception("%s: job failed", self.kind)
            job.future.set_exception(CommandError(ErrorCode.INTERNAL,
                                                  f"{self.kind}: {type(exc).__name__}: {exc}"))
        else:
            self.jobs_done += 1
            job.future.set_result(result)
        self._busy_deadline = None
        self._set_state(DeviceState.READY)

    def _park(self) -> None:
        """Leave the device safe before the owner exits (a moving robot halts); a failure is logged only."""
        try:
            self._connected().park()
        except Exception as exc:  # the port may be gone: nothing more can be done from here
            log.error("%s: could not be left safe at exit: %s", self.kind, describe(exc))

    def _backoff(self, seconds: float) -> None:
        """Wait before the next connect attempt, beating so the watchdog sees a responsive thread; cut short
        when the device comes to owe a halt meanwhile (a STOP must not wait out a backoff grown long)."""
        start = time.monotonic()
        end = start + seconds
        while not self._stop_evt.is_set():
            self.heartbeat = now = time.monotonic()
            if now >= end or now - start >= URGENT_RETRY_S and self._owes_halt():
                return
            self._stop_evt.wait(min(BEAT_S, end - now, URGENT_RETRY_S))

    def run(self) -> None:
        backoff = self.backoff_min
        while not self._stop_evt.is_set():
            self.heartbeat = time.monotonic()
            if self.state not in (DeviceState.READY, DeviceState.BUSY):
                if self._connect():
                    backoff = self.backoff_min
                    continue
                self._fail_queued(self.reason)
                self._backoff(URGENT_RETRY_S if self._owes_halt() else backoff)
                backoff = min(backoff * 2, self.backoff_max)
                continue
            try:
                job = self._jobs.get_nowait()
            except queue.Empty:
                job = None
            if job is not None:
                self._run_job(job)
                continue
            try:
                self._connected().pump(PUMP_S)
            except DeviceLost as exc:
                self._lost(exc)
            except Exception as exc:  # a pump bug must not kill the owner thread
                log.exception("%s: pump failed", self.kind)
                self._lost(exc)
        self._fail_queued("daemon stopping")
        if self.state in (DeviceState.READY, DeviceState.BUSY):
            self._park()
        self._close()
        shutdown = getattr(self.device, "shutdown", None)  # simulated devices also stop their fake peer
        if callable(shutdown):
            try:
                shutdown()
            except Exception:
                log.exception("%s: shutdown failed", self.kind)
        self._set_state(DeviceState.DISCONNECTED, "stopped")
