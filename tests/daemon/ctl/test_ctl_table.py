"""The command table: it matches the daemon's handlers, and ritactl's device subcommands follow it."""
from __future__ import annotations

import argparse
import shutil
import subprocess
from typing import Any

import pytest

from daemon.ritad import config, plugins
from daemon.ritad.calib_jobs import CalibJobs
from daemon.ritad.services import Reports, Services
from daemon.ritad.timelines import Timelines
from daemon.bus.command_table import COMMANDS, POS, PROCEDURES, ROLES, TABLE, CommandTable
from tests.ritad_up import unstarted_rigs
from daemon.ritad.commands import build_handlers
from daemon.ctl.main import build_parser, main, subparsers_of
from daemon.ctl.completion import bash_script
from daemon.ctl.device import table_args
from daemon.worker.procedures import RUN


def registered_commands(tmp_path, table: CommandTable) -> set[str]:
    """The names build_handlers registers, without starting a daemon."""
    cfg = config.sim_config(tmp_path)
    unused: Any = None  # building the handlers calls no service
    calib = CalibJobs(lambda topic, data: None)
    s = Services(storage=unused, data_dir=tmp_path, private_dirs=(), auth_dir=tmp_path / "authorized_keys",
                 save_capture=unused, calib=calib, latch=calib.latch, device_info=unused, table=table)
    found = plugins.installed(table)
    reports = Reports(unused, unused, unused)
    plugin_handlers = plugins.Running().handlers(s, found)
    return set(build_handlers(s, unstarted_rigs(cfg), reports, Timelines(), plugin_handlers))


def test_every_registered_command_has_an_entry_and_vice_versa(tmp_path):
    table = CommandTable()
    registered = registered_commands(tmp_path, table)
    assert registered - set(table) == set(), "commands without a table entry"
    assert set(table) - registered == set(), "table entries the daemon does not serve"
    assert set(COMMANDS) < set(table)  # the product's and the installed plugins' (the simulator's)


def test_entries_are_complete():
    assert set(RUN) == set(PROCEDURES)  # the worker runs exactly the declared procedures
    for cmd in TABLE:
        assert cmd.role in ROLES and cmd.help, cmd.name
        for arg in cmd.args:
            assert arg.help and arg.type in ("float", "int", "bool", "str", "map", "any"), (cmd.name, arg.name)
            assert arg.cli in (None, POS) or arg.cli.startswith("--"), (cmd.name, arg.name)


def walk(p: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    yield path, p
    for name, child in subparsers_of(p).items():
        yield from walk(child, path + (name,))


def options(p: argparse.ArgumentParser) -> set[str]:
    return {o for a in p._actions for o in a.option_strings}


def test_every_option_of_every_verb_has_help():
    for path, p in walk(build_parser()):
        for a in p._actions:
            if a.option_strings:
                assert a.help, f"ritactl {' '.join(path)}: {a.option_strings} has no help"
            elif path[:1] in (("tracker",), ("robot",), ("camera",)) and not isinstance(a, argparse._SubParsersAction):
                assert a.help, f"ritactl {' '.join(path)}: {a.metavar} has no help"


def test_device_subcommands_offer_only_their_own_options():
    tree = dict(walk(build_parser()))
    for path, p in tree.items():
        if path[:1] == ("tracker",):
            assert not options(p) & {"--yes", "--speed", "--no-wait", "--out"}, path
    assert {"--yes", "--speed", "--no-wait"} <= options(tree[("robot", "move")])
    assert {"--yes", "--speed"} <= options(tree[("robot", "turn")])
    assert "--yes" not in options(tree[("robot", "stop")])
    assert "--distance" in options(tree[("tracker", "find")])
    assert "--rate" in options(tree[("tracker", "stream", "start")])
    assert "--out" in options(tree[("camera", "capture")])
    generated = {c.cli for c in TABLE if c.cli}
    assert generated <= set(tree), "every table entry with cli words is a subcommand"


@pytest.mark.parametrize("argv, cmd, want", [
    (["robot", "move", "200", "--yes", "--speed", "30"], "robot.move",
     {"distance_mm": 200.0, "speed_mm_s": 30.0, "confirm": True}),
    (["robot", "move", "-150", "--no-wait"], "robot.move", {"distance_mm": -150.0, "wait": False}),
    (["robot", "turn", "90", "--yes"], "robot.turn", {"angle_deg": 90.0, "confirm": True}),
    (["tracker", "aim", "2800", "-2500", "-830"], "tracker.aim", {"x": 2800.0, "y": -2500.0, "z": -830.0}),
    (["tracker", "find", "--distance", "4000"], "tracker.find", {"approx_distance_mm": 4000.0}),
    (["tracker", "find"], "tracker.find", {}),
    (["tracker", "stream", "start", "--rate", "1000"], "tracker.stream.start", {"rate_hz": 1000.0}),
    (["camera", "capture", "--label", "x"], "camera.capture", {"label": "x"}),
])
def test_command_line_becomes_bus_arguments(argv, cmd, want):
    a = build_parser().parse_args(argv)
    assert a.command == cmd and table_args(COMMANDS[cmd], a) == want


@pytest.mark.parametrize("argv, named", [
    (["robot", "turn", "361"], "361"), (["tracker", "stream", "start", "--rate", "0"], "0"),
    (["tracker", "stream", "start", "--rate", "10001"], "10001"), (["tracker", "find", "--distance", "inf"], "inf"),
    (["robot", "move", "1e400"], "1e400"), (["robot", "move", "--speed", "-1", "10"], "-1"),
])
def test_values_outside_the_table_range_are_usage_errors_naming_them(argv, named, capsys):
    assert main(argv) == 64
    err = capsys.readouterr().err
    assert named in err and "Traceback" not in err


def test_bash_completion_completes_from_the_parser():
    if shutil.which("bash") is None:
        pytest.skip("no bash here")
    script = bash_script(build_parser())

    def complete(*words: str) -> set[str]:
        line = " ".join(["ritactl", *words])
        prog = (f"{script}\nCOMP_WORDS=(ritactl {' '.join(words)}); COMP_CWORD={len(words)}; "
                f"COMP_LINE='{line}'; _ritactl; printf '%s\\n' \"${{COMPREPLY[@]}}\"")
        out = subprocess.run(["bash", "-c", prog], capture_output=True, text=True, timeout=30, check=True)
        return set(out.stdout.split())

    assert {"status", "tracker", "robot", "calibrate", "jobs"} <= complete("")
    assert complete("tracker", "") == {"measure", "aim", "find", "stream", "status", "readback"}
    assert complete("tracker", "stream", "") == {"start", "stop"}
    tracker_opts = complete("tracker", "aim", "--")
    assert "--json" in tracker_opts and "--yes" not in tracker_opts and "--speed" not in tracker_opts
    assert {"--yes", "--speed", "--no-wait"} <= complete("robot", "move", "--")
    assert complete("keys", "") >= {"init", "allow", "revoke", "list"}


def test_a_table_entry_without_handler_stops_ritad(tmp_path, monkeypatch):
    """build_handlers refuses to run when the handlers and the table differ (ritad would not start)."""
    from daemon.ritad import commands

    monkeypatch.setattr(commands, "_plates", lambda s: {})
    with pytest.raises(RuntimeError, match="calib.plate.upload"):
        registered_commands(tmp_path, CommandTable())
