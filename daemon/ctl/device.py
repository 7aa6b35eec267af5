"""ritactl's per-device subcommands (``tracker``, ``robot``, ``camera``), generated from the command table.

Each table entry with ``cli`` words becomes one subcommand with exactly its own
arguments, typed and range-checked here so a bad value is a usage error (exit 64)
that names it. Bus argument names in the daemon's error messages get the option that
sets them appended, so the operator knows what to type.
"""
from __future__ import annotations

import argparse
import math
import re
from pathlib import Path
from typing import Any, Callable

from daemon.bus.client import Client, ClientTimeout
from daemon.bus.command_table import COMMANDS, POS, TABLE, Arg, Command
from daemon.ctl.io import print_result, say, yes_after_ctrl_c
from daemon.ctl.exitcodes import CtlError, Exit
from daemon.bus.png_write import frame_png
from daemon.bus.protocol import CommandError, ErrorCode
from daemon.bus.storage import atomic_write_bytes, atomic_write_json

# options that act on this computer only, not sent to the daemon
LOCAL_OPTIONS: dict[str, tuple[tuple[str, dict[str, Any]], ...]] = {
    "camera.capture": (("--out", {"metavar": "FILE.png",
                                  "help": "save the frame here, on this computer, as a lossless PNG "
                                          "(+ FILE.json metadata) instead of storing it on the robot"}),),
}


def _detect_text(r: dict[str, Any]) -> tuple[str, Exit]:
    """``camera detect``: the count or the mark's position; nothing found is exit 2 (FAIL)."""
    where = (f"frame {r.get('frame_id')}, searched {r.get('searched_w')}×{r.get('searched_h')} of "
             f"{r.get('full_w')}×{r.get('full_h')} px, {r.get('took_s')} s")
    if r.get("target") == "plate":
        if not r.get("found"):
            return f"no corners of plate {r.get('plate_id')} found ({where})", Exit.FAIL
        uv = r["uv"]
        box = [min(p[0] for p in uv), min(p[1] for p in uv), max(p[0] for p in uv), max(p[1] for p in uv)]
        return (f"{r['n']} corners of plate {r.get('plate_id')} ({where}); "
                f"within u {box[0]:.0f}–{box[2]:.0f}, v {box[1]:.0f}–{box[3]:.0f} px"), Exit.OK
    if not r.get("found"):
        return f"no {r.get('target')} mark found ({where}): {r.get('message', '')}", Exit.FAIL
    u, v = r["uv"]
    return f"{r.get('target')} mark at u {u:.2f}, v {v:.2f} px ({where})", Exit.OK


def motion_text(verb: str, r: dict[str, Any]) -> tuple[str, Exit]:
    """``robot move``/``turn``: one line on how the motion ended and where the odometry puts the robot.

    The exit code stays the call's (OK): a motion the base cut short says STOPPED in the line.
    """
    if r.get("started"):
        return (f"robot {verb} started; not waiting for its end (`ritactl robot status` shows the robot)",
                Exit.OK)
    result = str(r.get("result"))
    if r.get("recovered"):  # the base's DONE was lost: the end was read from STATUS, not how it ended
        how = "ended (its DONE event was lost: whether it completed is not known)"
    else:
        how = {"OK": "done", "STOPPED": "STOPPED before its end"}.get(result, f"ended ({result})")
    x, y, h = (r.get(k) for k in ("x_mm", "y_mm", "heading_deg"))
    where = "" if None in (x, y, h) else f"; odometry x {x:.1f} mm, y {y:.1f} mm, heading {h:.2f}°"
    return f"robot {verb} {how}{where}", Exit.OK


def stop_text(r: dict[str, Any]) -> tuple[str, Exit]:
    """``robot stop``: one line, whether the base confirmed the halt, the latch and the jobs it stopped."""
    halted = "robot halted" if r.get("stopped") else f"robot NOT YET HALTED ({r.get('message', 'no answer')})"
    jobs = r.get("jobs_stopped") or []
    stopped = f"; {len(jobs)} job(s) stopped: {', '.join(jobs)}" if jobs else ""
    return f"{halted}; latched: no motion until `ritactl robot release`{stopped}", Exit.OK


def release_text(r: dict[str, Any]) -> tuple[str, Exit]:
    """``robot release``: one line, and whether there was a latch to release."""
    was = "released the STOP latch" if r.get("was_latched") else "nothing to release (no STOP latched)"
    return f"{was}: motions are allowed (a stopped job continues with `ritactl resume JOB`)", Exit.OK


#: results a generated subcommand shows in words (with --json: the result, same exit code)
RESULT_TEXT: dict[str, Callable[[dict[str, Any]], tuple[str, Exit]]] = {
    "camera.detect": _detect_text, "robot.move": lambda r: motion_text("move", r),
    "robot.turn": lambda r: motion_text("turn", r), "robot.stop": stop_text, "robot.release": release_text}


def number_type(arg: Arg) -> Callable[[str], float]:
    """argparse type for a numeric table argument: finite and inside the table's range."""
    def parse(text: str) -> float:
        try:
            value = float(text) if arg.type == "float" else int(text)
        except ValueError:
            what = "a number" if arg.type == "float" else "an integer"
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}")
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
        why = arg.check(value)
        if why:
            raise argparse.ArgumentTypeError(why)
        return value

    return parse


def option_help(arg: Arg) -> str:
    """The table's help, plus unit, range and default: every option gets a help text."""
    notes = [n for n in (arg.unit, arg.range_text()) if n]
    if arg.type != "bool" and not arg.required:
        shown = arg.default_text or (None if arg.default is None else f"{arg.default:g}"
                                     if isinstance(arg.default, float) else arg.default)
        if shown is not None:
            notes.append(f"default {shown}")
    return arg.help + (f" ({'; '.join(notes)})" if notes else "")


def _dest(arg: Arg) -> str:
    return "arg_" + arg.name


def add_table_args(p: argparse.ArgumentParser, cmd: Command) -> None:
    """Add the CLI form of ``cmd``'s arguments to ``p``."""
    for arg in cmd.args:
        if arg.cli is None:
            continue
        kind: dict[str, Any] = {"help": option_help(arg)}
        if arg.type in ("float", "int"):
            kind["type"] = number_type(arg)
        if arg.choices:
            kind["choices"] = arg.choices
        if arg.cli == POS:
            p.add_argument(_dest(arg), metavar=arg.metavar or arg.name.upper(), **kind)
        elif arg.type == "bool":
            p.add_argument(arg.cli, dest=_dest(arg), action="store_const", const=not arg.default,
                           help=kind["help"])
        else:
            p.add_argument(arg.cli, dest=_dest(arg), metavar=arg.metavar or None, **kind)


def table_args(cmd: Command, a: argparse.Namespace) -> dict[str, Any]:
    """The bus arguments given on the command line (absent ones: the daemon's default)."""
    out = {}
    for arg in cmd.args:
        value = getattr(a, _dest(arg), None) if arg.cli else None
        if value is not None:
            out[arg.name] = value
    return out


def with_cli_names(cmd: Command, message: str) -> str:
    """Append the ritactl spelling to bus argument names in a daemon message."""
    for arg in cmd.args:
        if arg.cli:
            shown = (arg.metavar or arg.name.upper()) if arg.cli == POS else arg.cli
            word = rf"\b{re.escape(arg.name)}\b"
            message = re.sub(word, f"{arg.name} (ritactl: {shown})", message, count=1)
    return message


def add_device_parsers(sub: Any, parents: list[argparse.ArgumentParser]) -> None:
    """One subcommand per table entry with ``cli`` words; groups (``tracker stream``) nest."""
    nodes: dict[tuple[str, ...], Any] = {(): sub}
    for cmd in TABLE:
        for depth in range(1, len(cmd.cli)):
            path = cmd.cli[:depth]
            if path not in nodes:
                words = sorted({c.cli[depth] for c in TABLE if c.cli[:depth] == path})
                group = " ".join(path)
                p = nodes[path[:-1]].add_parser(path[-1], parents=parents, description=f"{group} commands",
                                                help=f"{group}: {', '.join(words)}")
                p.set_defaults(fn=None, parser_=p)
                nodes[path] = p.add_subparsers(title="commands", metavar="COMMAND")
        if cmd.cli:
            leaf = nodes[cmd.cli[:-1]].add_parser(cmd.cli[-1], parents=parents, help=cmd.help,
                                                  description=f"{cmd.help} (bus command {cmd.name})")
            add_table_args(leaf, cmd)
            for flag, kw in LOCAL_OPTIONS.get(cmd.name, ()):
                leaf.add_argument(flag, **kw)
            leaf.set_defaults(fn=cmd_device, command=cmd.name, parser_=leaf)


def _check_out(out: str) -> None:
    """Refuse an unusable --out before the camera is triggered (exit 5)."""
    path = Path(out)
    if not path.name or path.name in (".", "..") or path.is_dir():
        raise CtlError(Exit.BAD_INPUT, "bad_input",
                       f"--out {out!r} is a folder: give a file name like frame.png")
    if not path.parent.is_dir():
        raise CtlError(Exit.BAD_INPUT, "bad_input",
                       f"--out {out!r}: folder {str(path.parent)!r} does not exist")


def _save_png(out: str, result: dict[str, Any], extra: list[Any]) -> None:
    h = result["header"]
    try:
        atomic_write_bytes(Path(out), frame_png(h, extra[0].buffer))
        atomic_write_json(Path(out).with_suffix(".json"), h)
    except OSError as exc:
        raise CtlError(Exit.BAD_INPUT, "bad_input", f"cannot write {out}: {exc.strerror or exc}") from None


def _interrupted_motion(c: Client, cmd: Command, as_json: bool) -> int:
    if yes_after_ctrl_c(f"{cmd.name} may still be moving the robot. stop the robot?", as_json):
        r = c.call("robot.stop")
        say("robot stopped" if r.get("stopped") else f"robot stop {r.get('message')}", as_json)
    else:
        say("the motion goes on; `ritactl robot stop` stops the robot", as_json)
    return Exit.INTERRUPTED


def cmd_device(c: Client, a: argparse.Namespace) -> int:
    cmd = COMMANDS[a.command]
    args = table_args(cmd, a)
    out = getattr(a, "out", None)
    if out:
        _check_out(out)
        args.update(pixels=True, save=False)
    try:
        result, extra = c.call_raw(cmd.name, args, timeout=a.timeout or 120)
    except KeyboardInterrupt:
        if args.get("confirm"):  # a confirmed motion goes on in the daemon: say so, offer to stop it
            return _interrupted_motion(c, cmd, a.json)
        raise
    except ClientTimeout:
        raise
    except CommandError as exc:
        if exc.code == ErrorCode.CONFIRM_REQUIRED:  # the daemon's message speaks of the bus argument
            raise CommandError(exc.code, f"`ritactl {' '.join(cmd.cli)}` moves the robot: "
                               "add --yes to confirm that it may move") from None
        raise CommandError(exc.code, with_cli_names(cmd, exc.args[0])) from None
    if out:
        _save_png(out, result, extra)
        print_result({"saved": out, "metadata": str(Path(out).with_suffix(".json"))}, a.json)
        return Exit.OK
    if cmd.name in RESULT_TEXT:
        text, code = RESULT_TEXT[cmd.name](result)
        print_result(result, True) if a.json else print(text)
        return code
    print_result(result, a.json)
    return Exit.OK
