"""ritactl verbs for the calibration procedures: start, follow, answer prompts, results.

A procedure runs in the worker on the robot; ritactl only posts it and follows its
``calib.*`` telemetry. Ctrl-C detaches (the job goes on); ``ritactl follow JOB``
attaches again, ``ritactl cancel JOB`` stops it, ``ritactl resume JOB`` continues a
failed or cancelled job from its last completed step.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from daemon.client import Client


def _load_json(path: str | None, what: str) -> Any:
    if not path:
        return None
    try:
        return json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise SystemExit(f"ritactl: cannot read {what} {path}: {exc}") from None


def follow(c: Client, job: str, interactive: bool = True) -> int:
    """Print progress of ``job`` until its result; answer prompts from the keyboard."""
    sub = c.subscriber(["calib."])
    snap = c.call("calib.jobs")
    known = {j["job"]: j for j in snap["jobs"]}
    if job in known and known[job]["state"] in ("done", "failed") and known[job].get("result"):
        sub.close()
        return _show_result(known[job]["result"])
    try:
        while True:
            msg = sub.recv(1.0)
            if msg is None:
                continue
            topic, m, _ = msg
            d = m["data"]
            if d.get("job") != job:
                continue
            if topic == "calib.progress":
                wait = f" — waiting for {d['waiting_for']}" if d.get("waiting_for") else ""
                print(f"[{d.get('percent', 0):5.1f}%] {d.get('step')}{wait}", flush=True)
            elif topic == "calib.prompt":
                print(f"\n>>> {d['question']}  {d.get('choices')}", flush=True)
                if not interactive or not sys.stdin.isatty():
                    print(f"    answer with: ritactl answer {job} <text>", flush=True)
                    continue
                answer = input("answer> ").strip()
                c.call("calib.answer", job=job, answer=answer)
            elif topic == "calib.result":
                return _show_result(d)
    except KeyboardInterrupt:
        print(f"\ndetached; the job goes on. `ritactl follow {job}` to watch, `ritactl cancel {job}` to stop it.")
        return 0
    finally:
        sub.close()


def _show_result(d: dict[str, Any]) -> int:
    if d.get("failed"):
        print(f"FAILED: {d.get('message')}")
        return 1
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
    if d.get("table_markdown"):
        print("\n" + d["table_markdown"])
    print(f"  dataset: {d.get('dataset')}  {' '.join(d.get('files') or [])}")
    return 0 if d.get("verdict") != "fail" else 1


def _start(c: Client, a: argparse.Namespace, procedure: str, params: dict[str, Any]) -> int:
    r = c.call("calib.start", procedure=procedure, params={k: v for k, v in params.items() if v is not None},
               **({"job": a.job} if getattr(a, "job", None) else {}))
    job = r["job"]
    print(f"job {job} posted", flush=True)
    if r.get("worker_seen_s_ago") is None:
        print("  (no calibration worker has contacted the daemon yet: is it running?)", flush=True)
    return 0 if a.detach else follow(c, job)


def cmd_calibrate(c: Client, a: argparse.Namespace) -> int:
    params = {"plate": _load_json(a.plate, "plate definition"),
              "camera_model": _load_json(a.camera_model, "camera model"),
              "nests_approx_trk": _load_json(a.nests_approx, "approximate nest positions"),
              "robot_approx_trk": a.robot_approx, "reversal": a.reversal, "distance_mm": a.distance}
    return _start(c, a, "referencing", params)


def cmd_intrinsics(c: Client, a: argparse.Namespace) -> int:
    return _start(c, a, "intrinsics", {"plate": _load_json(a.plate, "plate definition"), "views": a.views,
                                       "camera_model": _load_json(a.camera_model, "camera model")})


def cmd_measure_mark(c: Client, a: argparse.Namespace) -> int:
    return _start(c, a, "measure-mark", {"mark_xy": a.mark, "heading_deg": a.heading, "kind": a.kind})


def cmd_experiment(c: Client, a: argparse.Namespace) -> int:
    return _start(c, a, "experiment", {"mark_xy": a.mark, "directions": a.directions, "repetitions": a.reps,
                                       "seed": a.seed, "kind": a.kind, "psi0_deg": a.psi0})


def cmd_results(c: Client, a: argparse.Namespace) -> int:
    r = c.call("calib.results")
    if a.json:
        print(json.dumps(r, indent=2))
        return 0
    act = r.get("active")
    if act:
        print(f"active calibration: job {act.get('job')} ({act.get('created')}), verdict {act.get('verdict')}")
        _show_result(act)
    else:
        print("no active calibration yet (run `ritactl calibrate`)")
    print("\nhistory:")
    for h in r["history"]:
        print(f"  {h.get('created')}  {h.get('procedure'):13s} {h.get('verdict')!s:5s} {h.get('job')}")
    return 0


def cmd_jobs(c: Client, a: argparse.Namespace) -> int:
    r = c.call("calib.jobs")
    for j in r["jobs"]:
        p = j.get("progress") or {}
        print(f"{j['job']:50s} {j['procedure']:13s} {j['state']:8s} {p.get('percent', '')} {p.get('step', '')}")
    print(f"worker last seen {r.get('worker_seen_s_ago')} s ago")
    return 0


def cmd_answer(c: Client, a: argparse.Namespace) -> int:
    c.call("calib.answer", job=a.job_id, answer=a.text)
    return 0


def cmd_cancel(c: Client, a: argparse.Namespace) -> int:
    c.call("calib.cancel", job=a.job_id)
    print(f"cancel requested for {a.job_id}")
    return 0


def cmd_resume(c: Client, a: argparse.Namespace) -> int:
    jobs = {j["job"]: j for j in c.call("calib.jobs")["jobs"]}
    proc = a.procedure or (jobs.get(a.job_id) or {}).get("procedure")
    if proc is None:
        print("ritactl: unknown job to this daemon; give --procedure", file=sys.stderr)
        return 2
    c.call("calib.start", procedure=proc, job=a.job_id, params={})
    return follow(c, a.job_id)


def cmd_follow(c: Client, a: argparse.Namespace) -> int:
    return follow(c, a.job_id)


def add_parsers(sub: Any) -> None:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument("--detach", action="store_true", help="post the job and return")
    common.add_argument("--job", help="job id (default: generated)")
    p = sub.add_parser("calibrate", parents=[common], help="referencing: rob_H_cam with the plate")
    p.add_argument("--plate", help="plate definition JSON (default: the robot's installed one)")
    p.add_argument("--camera-model", help="camera model JSON (default: the robot's installed one)")
    p.add_argument("--nests-approx", help='JSON {"red": [x, y, z], ...}: approximate nests, tracker frame, mm')
    p.add_argument("--robot-approx", nargs=3, type=float, metavar=("X", "Y", "Z"),
                   help="approximate robot reflector, tracker frame, mm")
    p.add_argument("--reversal", action="store_true", help="second referencing turned 180° (instrument reversal)")
    p.add_argument("--distance", type=float, help="straight drive between P0 and P1, mm (default 200)")
    p.set_defaults(fn=cmd_calibrate)
    p = sub.add_parser("intrinsics", parents=[common], help="camera model from several views of the target")
    p.add_argument("--plate")
    p.add_argument("--camera-model", help="initial guess")
    p.add_argument("--views", type=int, default=6)
    p.set_defaults(fn=cmd_intrinsics)
    for name, fn in (("measure-mark", cmd_measure_mark), ("experiment", cmd_experiment)):
        p = sub.add_parser(name, parents=[common], help=f"{name} with the active calibration")
        p.add_argument("--mark", nargs=2, type=float, required=True, metavar=("X", "Y"),
                       help="approximate mark position, ACS mm")
        p.add_argument("--kind", default="dot", choices=["dot", "cross"])
        if name == "measure-mark":
            p.add_argument("--heading", type=float, help="approach heading, ACS degrees")
        else:
            p.add_argument("--directions", type=int, default=8)
            p.add_argument("--reps", type=int, default=5)
            p.add_argument("--seed", type=int, default=1)
            p.add_argument("--psi0", type=float, default=0.0, help="heading of the first direction, deg")
        p.set_defaults(fn=fn)
    sub.add_parser("results", help="active calibration and history").set_defaults(fn=cmd_results)
    sub.add_parser("jobs", help="calibration jobs and their state").set_defaults(fn=cmd_jobs)
    for name, fn in (("follow", cmd_follow), ("cancel", cmd_cancel), ("resume", cmd_resume)):
        p = sub.add_parser(name, help=f"{name} a calibration job")
        p.add_argument("job_id")
        if name == "resume":
            p.add_argument("--procedure")
        p.set_defaults(fn=fn)
    p = sub.add_parser("answer", help="answer a procedure's prompt")
    p.add_argument("job_id")
    p.add_argument("text")
    p.set_defaults(fn=cmd_answer)


__all__ = ["add_parsers", "follow"]
