"""``python -m calibration.worker``: run calibration jobs posted on the bus.

Started by ritad (``[daemon] start_worker = true``) or by systemd beside it. It
resumes jobs a previous worker left unfinished, then long-polls ``calib.next``.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import traceback
from pathlib import Path
from typing import Any

from calibration.worker.compute import COMPUTE
from calibration.worker.job import Cancelled, JobContext
from calibration.worker.procedures import PROCEDURES
from calibration.worker.store import save_result
from daemon.client import Client, ClientTimeout
from daemon.protocol import CommandError

log = logging.getLogger("calibration.worker")


def run_job(client: Client, job: dict[str, Any], data_dir: Path) -> dict[str, Any] | None:
    """Run (or resume) one job to its end; report progress, prompts and the result on the bus."""
    ctx = JobContext(client, job, data_dir)
    ctx.state["status"] = "running"
    ctx.checkpoint()
    if ctx.resumed:
        ctx.progress("resumed", 1, f"skipping {len(ctx.state['done'])} completed step(s)")
    try:
        PROCEDURES[ctx.procedure](ctx)
        result = COMPUTE[ctx.procedure](ctx.obs, ctx.load_image)
        result.update(job=ctx.job_id, params={k: v for k, v in ctx.params.items()
                                              if k not in ("plate", "camera_model", "calibration")})
        result = save_result(ctx.root, data_dir, result)
    except Cancelled as exc:
        ctx.finish("cancelled")
        ctx.report("error", {"message": str(exc), "cancelled": True})
        return None
    except Exception as exc:  # noqa: BLE001 - any failure ends this job, never the worker
        # a device refused, a gate failed or input was bad: keep the observations, say how to resume
        ctx.finish("failed")
        msg = f"{type(exc).__name__}: {exc}. The data so far is kept; `ritactl resume {ctx.job_id}` continues."
        log.error("job %s failed: %s", ctx.job_id, msg)
        if not isinstance(exc, (CommandError, ValueError, TimeoutError, FileNotFoundError)):
            log.error("%s", traceback.format_exc())
        ctx.report("error", {"message": msg})
        return None
    ctx.finish("done")
    summary = {k: result.get(k) for k in ("procedure", "verdict", "messages", "rob_H_cam", "dataset", "mark",
                                          "table_markdown", "files", "uncertainty")}
    ctx.report("result", summary)
    ctx.progress("done", 100, "")
    return result


def unfinished(data_dir: Path) -> list[dict[str, Any]]:
    """Jobs a previous worker was running when it died."""
    out = []
    for state_path in sorted((data_dir / "procedures").glob("*/state.json")):
        try:
            st = json.loads(state_path.read_text())
        except (OSError, json.JSONDecodeError):
            continue
        if st.get("status") == "running":
            out.append({"job": st["job"], "procedure": st["procedure"], "params": st.get("params", {})})
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m calibration.worker", description="Rita calibration worker")
    ap.add_argument("--endpoint", help="ritad command endpoint (default $RITA_ENDPOINT)")
    ap.add_argument("--data-dir", help="where datasets and results go (default: the daemon's data_dir)")
    ap.add_argument("--once", action="store_true", help="exit after one job (tests)")
    ap.add_argument("--parent-pid", type=int, help="exit when this process (ritad) is gone")
    ap.add_argument("--log-level", default="INFO")
    args = ap.parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")

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
    for job in unfinished(data_dir):
        log.info("resuming job %s (%s)", job["job"], job["procedure"])
        run_job(client, job, data_dir)
        if args.once:
            return 0
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
            if args.once:
                return 0


if __name__ == "__main__":
    sys.exit(main())
