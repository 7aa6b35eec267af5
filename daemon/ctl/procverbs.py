"""ritactl's procedure verbs (``calibrate``, ``intrinsics``, ``measure-mark``, ``experiment``), generated.

One verb per declaration in daemon/bus/procedures.py, as daemon/ctl/device.py does for the
command table: each parameter is ``--name-with-dashes`` plus its declared aliases (the flags
older scripts use, e.g. ``--reps``), typed and range-checked from the declaration, with its
unit and default in the help. A ``file`` parameter names a JSON file on this computer, read
here and sent as its object (the daemon checks it again). A parameter not given is not sent:
the worker's default applies. Adding a parameter to a declaration adds its option here.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any, Callable

from daemon.bus.client import Client
from daemon.bus.procedure_params import Param
from daemon.bus import procedures as declared
from daemon.bus.procedures import Procedure, cli_flags
from daemon.ctl.device import number_type, option_help
from daemon.ctl.exitcodes import bad_input

_AXES = ("X", "Y", "Z")


def _dest(p: Param) -> str:
    return "pp_" + p.name


def _add_option(parser: argparse.ArgumentParser, p: Param) -> None:
    kind: dict[str, Any] = {"dest": _dest(p), "help": option_help(p)}
    if p.type == "bool":  # --name sets it, --no-name clears it, whatever the default
        yes, no, *aliases = cli_flags(p)
        parser.add_argument(yes, *aliases, action="store_const", const=True, **kind)
        parser.add_argument(no, action="store_const", const=False, dest=kind["dest"], help=f"not: {p.help}")
        return
    if p.type == "vec":
        number = Param(p.name, "float", p.help, unit=p.unit, lo=p.lo, hi=p.hi, lo_open=p.lo_open)
        kind.update(nargs=p.length, type=number_type(number), metavar=_AXES[:p.length])
    elif p.type == "file":
        kind.update(metavar="FILE", help=f"{p.help}: a JSON file on this computer (default {p.default_text})")
    elif p.type in ("int", "float"):
        kind.update(type=number_type(p), metavar="N")
    elif p.choices:
        kind.update(choices=p.choices)
    else:
        kind.update(metavar="TEXT")
    parser.add_argument(*cli_flags(p), required=p.required, **kind)


def _read_json(path: str, p: Param) -> Any:
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise bad_input(f"cannot read {p.name} {path}: {exc}") from None


def params_of(proc: Procedure, a: argparse.Namespace) -> dict[str, Any]:
    """The parameters given on the command line, files read; the rest is left to the worker."""
    out: dict[str, Any] = {}
    for p in proc.params:
        value = getattr(a, _dest(p), None)
        if value is not None:
            out[p.name] = _read_json(value, p) if p.type == "file" else value
    return out


def add_procedure_parsers(sub: Any, common: argparse.ArgumentParser,
                          start: Callable[[Client, argparse.Namespace, str, dict[str, Any]], int]) -> None:
    """A verb per declared procedure; ``start`` posts the job and follows it."""
    for proc in declared.ALL:  # read at call time: the declarations are the one list
        p = sub.add_parser(proc.verb, parents=[common], help=proc.help,
                           description=f"{proc.help} (procedure {proc.name}; "
                                       f"{'drives the robot' if proc.moves else 'does not drive the robot'})")
        for param in proc.params:
            _add_option(p, param)
        p.set_defaults(fn=lambda c, a, proc=proc: start(c, a, proc.name, params_of(proc, a)))
