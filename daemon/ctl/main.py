"""ritactl: the operator's client (needs only pyzmq and msgpack; runs on Windows too).

Examples::

    ritactl status                # exits 4 when a device is not READY/BUSY
    ritactl watch                 # live telemetry, one summary line per second
    ritactl watch --frames        # frame rate, drops and latency of the image stream
    ritactl capture --label nest-red
    ritactl tracker measure | aim X Y Z | find --distance MM | stream start --rate HZ | stream stop | status
    ritactl robot move MM --yes [--speed MM_S] | turn DEG --yes | stop | release | status
    ritactl camera capture --out frame.png | stream start | stream stop | status
    ritactl calibrate --reversal | experiment --mark X Y | measure-mark --mark X Y | results
    ritactl jobs | follow JOB | answer JOB TEXT | cancel JOB | resume JOB [--detach]
    ritactl validate FOLDER | recompute DATASET  # offline, on this computer
    ritactl plate survey FOLDER --plate DESIGN.json --out plate.json  # offline
    ritactl plate upload plate.json [--name NAME]  # to the robot's calibration folder (operator)
    ritactl record --out FILE.mcap [--duration S] [--frames every N|off] [--frames-format raw|jpeg|png]
                   [--max-size N] [--min-free N]
    ritactl replay FILE.mcap [--speed X|max] [--endpoint ipc:///PATH]  # republish it, for watch
    ritactl call COMMAND '{"arg": 1}'   # any bus command, JSON args
    ritactl fetch [PATH ...] [--to DIR] [--quiet]  # datasets, results and reports from the robot
    ritactl keys init | allow FILE | role | revoke | list   # CURVE keys (each with its --help)
    ritactl completion bash|zsh|fish  # shell completion script

The daemon is found at --endpoint, else $RITA_ENDPOINT, else ritactl.toml's endpoint, else
ipc:///run/ritad/cmd; keys: --key/--keys/--config (docs/operations.md, Keys).
The device subcommands come from daemon/bus/command_table.py. Exit codes: daemon/ctl/exitcodes.py
(docs/operations.md, "Exit codes"); ``main()`` maps every failure to one of them, never a traceback.
"""
from __future__ import annotations

import argparse
import errno
import json
import os
import re
import sys
from typing import Any, Callable, NoReturn

import zmq

from daemon import __version__
from daemon.ctl import fetch as ctl_fetch
from daemon.ctl import watch as ctl_watch
from daemon.bus.client import Client, ClientTimeout, default_endpoint
from daemon.bus.command_table import COMMANDS
from daemon.ctl.device import add_device_parsers, add_table_args, table_args
from daemon.ctl.io import fail, print_result, quiet_stdout, subparsers_of
from daemon.ctl.exitcodes import CtlError, Exit
from daemon.bus.protocol import CommandError

_print = print_result  # old name, kept for callers outside this module
GLOBAL_OPTIONS = ("--endpoint", "--timeout", "--json")
_ENDPOINT_RE = re.compile(r"^(tcp://(\[[0-9A-Fa-f:.]+\]|[^\s:/\[\]]+):(\d{1,5})|ipc://\S+|inproc://\S+)$")
OK_STATES = ("READY", "BUSY")  # a device that is connected and idle or working


class UsageError(Exception):
    def __init__(self, parser: argparse.ArgumentParser, message: str) -> None:
        super().__init__(message)
        self.parser = parser


class _Parser(argparse.ArgumentParser):
    """argparse that raises instead of exiting 2, so main() can exit 64 (EX_USAGE) or answer in JSON."""

    def error(self, message: str) -> NoReturn:
        raise UsageError(self, message)


def cmd_status(c: Client, a: argparse.Namespace) -> int:
    h = c.call("status")
    bad = {k: s for k, s in h["devices"].items() if s["state"] not in OK_STATES}
    if a.json:
        print_result(h, True)
        return Exit.REFUSED if bad else Exit.OK
    print(f"ritad {h['version']}  up {h['uptime_s']:.0f} s  alive={h['alive']}")
    for kind, s in h["devices"].items():
        reason = f" - {s['reason']}" if s["reason"] else ""
        print(f"  {kind:8s} {s['state']:12s} jobs {s['jobs_done']} done, {s['jobs_failed']} failed; "
              f"reconnects {s['reconnects']}{reason}")
    latch = h.get("latch") or {}
    if latch.get("latched"):  # plainly: the robot will not move until someone releases it
        print(f"  STOP LATCHED by {latch.get('by')}: no motion until `ritactl robot release` "
              f"({latch.get('refused', 0)} motion(s) refused)")
    if latch.get("halt_pending"):  # latched is not halted: say so until the base has acknowledged it
        print("  HALT NOT YET ACKNOWLEDGED by the base: STOP is sent as soon as it answers")
    t, f, cm = h["telemetry"], h["frames"], h["commands"]
    print(f"  telemetry sent={t['sent']} dropped={sum(t['dropped'].values())}   frames sent={f['sent']} "
          f"dropped={f['dropped']}   commands={cm['requests']} errors={cm['errors']}")
    if bad:
        names = ", ".join(f"{k} {s['state']}" for k, s in bad.items())
        print(f"ritactl: not ready: {names}", file=sys.stderr)
        return Exit.REFUSED
    return Exit.OK


def cmd_capture(c: Client, a: argparse.Namespace) -> int:
    r = c.call_raw("capture", table_args(COMMANDS["capture"], a), timeout=a.timeout or 90)[0]
    if a.json:
        print_result(r, True)
    else:
        t = r["tracker"]
        print(f"saved {r['path']}")
        print(f"  image {r['header']['shape']} frame {r['header']['frame_id']}; reflector "
              f"({t['x']:.4f}, {t['y']:.4f}, {t['z']:.4f}) mm; robot {r['robot']['state']}")
    return Exit.OK


def cmd_call(c: Client, a: argparse.Namespace) -> int:
    try:
        args = json.loads(a.args) if a.args else {}
    except json.JSONDecodeError as exc:
        raise CtlError(Exit.USAGE, "usage", f"ARGS is not valid JSON ({exc}): {a.args}") from None
    if not isinstance(args, dict):
        raise CtlError(Exit.USAGE, "usage", f"ARGS must be a JSON object like '{{\"x\": 1}}', got {a.args}")
    print_result(c.call_raw(a.command, args, timeout=a.timeout)[0], True)
    return Exit.OK


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not 0 < value < 1e6:
        raise argparse.ArgumentTypeError(f"{text!r} must be between 0 and 1e6 seconds")
    return value


def _global_options(p: argparse.ArgumentParser, top: bool) -> None:
    """--endpoint/--timeout/--json, before the verb (top) or after it (every subcommand)."""
    keep: dict[str, Any] = {} if top else {"default": argparse.SUPPRESS}
    p.add_argument("--endpoint", help=f"daemon command endpoint, tcp://HOST:PORT or ipc:///PATH "
                                      f"(now: {default_endpoint()})", **keep)
    p.add_argument("--timeout", type=_seconds, help="seconds to wait for an answer", **keep)
    p.add_argument("--json", action="store_true", help="JSON on stdout, errors too (docs/operations.md)",
                   **keep)


def _offline_only(p: argparse.ArgumentParser) -> bool:
    """A verb that never talks to the daemon (validate, recompute, plate survey, keys init, completion)."""
    return p.get_default("offline") is True and "--bus" not in p._option_string_actions


def _add_globals_everywhere(p: argparse.ArgumentParser) -> None:
    """Every verb accepts the global options after it too (``ritactl jobs --json``); an offline verb
    only --json: it has no daemon to reach, so --endpoint and --timeout would mean nothing."""
    for child in {id(c): c for c in subparsers_of(p).values()}.values():
        if _offline_only(child) and "--json" not in child._option_string_actions:
            child.add_argument("--json", action="store_true", default=argparse.SUPPRESS,
                               help="JSON on stdout, errors too (docs/operations.md)")
        elif not any(o in child._option_string_actions for o in GLOBAL_OPTIONS):
            _global_options(child, top=False)
        _add_globals_everywhere(child)


def build_parser() -> argparse.ArgumentParser:
    from daemon.ctl.calib import add_parsers
    from daemon.ctl.completion import add_parser as add_completion_parser
    from daemon.ctl.console import add_parser as add_console_parser
    from daemon.ctl.datasets import add_parsers as add_dataset_parsers
    from daemon.ctl.keys import add_parser as add_keys_parser
    from daemon.ctl.plate import add_parsers as add_plate_parsers
    from daemon.ctl.record import add_parser as add_record_parser
    from daemon.ctl.replay import add_parser as add_replay_parser

    ap = _Parser(prog="ritactl", description="Operator client for ritad",
                 epilog="Endpoint: --endpoint, else $RITA_ENDPOINT, else ritactl.toml, else "
                        "ipc:///run/ritad/cmd. Exit codes: docs/operations.md.")
    ap.add_argument("--version", action="version", version=f"ritactl {__version__}")
    _global_options(ap, top=True)
    ap.add_argument("--key", metavar="NAME", help="CURVE key NAME.key_secret for tcp endpoints "
                                                  "(default: `key` in ritactl.toml, else client)")
    ap.add_argument("--keys", metavar="DIR", help="CURVE keys folder (default $RITA_KEYS, else "
                                                  "ritactl.toml's keys_dir, else ~/.config/rita)")
    ap.add_argument("--config", metavar="FILE", help="ritactl.toml to read (default $RITA_CONFIG, else "
                                                     "~/.config/rita/ritactl.toml)")
    ap.set_defaults(fn=None, parser_=ap)
    sub = ap.add_subparsers(title="verbs", metavar="VERB")
    status = sub.add_parser("status", help="device states at a glance (exit 4 if one is not READY/BUSY)",
                            description="device states; exit 4 when a device is not READY or BUSY")
    status.set_defaults(fn=cmd_status)
    ctl_watch.add_parser(sub)
    cap = sub.add_parser("capture", help=COMMANDS["capture"].help)
    add_table_args(cap, COMMANDS["capture"])
    cap.set_defaults(fn=cmd_capture)
    add_device_parsers(sub, [])
    add_parsers(sub)
    add_dataset_parsers(sub)
    add_plate_parsers(sub)
    add_keys_parser(sub)
    ctl_fetch.add_parser(sub)
    add_record_parser(sub)
    add_replay_parser(sub)
    add_console_parser(sub)
    call = sub.add_parser("call", help="send any bus command (JSON result)")
    call.add_argument("command", help="bus command name (`ritactl call help` lists them)")
    call.add_argument("args", nargs="?", help='JSON object of arguments, e.g. \'{"x": 1}\'')
    call.set_defaults(fn=cmd_call)
    add_completion_parser(sub)
    _add_globals_everywhere(ap)
    return ap


def check_endpoint(endpoint: str, source: str) -> None:
    m = _ENDPOINT_RE.match(endpoint)
    if not m or (m.group(3) and not 0 < int(m.group(3)) < 65536):
        raise CtlError(Exit.USAGE, "usage", f"bad endpoint {endpoint!r} (from {source}): "
                                            f"use tcp://HOST:PORT or ipc:///PATH")


def _run(fn: Callable[[Any, argparse.Namespace], int], client: Client | None, a: argparse.Namespace) -> int:
    """Run a verb; map every failure to the documented exit codes."""
    where = client.endpoint if client else "-"
    try:
        return int(fn(client, a))
    except ClientTimeout as exc:  # ClientRefused too: "refused: key … is not allowed"
        return fail(Exit.NO_ANSWER, "refused" if exc.code == "refused" else "no_answer", exc.args[0], a.json)
    except CommandError as exc:
        return fail(Exit.REFUSED, exc.code, f"{exc.args[0]} [{exc.code}]", a.json)
    except CtlError as exc:
        return fail(exc.exit, exc.code, exc.args[0], a.json)
    except zmq.ZMQError as exc:
        if exc.errno in (errno.EINVAL, zmq.EPROTONOSUPPORT):
            return fail(Exit.USAGE, "usage", f"bad endpoint {where!r}: {exc}", a.json)
        return fail(Exit.NO_ANSWER, "no_answer", f"bus error with {where}: {exc}", a.json)
    except BrokenPipeError:
        raise
    except OSError as exc:
        what = f"{exc.filename}: {exc.strerror}" if exc.filename else str(exc)
        return fail(Exit.BAD_INPUT, "bad_input", f"local file problem: {what}", a.json)
    except (KeyboardInterrupt, SystemExit):
        raise
    except Exception as exc:  # noqa: BLE001 - a bug here must still not show a traceback to the operator
        return fail(Exit.FAIL, "internal", f"unexpected error in ritactl (a bug, please report): "
                                           f"{type(exc).__name__}: {exc}", a.json)


def _parse(argv: list[str], as_json: bool) -> argparse.Namespace | int:
    ap = build_parser()
    try:
        a = ap.parse_args(argv)
    except UsageError as exc:
        prog = exc.parser.prog
        if not as_json:
            exc.parser.print_usage(sys.stderr)
        where = prog.removeprefix("ritactl").strip()
        return fail(Exit.USAGE, "usage", f"{where + ': ' if where else ''}{exc.args[0]} "
                    f"(see `{prog} --help`)", as_json)
    except SystemExit as exc:  # --help and --version print and "exit" 0
        return Exit.OK if exc.code in (0, None) else Exit.USAGE
    if a.fn is None:  # bare `ritactl` or a group without its verb (`ritactl tracker`)
        if as_json:
            return fail(Exit.USAGE, "usage", f"{a.parser_.prog}: a verb is needed", True)
        a.parser_.print_help(sys.stderr)
        return Exit.USAGE
    return a


def _main(argv: list[str], as_json: bool) -> int:
    a = _parse(argv, as_json)
    if isinstance(a, int):
        return a
    if getattr(a, "offline", False):
        return _run(a.fn, None, a)
    from daemon.ctl.keys import resolve_connection

    try:  # the command line beats the environment, which beats ritactl.toml (docs/operations.md, Keys)
        conn = resolve_connection(a.endpoint, a.key, a.keys, a.config)
        source = "--endpoint" if a.endpoint else "$RITA_ENDPOINT, ritactl.toml or the default"
        check_endpoint(conn["endpoint"], source)
    except CtlError as exc:
        return fail(exc.exit, exc.code, exc.args[0], a.json)
    except (OSError, ValueError) as exc:  # CtlConfigError, KeyConfigError: they name the file
        return fail(Exit.BAD_INPUT, "bad_input", str(exc), a.json)
    client = Client(conn["endpoint"], timeout=a.timeout or conn["timeout"] or 5.0, curve=conn["curve"],
                    key_id=conn["key_id"], fail_fast=True)
    try:
        return _run(a.fn, client, a)
    finally:
        client.close()


def _one_blas_thread() -> None:
    """One OpenBLAS thread for this process, unless numpy is loaded already or the user chose.

    ritactl's computations (recompute, plate survey) solve small systems (a PnP, a 7-parameter
    refit, 6×6 covariances): OpenBLAS's helper threads gain nothing there and cost a wake-up per
    call, milliseconds on a busy machine (docs/benchmarks.md, "Referencing compute").
    """
    if "numpy" not in sys.modules:  # the setting is read when numpy loads; a library caller keeps its own
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    _one_blas_thread()
    as_json = "--json" in (argv[:argv.index("--")] if "--" in argv else argv)  # for errors before parsing
    try:
        code = _main(argv, as_json)
        sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's exit
        return code
    except BrokenPipeError:  # `ritactl … | head`: the reader has what it wanted
        quiet_stdout()
        return Exit.OK
    except KeyboardInterrupt:
        return fail(Exit.INTERRUPTED, "interrupted", "interrupted (Ctrl-C)", as_json)


if __name__ == "__main__":
    sys.exit(main())
