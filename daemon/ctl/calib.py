"""ritactl verbs for the calibration procedures: start, follow, answer prompts, results.

A procedure runs in the worker on the robot; ritactl only posts it and follows its
``calib.*`` telemetry. Ctrl-C detaches (the job goes on) after asking whether to cancel
it, since every procedure drives the robot; ``ritactl follow JOB`` attaches again,
``ritactl cancel JOB`` stops it, ``ritactl resume JOB`` continues a failed or cancelled
job from its last completed step. Procedure verbs exit with ``for_verdict``.
"""
from __future__ import annotations

import argparse
import sys
import time
from typing import Any

from daemon.bus.client import Client
from daemon.bus.command_table import COMMANDS
from daemon.bus.names import JobState
from daemon.bus.procedures import BY_NAME, MOVING_PROCEDURES
from daemon.ctl.device import add_table_args, table_args
from daemon.ctl.procverbs import add_procedure_parsers
from daemon.ctl.io import ask, print_result, say, yes_after_ctrl_c
from daemon.ctl.exitcodes import Exit, for_verdict
from daemon.bus.protocol import CommandError, ErrorCode
from daemon.bus.figures import counted, counted_from, experiment_goal_lines

POLL_S = 1.0  # how often follow re-reads calib.jobs, which catches results telemetry did not bring


def job_record(c: Client, job: str) -> dict[str, Any]:
    for j in c.call("calib.jobs")["jobs"]:
        if j.get("job") == job:
            return j
    raise CommandError(ErrorCode.NOT_FOUND, f"no such job {job!r} (`ritactl jobs` lists them)")


def final_of(j: dict[str, Any]) -> dict[str, Any] | None:
    """A job's end as a result message, or None while it runs.

    A stored result or error is final whatever ``state`` says (the worker's last
    progress report may have set it back to running).
    """
    state = j.get("state")
    if isinstance(j.get("result"), dict) and j["result"]:  # also a failure's, with failed/cancelled set
        cancelled = {"cancelled": True} if state == JobState.CANCELLED else {}
        return {"job": j["job"], **j["result"], **cancelled}
    err = j.get("error")
    if err or state in (JobState.FAILED, JobState.CANCELLED, JobState.STOPPED):
        msg = err.get("message") if isinstance(err, dict) else (err or f"job {state}")
        return {"job": j["job"], "failed": True, "cancelled": state == JobState.CANCELLED,
                "stopped": state == JobState.STOPPED, "message": str(msg)}
    return None


def _prompt_key(d: dict[str, Any]) -> tuple[Any, ...]:
    return d.get("question"), tuple(d.get("choices") or ())


def _interactive() -> bool:
    try:
        return sys.stdin is not None and sys.stdin.isatty()
    except (ValueError, OSError):  # stdin closed
        return False


def _answer_prompt(c: Client, job: str, d: dict[str, Any], interactive: bool, as_json: bool) -> None:
    say(f"\n>>> {d.get('question')}  {d.get('choices')}", as_json)
    hint = f"    answer with: ritactl answer {job} <text>"
    if not (interactive and _interactive()):
        say(hint, as_json)
        return
    text = ask("answer> ")
    if text is None:  # Ctrl-D: leave the answer to another terminal and keep following
        say(f"\n{hint}", as_json)
        return
    choices = d.get("choices") or []
    c.call("calib.answer", job=job, answer=text or (choices[0] if len(choices) == 1 else ""))


def _follow(c: Client, sub: Any, j: dict[str, Any] | None, job: str, interactive: bool, as_json: bool) -> int:
    shown: tuple[Any, ...] | None = None
    next_poll = 0.0
    while True:
        if time.monotonic() >= next_poll:
            j = j or job_record(c, job)
            end = final_of(j)
            if end is not None:
                return show_result(end, as_json)
            if isinstance(j.get("prompt"), dict) and _prompt_key(j["prompt"]) != shown:
                shown = _prompt_key(j["prompt"])
                _answer_prompt(c, job, j["prompt"], interactive, as_json)
            j, next_poll = None, time.monotonic() + POLL_S
        msg = sub.recv(0.25)
        if msg is None or not isinstance(msg[1].get("data"), dict) or msg[1]["data"].get("job") != job:
            continue
        topic, d = msg[0], msg[1]["data"]
        if topic == "calib.result":
            return show_result(d, as_json)
        if topic == "calib.progress":
            wait = f" — waiting for {d['waiting_for']}" if d.get("waiting_for") else ""
            say(f"[{d.get('percent') or 0:5.1f}%] {d.get('step')}{wait}", as_json)
        elif topic == "calib.prompt" and _prompt_key(d) != shown:
            shown = _prompt_key(d)
            _answer_prompt(c, job, d, interactive, as_json)


def _interrupted(c: Client, job: str, procedure: str | None, as_json: bool) -> int:
    """Ctrl-C while following: detach, or stop the robot in a motion procedure (asked; Ctrl-C again: yes)."""
    reattach = f"`ritactl follow {job}` re-attaches"
    if procedure not in MOVING_PROCEDURES:
        say(f"\ndetached; job {job} goes on. {reattach}, `ritactl cancel {job}` stops it.", as_json)
        return Exit.INTERRUPTED
    if yes_after_ctrl_c(f"job {job} moves the robot. stop the robot (and the job)?", as_json):
        r = c.call("robot.stop")  # the one latched stop, as `ritactl robot stop` and the console's STOP
        halted = "stopped and latched" if r.get("stopped") else r.get("message")  # latched; halt still owed
        say(f"\nrobot {halted}; stopped job(s): {', '.join(r.get('jobs_stopped') or []) or 'none'}. "
            f"`ritactl robot release`, then `ritactl resume {job}` continues it.", as_json)
    else:
        say(f"detached; job {job} goes on AND MAY STILL MOVE THE ROBOT. `ritactl robot stop` stops the robot "
            f"and the job, `ritactl cancel {job}` cancels it after its current step; {reattach}.", as_json)
    return Exit.INTERRUPTED


def follow(c: Client, job: str, interactive: bool = True, as_json: bool = False) -> int:
    """Print ``job``'s progress until its end and exit with its verdict; answer prompts from the keyboard.

    Returns at once for a job that has ended; an unknown job raises ``not_found``.
    """
    sub = c.subscriber(["calib."])  # subscribe first: the snapshot below covers what came before
    procedure = None
    try:
        j = job_record(c, job)
        procedure = j.get("procedure")
        return _follow(c, sub, j, job, interactive, as_json)
    except KeyboardInterrupt:
        return _interrupted(c, job, procedure, as_json)
    finally:
        sub.close()


def show_result(d: dict[str, Any], as_json: bool = False) -> int:
    """Print a job's result (or failure); its exit code (``for_verdict``; failed/cancelled/stopped: FAIL)."""
    code = Exit.FAIL if d.get("failed") else for_verdict(d.get("verdict"))
    if as_json:
        print_result(d, True)
        return code
    if d.get("failed"):
        print(f"{'CANCELLED' if d.get('cancelled') else 'STOPPED' if d.get('stopped') else 'FAILED'}: "
              f"{d.get('message')}")
        return code
    print(f"\nresult: {d.get('procedure')} verdict={d.get('verdict')}")
    for m in d.get("messages") or []:
        print(f"  - {m}")
    if d.get("rob_H_cam"):
        print("  rob_H_cam =")
        for row in d["rob_H_cam"]:
            print("    " + " ".join(f"{v:12.6f}" for v in row))
    unc = d.get("uncertainty")
    if unc:
        t = ", ".join(f"{v * 1000:.1f}" for v in unc["std_t_mm"])
        r = ", ".join(f"{v * 3600:.1f}" for v in unc["std_rot_deg"])
        print(f"  1σ: translation ({t}) µm, rotation ({r}) arcsec, camera footprint "
              f"{unc['footprint_std_mm'] * 1000:.1f} µm")
    if d.get("mark"):
        x, y, z = d["mark"]["abs_xyz"]
        print(f"  mark at ACS ({x:.4f}, {y:.4f}, {z:.4f}) mm ± {d['mark']['std_mm'] * 1000:.0f} µm")
    if view_of(d.get("procedure")) == "checks" and d.get("checks"):  # one line per check, as the kit's
        print_checks(d["checks"])
    elif d.get("table_markdown"):
        print("\n" + d["table_markdown"])
    for line in experiment_goal_lines(d.get("metrics")):  # each goal met or MISSED, never a bare figure
        print(f"  {line}")
    comp = d.get("compensation")
    if comp:  # which compensations took effect, and why not
        counts = (f"{n} {comp['applied'].get(n, 0)}/{comp['stops']}" for n in comp["requested"])
        done = ", ".join(counts) or "none"
        print(f"  compensations (stops applied): {done}")
        # counted over the stops (a result from before the counts: each reason once)
        for n, why in (comp.get("skipped") or {}).items():
            stops = (comp.get("skipped_stops") or {}).get(n)
            print(f"    {n} skipped: {'; '.join(counted_from(stops) if stops else counted(why))}")
    print(f"  dataset: {d.get('dataset')}  {' '.join(d.get('files') or [])}")
    return code




def view_of(procedure: Any) -> str:
    """What a procedure's result shows (daemon/bus/procedures.py ``view``); "" for an unknown one."""
    proc = BY_NAME.get(procedure) if isinstance(procedure, str) else None
    return proc.view if proc else ""


def print_checks(checks: list[dict[str, Any]]) -> None:
    """A commissioning's checks: verdict, device, check, the measured value and why."""
    for c in checks:
        detail = f"  ({c['detail']})" if c.get("detail") else ""
        verdict = str(c.get("verdict")).upper()
        print(f"  {verdict:4}  {c.get('device')!s:7} {c.get('name')!s:18} {c.get('value')}{detail}")
    n = {v: sum(1 for c in checks if c.get("verdict") == v) for v in ("pass", "fail", "warn", "skip")}
    print(f"  {n['pass']} passed, {n['fail']} failed, {n['warn']} warned, {n['skip']} skipped")


_show_result = show_result  # the name daemon/ctl/datasets.py imports (recompute)


def _start(c: Client, a: argparse.Namespace, procedure: str, params: dict[str, Any]) -> int:
    r = c.call("calib.start", procedure=procedure, params={k: v for k, v in params.items() if v is not None},
               **({"job": a.job} if getattr(a, "job", None) else {}))
    job = r["job"]
    if a.detach and a.json:
        print_result(r, True)
    else:
        say(f"job {job} posted", a.json)
    if r.get("worker_seen_s_ago") is None:
        say("  (no calibration worker has contacted the daemon yet: is it running?)", a.json)
    return Exit.OK if a.detach else follow(c, job, as_json=a.json)


def cmd_results(c: Client, a: argparse.Namespace) -> int:
    r = c.call("calib.results")
    if a.json:
        print_result(r, True)
        return Exit.OK
    act = r.get("active")
    if act:
        print(f"active calibration: job {act.get('job')} ({act.get('created')}), "
              f"verdict {act.get('verdict')}")
        show_result(act)
    else:
        print("no active calibration yet (run `ritactl calibrate`)")
    print("\nhistory:")
    for h in r["history"]:
        print(f"  {h.get('created')}  {h.get('procedure')!s:13s} {h.get('verdict')!s:5s} {h.get('job')}")
    return Exit.OK


def cmd_jobs(c: Client, a: argparse.Namespace) -> int:
    r = c.call("calib.jobs")
    if a.json:
        print_result(r, True)
        return Exit.OK
    for j in r["jobs"]:
        end = final_of(j)
        state = j["state"] if end is None else (
            JobState.CANCELLED if end.get("cancelled") else JobState.STOPPED if end.get("stopped")
            else JobState.FAILED if end.get("failed") else JobState.DONE)
        p = {} if end else (j.get("progress") or {})
        print(f"{j['job']:50s} {j['procedure']!s:13s} {state:9s} {p.get('percent', '')} {p.get('step', '')}")
    if (r.get("latch") or {}).get("latched"):
        print(f"STOP LATCHED by {r['latch'].get('by')}: stopped jobs resume after `ritactl robot release`")
    print(f"worker last seen {r.get('worker_seen_s_ago')} s ago")
    return Exit.OK


def cmd_answer(c: Client, a: argparse.Namespace) -> int:
    print_result(c.call_raw("calib.answer", table_args(COMMANDS["calib.answer"], a))[0], a.json)
    return Exit.OK


def cmd_cancel(c: Client, a: argparse.Namespace) -> int:
    r = c.call_raw("calib.cancel", table_args(COMMANDS["calib.cancel"], a))[0]
    print_result(r, True) if a.json else print(f"cancel requested for {a.arg_job}")
    return Exit.OK


def cmd_resume(c: Client, a: argparse.Namespace) -> int:
    # the daemon knows the procedure, also for a job of an earlier run
    r = c.call("calib.resume", job=a.job_id)
    if getattr(a, "detach", False):  # as a procedure verb's --detach: posted, exit 0, follow it later
        print_result(r, True) if a.json else print(f"job {a.job_id} resumed (`ritactl follow {a.job_id}`)")
        return Exit.OK
    return follow(c, a.job_id, as_json=a.json)


def cmd_follow(c: Client, a: argparse.Namespace) -> int:
    return follow(c, a.job_id, as_json=a.json)


def add_parsers(sub: Any) -> None:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--detach", action="store_true", help="post the job and return (exit 0)")
    common.add_argument("--job", help="job id (default: generated)")
    add_procedure_parsers(sub, common, _start)  # one verb per declared procedure
    sub.add_parser("results", help="active calibration and history").set_defaults(fn=cmd_results)
    sub.add_parser("jobs", help="calibration jobs and their state").set_defaults(fn=cmd_jobs)
    for name, fn, what in (
            ("follow", cmd_follow, "print a job's progress until it ends; exit with its verdict"),
            ("resume", cmd_resume, "continue a failed or cancelled job from its last step")):
        p = sub.add_parser(name, help=what)
        p.add_argument("job_id", metavar="JOB", help="job id (`ritactl jobs` lists them)")
        if name == "resume":
            p.add_argument("--detach", action="store_true", help="resume the job and return (exit 0)")
        p.set_defaults(fn=fn)
    for verb, cmd, fn in (("cancel", "calib.cancel", cmd_cancel), ("answer", "calib.answer", cmd_answer)):
        p = sub.add_parser(verb, help=COMMANDS[cmd].help)
        add_table_args(p, COMMANDS[cmd])
        p.set_defaults(fn=fn)
