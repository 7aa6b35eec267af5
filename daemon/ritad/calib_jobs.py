"""Calibration job mailbox: how operators and the worker meet on the bus.

The worker is a plain bus client. Operators (ritactl) post jobs with ``calib.start``
and answers with ``calib.answer``; the worker long-polls ``calib.next`` for jobs and
``calib.inbox`` for answers/cancels, and sends ``calib.report`` which the daemon
republishes as ``calib.progress`` / ``calib.result`` / ``calib.prompt`` telemetry.
Long polls are Futures completed by a post or by a timer, so the ROUTER thread
never blocks. Handlers see args already checked by the command table (types, ranges,
procedure and kind choices); the job id's syntax and the job states are checked here.
"""
from __future__ import annotations

import collections
import json
import logging
import re
import threading
import time
import uuid
from concurrent.futures import Future
from pathlib import Path
from typing import Any, Callable

from daemon.bus.procedures import MOVING_PROCEDURES, PROCEDURES, check_params, get
from daemon.bus.protocol import CommandError, ErrorCode
from daemon.ritad.server import Request
from daemon.ritad.stop_latch import StopLatch
from daemon.ritad.timeouts import Timeouts
from daemon.bus.names import JobState, Topic

#: a job never leaves these by itself; ``calib.resume`` queues a failed or cancelled one again
FINAL_STATES = (JobState.DONE, JobState.FAILED, JobState.CANCELLED)
RESUMABLE = (JobState.FAILED, JobState.CANCELLED, JobState.STOPPED)
#: a robot STOP stops the jobs of moving procedures in these states
ACTIVE_STATES = (JobState.QUEUED, JobState.RUNNING, JobState.WAITING)
#: a stopped job whose worker has not reported the end of its run yet is resumed anyway after this long
#: without a sign of the worker (it died; the next worker finds the job stopped)
WORKER_GONE_S = 60.0
#: job ids name dataset folders: no separators, no leading dot
JOB_ID = re.compile(r"[A-Za-z0-9_][A-Za-z0-9._-]{0,127}")

log = logging.getLogger(__name__)


class _Mailbox:
    """A FIFO whose ``get`` returns a Future (completed now, on the next put, or None on timeout)."""

    def __init__(self, timeouts: Timeouts) -> None:
        self._timeouts = timeouts
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

    def remove(self, pred: Callable[[Any], bool]) -> bool:
        """Take the queued items ``pred`` matches out; whether there were any."""
        with self._lock:
            keep = [i for i in self._items if not pred(i)]
            found = len(keep) != len(self._items)
            self._items = collections.deque(keep)
        return found

    def get(self, timeout: float) -> Future:
        fut: Future = Future()
        with self._lock:
            if self._items or timeout <= 0:  # a poll that does not wait needs no timeout
                fut.set_result(self._items.popleft() if self._items else None)
                return fut
            self._waiters.append(fut)

        def expire() -> None:
            with self._lock:
                if fut in self._waiters:
                    self._waiters.remove(fut)
                    fut.set_result(None)

        pending = self._timeouts.call_later(timeout, expire)
        fut.add_done_callback(lambda _: pending.cancel())
        return fut

    def __len__(self) -> int:
        return len(self._items)


class CalibJobs:
    """Job bookkeeping shared by the calib.* handlers.

    States: ``queued`` → ``running`` ⇄ ``waiting`` (a prompt) → ``done`` | ``failed`` |
    ``cancelled``. The last three are final: once a job has a result or an error, later
    progress or prompt reports cannot move it back (a stale report is ignored), and only
    ``calib.resume`` of a failed or cancelled job queues it again. A robot STOP puts the
    active jobs of moving procedures into ``stopped`` at once (the worker learns it from its
    inbox, and the latch refuses its next motion); ``calib.resume`` continues a stopped job
    only after ``robot.release`` and after its worker has ended the stopped run.
    """

    def __init__(self, publish: Callable[[str, Any], None], data_dir: Path | None = None,
                 latch: StopLatch | None = None, timeouts: Timeouts | None = None) -> None:
        self._publish = publish
        # ritad passes its own; alone (tests, tools) the mailbox has one of its own
        self._timeouts = timeouts if timeouts is not None else Timeouts("calib-timeouts")
        self.latch = latch if latch is not None else StopLatch(publish)
        self._data_dir = Path(data_dir) if data_dir is not None else None  # finds an earlier run's jobs
        self._queue = _Mailbox(self._timeouts)
        self._inboxes: dict[str, _Mailbox] = collections.defaultdict(lambda: _Mailbox(self._timeouts))
        self.jobs: dict[str, dict[str, Any]] = {}
        self.worker_seen: float | None = None

    def _job_id(self, req: Request) -> str:
        job_id = req.args.get("job")
        if not isinstance(job_id, str) or not JOB_ID.fullmatch(job_id):
            raise CommandError(ErrorCode.BAD_ARGS,
                               f"{req.cmd}: 'job' must be a job id (letters, digits, . _ -), got {job_id!r}")
        return job_id

    def _need_job(self, req: Request) -> dict[str, Any]:
        job_id = self._job_id(req)
        if job_id not in self.jobs:
            raise CommandError(ErrorCode.NOT_FOUND, f"{req.cmd}: no calibration job {job_id!r} "
                                                    f"(recent: {', '.join(list(self.jobs)[-5:]) or 'none'}; "
                                                    f"`ritactl jobs` lists them)")
        return self.jobs[job_id]

    def _new_job(self, job_id: str, proc: str, params: dict[str, Any], by: str,
                 state: JobState) -> dict[str, Any]:
        job = {"job": job_id, "procedure": proc, "params": params, "state": state, "by": by,
               "posted_ns": time.time_ns(), "progress": None, "result": None, "prompt": None, "error": None}
        self.jobs[job_id] = job
        return job

    def _enqueue(self, job: dict[str, Any], step: str) -> dict[str, Any]:
        job.update(state=JobState.QUEUED, progress=None, result=None, prompt=None, error=None)
        self._inboxes.pop(job["job"], None)  # a stale answer or cancel must not hit the new run
        self._queue.put({k: job[k] for k in ("job", "procedure", "params")})
        self._publish(Topic.CALIB_PROGRESS, {"job": job["job"], "step": step, "percent": 0.0,
                                         "waiting_for": "the calibration worker"})
        return {"job": job["job"], "worker_seen_s_ago": self.worker_age()}

    # ---------------------------------------------------------------- operator side

    def _not_latched(self, cmd: str, proc: str) -> None:
        if proc in MOVING_PROCEDURES and self.latch.latched:
            raise CommandError(ErrorCode.STOPPED, self.latch.message(f"{cmd} ({proc} drives the robot)"))

    def start(self, req: Request) -> Any:
        proc, params = req.args["procedure"], req.args["params"]
        self._not_latched(req.cmd, proc)
        if req.args.get("job") is None:
            job_id = f"{time.strftime('%Y%m%dT%H%M%S')}-{proc}-{uuid.uuid4().hex[:6]}"
        else:
            job_id = self._job_id(req)
        # the daemon is the authority on parameters: bad ones never reach a job (a resume keeps the job's own,
        # a new job's are stored resolved: every default applied)
        if job_id in self.jobs:  # posting an existing id resumes it (as calib.resume does)
            check_params(proc, params, required=False, paths=False)
            job = self._resumable(req.cmd, self.jobs[job_id])
            if job["procedure"] != proc:
                raise CommandError(ErrorCode.BAD_ARGS,
                                   f"calib.start: job {job_id!r} is a {job['procedure']} job, not {proc}")
            return self._enqueue(job, "queued (resumed)")
        params = get(proc).resolve(params).to_dict()
        return self._enqueue(self._new_job(job_id, proc, params, req.peer, JobState.QUEUED), "queued")

    def resume(self, req: Request) -> Any:
        """Queue a failed or cancelled job again; the worker continues from its checkpoint."""
        job_id = self._job_id(req)
        job = self.jobs.get(job_id) or self._from_disk(req.cmd, job_id)
        return self._enqueue(self._resumable(req.cmd, job), "queued (resumed)")

    def _resumable(self, cmd: str, job: dict[str, Any]) -> dict[str, Any]:
        state = job["state"]
        self._not_latched(cmd, job["procedure"])
        age = self.worker_age()
        ended = job.get("run_ended", True)
        if state == JobState.STOPPED and not ended and age is not None and age < WORKER_GONE_S:
            raise CommandError(ErrorCode.BUSY, f"{cmd}: the worker has not yet ended the stopped run of job "
                                               f"{job['job']!r}; try again in a few seconds")
        if state == JobState.DONE:
            raise CommandError(ErrorCode.BAD_ARGS, f"{cmd}: job {job['job']!r} is done; there is nothing "
                                                   f"to resume (start a new job to measure again)")
        if state not in RESUMABLE:
            raise CommandError(ErrorCode.BAD_ARGS, f"{cmd}: job {job['job']!r} is still {state}; "
                                                   f"`ritactl follow {job['job']}` to watch it or "
                                                   f"`ritactl cancel {job['job']}`")
        return job

    def _from_disk(self, cmd: str, job_id: str) -> dict[str, Any]:
        """A job this daemon has not seen: adopt it from its dataset's checkpoint, if there is one."""
        path = None if self._data_dir is None else self._data_dir / "procedures" / job_id / "state.json"
        try:
            st = json.loads(path.read_text()) if path is not None else None
        except (OSError, ValueError):
            st = None
        if not isinstance(st, dict) or st.get("procedure") not in PROCEDURES:
            raise CommandError(ErrorCode.NOT_FOUND, f"{cmd}: no calibration job {job_id!r} "
                                                    f"(recent: {', '.join(list(self.jobs)[-5:]) or 'none'})")
        status = st.get("status")
        # "running" on disk: its worker died
        state = JobState(status) if status in (*FINAL_STATES, JobState.STOPPED) else JobState.FAILED
        return self._new_job(job_id, st["procedure"], {}, "dataset on disk", state)

    def answer(self, req: Request) -> Any:
        job = self._need_job(req)
        prompt = job.get("prompt")
        if job["state"] != JobState.WAITING or not isinstance(prompt, dict):
            raise CommandError(ErrorCode.BAD_ARGS, f"calib.answer: job {job['job']!r} is {job['state']} "
                                                   f"and is not asking anything now")
        answer = req.args.get("answer")
        choices = [str(c) for c in prompt.get("choices") or ["ok"]]
        if not isinstance(answer, str) or answer.strip() not in choices:
            raise CommandError(ErrorCode.BAD_ARGS, f"calib.answer: answer {answer!r} is not one of the "
                                                   f"choices {choices} (question: {prompt.get('question')})")
        self._inboxes[job["job"]].put({"answer": answer.strip()})
        job.update(prompt=None, state=JobState.RUNNING)
        return {"delivered": True}

    def cancel(self, req: Request) -> Any:
        job = self._need_job(req)
        if job["state"] in (*FINAL_STATES, JobState.STOPPED):
            raise CommandError(ErrorCode.BAD_ARGS, f"calib.cancel: job {job['job']!r} is already "
                                                   f"{job['state']}; there is nothing to cancel")
        self._inboxes[job["job"]].put({"cancel": True})
        return {"cancel_requested": True, "state": job["state"]}

    def list_jobs(self, req: Request) -> Any:
        return {"jobs": list(self.jobs.values()), "queued": len(self._queue),
                "worker_seen_s_ago": self.worker_age(), "latch": self.latch.snapshot()}

    def stop_moving_jobs(self, by: str) -> list[str]:
        """A robot STOP: every active job that drives becomes ``stopped`` now; their ids."""
        out = []
        for job in self.jobs.values():
            if job["procedure"] not in MOVING_PROCEDURES or job["state"] not in ACTIVE_STATES:
                continue
            job_id = job["job"]
            never_ran = self._queue.remove(lambda item: item.get("job") == job_id)  # runs now, in this turn
            if not never_ran:  # its worker sees this at its next bus call, before any further step
                self._inboxes[job_id].put({"stop": True})
            msg = (f"stopped by {by} (robot STOP); `ritactl robot release`, then `ritactl resume {job_id}` "
                   f"continues it from its last completed step")
            payload = {"job": job_id, "procedure": job["procedure"], "state": JobState.STOPPED,
                       "stopped": True, "failed": True, "message": msg}
            job.update(state=JobState.STOPPED, prompt=None, run_ended=never_ran, result=payload, error=msg)
            log.warning("job %s stopped by %s", job_id, by)
            self._publish(Topic.CALIB_RESULT, payload)
            out.append(job_id)
        return out

    def worker_age(self) -> float | None:
        """Seconds since the worker last called, or None if it never did (shown in ``daemon.health``)."""
        return None if self.worker_seen is None else round(time.monotonic() - self.worker_seen, 1)

    # ---------------------------------------------------------------- worker side

    def next(self, req: Request) -> Any:
        self.worker_seen = time.monotonic()
        return self._queue.get(float(req.args["timeout_s"]))

    def inbox(self, req: Request) -> Any:
        self.worker_seen = time.monotonic()
        job = self._need_job(req)
        return self._inboxes[job["job"]].get(float(req.args["timeout_s"]))

    def report(self, req: Request) -> Any:
        self.worker_seen = time.monotonic()
        kind = req.args["kind"]
        job_id = self._job_id(req)  # it becomes a dict key, a name in messages and a folder name
        data = req.args.get("data")
        data = {} if data is None else data if isinstance(data, dict) else {"data": data}
        job = self.jobs.get(job_id)
        if job is None:  # a job resumed by a restarted worker after a daemon restart: adopt it
            proc = req.args.get("procedure")
            job = self._new_job(job_id, proc if proc in PROCEDURES else "?", {}, "worker (resumed)",
                                JobState.RUNNING)
        # the worker ended the stopped run
        if job["state"] == JobState.STOPPED and kind in ("result", "error"):
            job["run_ended"] = True
            return {"ok": True, "ignored": f"job {job_id} is stopped"}
        if job["state"] in (*FINAL_STATES, JobState.STOPPED):
            log.info("job %s is %s: ignoring a late %s report", job_id, job["state"], kind)
            return {"ok": True, "ignored": f"job {job_id} is already {job['state']}"}
        if kind == "progress":
            job.update(progress=data, state=JobState.RUNNING)
            self._publish(Topic.CALIB_PROGRESS, {"job": job_id, **data})
        elif kind == "prompt":
            job.update(prompt=data, state=JobState.WAITING)
            self._publish(Topic.CALIB_PROMPT, {"job": job_id, **data})
        else:
            # a run the latched stop ended is "stopped" (resumable after release), also a job adopted above
            stopped = kind == "error" and bool(data.get("stopped"))
            state = (JobState.DONE if kind == "result" else JobState.CANCELLED if data.get("cancelled") else
                     JobState.STOPPED if stopped else JobState.FAILED)
            payload = {"job": job_id, **data, "state": state, **({"failed": True} if kind == "error" else {})}
            job.update(state=state, result=payload, prompt=None,
                       run_ended=True if stopped else job.get("run_ended"),
                       error=str(data.get("message", "failed")) if kind == "error" else None)
            log.info("job %s %s", job_id, state)
            self._publish(Topic.CALIB_RESULT, payload)
        return {"ok": True}

    def handlers(self) -> dict[str, Callable[[Request], Any]]:
        return {"calib.start": self.start, "calib.resume": self.resume, "calib.answer": self.answer,
                "calib.cancel": self.cancel, "calib.jobs": self.list_jobs, "calib.next": self.next,
                "calib.inbox": self.inbox, "calib.report": self.report}
