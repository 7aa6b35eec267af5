"""``python -m daemon.worker``: run calibration jobs posted on the bus.

Started by ritad (``[daemon] start_worker = true``) or by systemd beside it. It
resumes jobs a previous worker left unfinished, then long-polls ``calib.next``.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import logging
import os
import signal
import sys
import traceback
from pathlib import Path
from typing import Any

from calibration.errors import CalibrationError
from daemon.compute.procedures import COMPUTE, shown_params
from daemon.worker.finish import finish
from daemon.worker.job import Cancelled, JobContext, StepFailed, Stopped, ended_with
from daemon.worker.procedures import RUN
from daemon.worker.store import save_result
from daemon.bus.client import Client, ClientTimeout
from daemon.bus.names import JobState
from daemon.bus.protocol import CommandError

log = logging.getLogger("daemon.worker")


def operator_message(exc: BaseException) -> str:
    """What went wrong, in the operator's words, with what failed after it while the job ended."""
    return ended_with(exc, _what(exc))


def _what(exc: BaseException) -> str:
    """The error in the operator's words (no Python class names in front)."""
    if isinstance(exc, ClientTimeout):
        return f"the daemon did not answer ({exc.args[0]})"
    if isinstance(exc, StepFailed):
        return str(exc)
    if isinstance(exc, CommandError):
        return f"{exc.args[0]} [{exc.code}]"
    if isinstance(exc, CalibrationError):
        return f"the calculation could not give a trustworthy result: {exc}"
    if isinstance(exc, (FileNotFoundError, PermissionError)):
        return f"a file is missing or unreadable: {exc}"
    if isinstance(exc, KeyError):
        return f"{exc.args[0]!r} is missing from the parameters or the stored data"
    if isinstance(exc, (ValueError, TimeoutError)):
        return str(exc) or "bad input"
    # anything else is a bug in the worker: keep the class name, but not in front
    return f"internal error in the calibration worker, see worker.log ({type(exc).__name__}: {exc})"


def _digest(obs: dict[str, Any]) -> str:
    """A fingerprint of the stored observations: did a resume change anything?"""
    return hashlib.sha256(json.dumps(obs, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _compute(ctx: JobContext, before: dict[str, Any]) -> dict[str, Any]:
    """The result from the stored observations; ``before`` is the failure of the previous attempt."""
    ctx.progress("compute the result", 95, "")
    try:
        return COMPUTE[ctx.procedure](ctx.obs, ctx.load_image)
    except Exception as exc:
        ctx.state["failure"] = {"step": ctx.step, "obs": _digest(ctx.obs), "message": operator_message(exc)}
        if before.get("step") == ctx.step and before.get("obs") == _digest(ctx.obs):
            # resuming re-ran the calculation on exactly the data that failed before
            raise StepFailed("the calculation failed again on the same stored data (nothing was re-measured "
                             f"since the last attempt): {operator_message(exc)}. Start a new job after "
                             f"fixing the cause", resumable=False) from exc
        raise


def _dedupe(messages: list[str] | None) -> list[str]:
    """Both runs of a reversal report the same nest findings: say each once."""
    return list(dict.fromkeys(messages or []))


def run_job(client: Client, job: dict[str, Any], data_dir: Path) -> dict[str, Any] | None:
    """Run (or resume) one job to its end; report progress, prompts and the result on the bus."""
    ctx = JobContext(client, job, data_dir)
    ctx.state["status"] = JobState.RUNNING
    ctx.checkpoint()
    previous = ctx.state.pop("failure", None) or {}
    if ctx.resumed:
        failed = previous.get("step")
        ctx.progress("resumed", 1, f"{len(ctx.state['done'])} completed step(s) kept"
                     + (f"; re-running the failed step ({failed})" if failed else ""))
    try:
        ctx.check_cancel()
        RUN[ctx.procedure](ctx)
        result = _compute(ctx, previous)
        result.update(job=ctx.job_id, messages=_dedupe(result.get("messages")),
                      params=shown_params(ctx.procedure, ctx.params.to_dict()))
        result = finish(ctx, save_result(ctx.root, data_dir, result))  # activate, install, store the bias
    except Cancelled as exc:
        ctx.finish(JobState.CANCELLED)
        ctx.report("error", {"message": ended_with(exc), "cancelled": True})
        return None
    except Stopped as exc:  # no further bus call: the daemon already shows the job stopped
        log.warning("job %s stopped at %s: %s", ctx.job_id, ctx.step, ended_with(exc))
        ctx.finish(JobState.STOPPED)
        ctx.report("error", {"message": ended_with(exc), "stopped": True, "step": ctx.step})
        return None
    except Exception as exc:  # noqa: BLE001 - any failure ends this job, never the worker
        # a device refused, a gate failed or input was bad: keep the observations, say how to resume
        ctx.state.setdefault("failure", {"step": ctx.step, "message": operator_message(exc)})
        ctx.finish(JobState.FAILED)
        hint = (f"The data so far is kept; `ritactl resume {ctx.job_id}` re-runs the failed step."
                if getattr(exc, "resumable", True) else f"The data is kept in {ctx.root}.")
        msg = f"{ctx.step}: {operator_message(exc)}. {hint}"
        log.error("job %s failed: %s", ctx.job_id, msg)
        expected = (CommandError, ValueError, TimeoutError, OSError, CalibrationError, StepFailed)
        if not isinstance(exc, expected):  # a bug: its traceback goes to the log
            log.error("%s", traceback.format_exc())
        ctx.report("error", {"message": msg, "step": ctx.step})
        return None
    ctx.state.pop("failure", None)
    ctx.finish(JobState.DONE)
    summary = {k: result.get(k) for k in ("procedure", "verdict", "messages", "rob_H_cam", "dataset", "mark",
                                          "table_markdown", "files", "uncertainty", "compensation",
                                          "metrics", "checks")}  # metrics: ritactl marks the goals
    ctx.report("result", summary)  # the last report: a job with a result is final
    return result


def _stopped_in_daemon(client: Client) -> set[str]:
    """Jobs the daemon holds as stopped: a restarted worker must not resume them on its own."""
    try:
        jobs = client.call("calib.jobs", timeout=10)["jobs"]
        return {j["job"] for j in jobs if j.get("state") == JobState.STOPPED}
    except (ClientTimeout, CommandError, KeyError, TypeError):
        return set()


def unfinished(data_dir: Path) -> list[dict[str, Any]]:
    """Jobs a previous worker was running when it died."""
    out = []
    for state_path in sorted((data_dir / "procedures").glob("*/state.json")):
        try:
            st = json.loads(state_path.read_text())
        except (OSError, json.JSONDecodeError):
            continue
        if st.get("status") == JobState.RUNNING:
            out.append({"job": st["job"], "procedure": st["procedure"], "params": st.get("params", {})})
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m daemon.worker", description="Rita calibration worker")
    ap.add_argument("--endpoint", help="ritad command endpoint (default $RITA_ENDPOINT)")
    ap.add_argument("--data-dir", help="where datasets and results go (default: the daemon's data_dir)")
    ap.add_argument("--parent-pid", type=int, help="exit when this process (ritad) is gone")
    ap.add_argument("--log-level", default="INFO")
    args = ap.parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")

    def on_term(*_: object) -> None:
        # leave at once, even from inside a long poll or a job: every completed step is
        # checkpointed, and a job left "running" is resumed by the next worker
        raise SystemExit(0)

    signal.signal(signal.SIGTERM, on_term)
    client = Client(args.endpoint, timeout=30)
    try:
        data_dir = Path(args.data_dir or client.call("data.dir")["data_dir"])
    except ClientTimeout as exc:
        print(f"calibration worker: {exc.args[0]}", file=sys.stderr)
        return 3
    stopped = _stopped_in_daemon(client)
    for job in unfinished(data_dir):
        if job["job"] in stopped:  # stopped while its worker was gone: it waits for calib.resume
            ctx = JobContext(client, job, data_dir)
            ctx.finish(JobState.STOPPED)
            ctx.report("error", {"message": "stopped while no worker ran it", "stopped": True})
            continue
        log.info("resuming job %s (%s)", job["job"], job["procedure"])
        run_job(client, job, data_dir)
    log.info("waiting for jobs from %s", client.endpoint)
    while True:
        if args.parent_pid and os.getppid() != args.parent_pid:
            log.info("ritad (pid %d) is gone: exiting", args.parent_pid)
            return 0
        try:
            job = client.call("calib.next", timeout=20, timeout_s=10)
        except ClientTimeout:
            continue  # the daemon may be restarting: keep trying
        if job:
            run_job(client, job, data_dir)


if __name__ == "__main__":
    sys.exit(main())
