"""Calibration job mailbox: how operators and the worker meet on the bus.

The worker is a plain bus client. Operators (ritactl) post jobs with ``calib.start``
and answers with ``calib.answer``; the worker long-polls ``calib.next`` for jobs and
``calib.inbox`` for answers/cancels, and sends ``calib.report`` which the daemon
republishes as ``calib.progress`` / ``calib.result`` / ``calib.prompt`` telemetry.
Long polls are Futures completed by a post or by a timer, so the ROUTER thread
never blocks.
"""
from __future__ import annotations

import collections
import itertools
import threading
import time
import uuid
from concurrent.futures import Future
from typing import Any, Callable

from daemon.protocol import CommandError, ErrorCode
from daemon.server import Request

PROCEDURES = ("referencing", "intrinsics", "measure-mark", "experiment")
REPORT_KINDS = ("progress", "result", "prompt", "error")


class _Mailbox:
    """A FIFO whose ``get`` returns a Future (completed now, on the next put, or None on timeout)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._items: collections.deque[Any] = collections.deque()
        self._waiters: collections.deque[Future] = collections.deque()

    def put(self, item: Any) -> None:
        with self._lock:
            while self._waiters:
                w = self._waiters.popleft()
                if not w.done():
                    w.set_result(item)
                    return
            self._items.append(item)

    def get(self, timeout: float) -> Future:
        fut: Future = Future()
        with self._lock:
            if self._items:
                fut.set_result(self._items.popleft())
                return fut
            self._waiters.append(fut)

        def expire() -> None:
            with self._lock:
                if fut in self._waiters:
                    self._waiters.remove(fut)
                    fut.set_result(None)

        timer = threading.Timer(timeout, expire)
        timer.daemon = True
        timer.start()
        fut.add_done_callback(lambda _: timer.cancel())
        return fut

    def __len__(self) -> int:
        return len(self._items)


class CalibJobs:
    """Job bookkeeping shared by the calib.* handlers."""

    def __init__(self, publish: Callable[[str, Any], None]) -> None:
        self._publish = publish
        self._queue = _Mailbox()
        self._inboxes: dict[str, _Mailbox] = collections.defaultdict(_Mailbox)
        self.jobs: dict[str, dict[str, Any]] = {}
        self._seq = itertools.count(1)
        self.worker_seen: float | None = None

    def _need_job(self, req: Request) -> dict[str, Any]:
        job_id = req.args.get("job")
        if not isinstance(job_id, str) or job_id not in self.jobs:
            raise CommandError(ErrorCode.NOT_FOUND, f"{req.cmd}: no calibration job {job_id!r} "
                                                    f"(known: {', '.join(self.jobs) or 'none'})")
        return self.jobs[job_id]

    # ---------------------------------------------------------------- operator side

    def start(self, req: Request) -> Any:
        proc = req.args.get("procedure")
        if proc not in PROCEDURES:
            raise CommandError(ErrorCode.BAD_ARGS, f"calib.start: procedure {proc!r} is not one of {PROCEDURES}")
        params = req.args.get("params", {})
        if not isinstance(params, dict):
            raise CommandError(ErrorCode.BAD_ARGS, "calib.start: 'params' must be a map")
        job_id = req.args.get("job") or f"{time.strftime('%Y%m%dT%H%M%S')}-{proc}-{uuid.uuid4().hex[:6]}"
        if not isinstance(job_id, str):
            raise CommandError(ErrorCode.BAD_ARGS, "calib.start: 'job' must be a string")
        job = {"job": job_id, "procedure": proc, "params": params, "state": "queued", "by": req.peer,
               "posted_ns": time.time_ns(), "progress": None, "result": None, "prompt": None, "error": None}
        self.jobs[job_id] = job
        self._queue.put({k: job[k] for k in ("job", "procedure", "params")})
        self._publish("calib.progress", {"job": job_id, "step": "queued", "percent": 0.0,
                                         "waiting_for": "the calibration worker"})
        return {"job": job_id, "worker_seen_s_ago": self._worker_age()}

    def answer(self, req: Request) -> Any:
        job = self._need_job(req)
        self._inboxes[job["job"]].put({"answer": req.args.get("answer")})
        job["prompt"] = None
        return {"delivered": True}

    def cancel(self, req: Request) -> Any:
        job = self._need_job(req)
        self._inboxes[job["job"]].put({"cancel": True})
        return {"cancel_requested": True}

    def list(self, req: Request) -> Any:
        return {"jobs": list(self.jobs.values()), "queued": len(self._queue),
                "worker_seen_s_ago": self._worker_age()}

    def _worker_age(self) -> float | None:
        return None if self.worker_seen is None else round(time.monotonic() - self.worker_seen, 1)

    # ---------------------------------------------------------------- worker side

    def next(self, req: Request) -> Any:
        self.worker_seen = time.monotonic()
        timeout = req.args.get("timeout_s", 10.0)
        if not isinstance(timeout, (int, float)) or not 0 <= timeout <= 60:
            raise CommandError(ErrorCode.BAD_ARGS, f"calib.next: timeout_s={timeout!r} must be 0..60")
        return self._queue.get(float(timeout))

    def inbox(self, req: Request) -> Any:
        self.worker_seen = time.monotonic()
        job = self._need_job(req)
        timeout = req.args.get("timeout_s", 0.0)
        if not isinstance(timeout, (int, float)) or not 0 <= timeout <= 60:
            raise CommandError(ErrorCode.BAD_ARGS, f"calib.inbox: timeout_s={timeout!r} must be 0..60")
        return self._inboxes[job["job"]].get(float(timeout))

    def report(self, req: Request) -> Any:
        self.worker_seen = time.monotonic()
        kind = req.args.get("kind")
        if kind not in REPORT_KINDS:
            raise CommandError(ErrorCode.BAD_ARGS, f"calib.report: kind {kind!r} is not one of {REPORT_KINDS}")
        job_id = req.args.get("job")
        if not isinstance(job_id, str) or not job_id:  # it becomes a dict key and a name in messages
            raise CommandError(ErrorCode.BAD_ARGS, f"calib.report: 'job' must be a non-empty string, got {job_id!r}")
        if job_id not in self.jobs:
            # a job resumed by a restarted worker after a daemon restart: adopt it
            self.jobs[job_id] = {"job": job_id, "procedure": req.args.get("procedure", "?"), "params": {},
                                 "state": "running", "by": "worker (resumed)", "posted_ns": time.time_ns(),
                                 "progress": None, "result": None, "prompt": None, "error": None}
        job = self.jobs[job_id]
        data = req.args.get("data", {})
        job[kind] = data
        job["state"] = {"progress": "running", "prompt": "waiting", "result": "done", "error": "failed"}[kind]
        topic = "calib.result" if kind == "error" else f"calib.{kind}"
        self._publish(topic, {"job": job_id, **(data if isinstance(data, dict) else {"data": data}),
                              **({"failed": True} if kind == "error" else {})})
        return {"ok": True}

    def handlers(self) -> dict[str, Callable[[Request], Any]]:
        return {"calib.start": self.start, "calib.answer": self.answer, "calib.cancel": self.cancel,
                "calib.jobs": self.list, "calib.next": self.next, "calib.inbox": self.inbox,
                "calib.report": self.report}
