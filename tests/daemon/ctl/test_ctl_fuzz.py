"""CLI fuzz: 1,200 seeded random argv lists over every ritactl verb, in-process against a simulated daemon.

Argument lists are drawn from ritactl's own parser tree (so a new verb is fuzzed without
editing this file): each verb's options and positionals with plausible, wrong, empty,
huge and non-finite values, global options before or after the verb, and random
insertions/deletions. Safety rules keep the run short and harmless: motions are never
confirmed, procedures are posted with --detach (no worker runs), watch stops after
0.3 s, keys live in a temp folder, follow/resume only see ended or unknown jobs.
Oracle: main() returns (never raises), the code is in the documented list, no
traceback or "unexpected error" is printed, and --json errors are JSON on stdout.
"""
from __future__ import annotations

import argparse
import collections
import io
import json
import math
import random
import signal
import sys

import pytest

from daemon.ctl import main as ctl
from daemon.bus.client import Client
from daemon.bus import procedures
from daemon.bus.command_table import CommandTable
from daemon.ritad import plugins
from daemon.ctl.exitcodes import Exit
from tests.ctl_sim import post_job, report, sim_daemon
from tests.daemon.ctl.test_ctl_table import walk
from tests.fuzzscale import cases, scaled

SIZES = (1200, 400)  # full run, make-test sample
N_CASES = cases(*SIZES)
CASE_S = 30.0  # no case may take longer (a hang is a finding, not a stuck test run)
DOCUMENTED = {int(e) for e in Exit}
PROCEDURE_VERBS = {p.verb for p in procedures.ALL}
JOB_VERBS = {"follow", "resume", "answer", "cancel"}
# verbs whose --json output is not the error object: validate prints its problem report (a JSON
# document, docs/datasets.md); keys reports its errors as text (daemon/ctl/keys.py)
OWN_ERROR_TEXT = {"keys", "validate"}
# the ended jobs follow may see: no case may post them again (calibrate --job, call calib.start)
ENDED = ("fz-done", "fz-failed")
# bus commands `call` may send: no motion, no long poll that would hold the reply
COMMANDS = CommandTable()
plugins.installed(COMMANDS)  # the table the daemon serves: the simulator's commands too
# (robot.commission: the base's checks run for seconds, up to 600: its verb is fuzzed and always refused)
CALLABLE = sorted(set(COMMANDS) - {"robot.move", "robot.turn", "calib.next", "calib.inbox",
                                   "robot.commission"})
NUMBERS = ["0", "-1", "1", "200", "-200", "3.5", "1e3", "1e400", "-1e400", "nan", "inf", "-inf", "abc", "",
           "0x10", "1_000", "5e-324", "10001", "360", "-360.5", "1,5", " 7 "]
TEXTS = ["", "x", "a b", "é€", "--", "-", "-x", "../../etc/passwd", "x" * 300, "{}", "null"]
JSONS = ['{}', '{"x": 1}', '{"label": 3}', '[1]', '1', 'null', '{', '{"confirm": false, "distance_mm": 1}', '"s"',
         '{"procedure": "nope"}', '{"rate_hz": -1}']


def value(rng: random.Random, action: argparse.Action) -> str:
    """Mostly a plausible value (so most cases reach the daemon), else a wrong, empty or extreme one."""
    numeric = action.type in (float, int) or getattr(action.type, "__name__", "") == "parse"
    if rng.random() < 0.7:
        if action.choices:
            return str(rng.choice(sorted(map(str, action.choices))))
        if numeric:
            return rng.choice([f"{rng.uniform(-300, 300):.2f}", str(rng.randint(1, 50))])
        return rng.choice(["x", "nest-red", "lbl_1", "f.json"])
    return rng.choice(NUMBERS + TEXTS + [f"{rng.uniform(-5000, 5000):.3f}"])


def tokens_for(rng: random.Random, action: argparse.Action) -> list[str]:
    n = action.nargs
    if n == 0:
        return []
    count = n if isinstance(n, int) else {None: 1, "?": rng.randint(0, 1), "*": rng.randint(0, 2),
                                          "+": rng.randint(1, 2)}.get(n, 1)
    return [value(rng, action) for _ in range(count)]


def draw_argv(rng: random.Random, path: tuple[str, ...], p: argparse.ArgumentParser) -> list[str]:
    argv = list(path)
    for a in p._actions:
        if isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)):
            continue
        if a.option_strings:
            often = 0.08 if set(a.option_strings) & set(ctl.GLOBAL_OPTIONS) else 0.3
            if rng.random() < often or (a.required and rng.random() < 0.9):
                argv += [rng.choice(a.option_strings), *tokens_for(rng, a)]
        elif rng.random() < 0.93:
            argv += tokens_for(rng, a)
    if rng.random() < 0.3:
        argv.insert(rng.choice([0, len(argv)]), "--json")
    if rng.random() < 0.1:
        argv[:0] = ["--timeout", rng.choice(["2", "0.01", "abc", "-1", "0", "1e9"])]
    if rng.random() < 0.07 and argv:
        del argv[rng.randrange(len(argv))]
    if rng.random() < 0.07:
        argv.insert(rng.randint(0, len(argv)), rng.choice(NUMBERS + TEXTS + ["--yes", "--rate", "-h", "--nope"]))
    return argv


def make_safe(argv: list[str], path: tuple[str, ...], rng: random.Random, tmp: str, endpoint: str) -> list[str]:
    if path[:1] == ("robot",):
        argv = [t for t in argv if t != "--yes"]  # never confirm a motion
    if path == ("robot", "conformance"):
        argv += ["--clock-s", "0"]  # refused: a valid one runs the base's checks for seconds
    verb = path[0] if path else ""
    if verb in PROCEDURE_VERBS:
        argv.append("--detach")  # no worker here: following would wait for ever
    if verb in ("watch", "record"):
        argv += ["--duration", "0.3"]
    if verb == "keys":
        argv += ["--dir", f"{tmp}/keys"]
    if verb == "console":  # never a browser; a short run on a free port
        argv = [t for t in argv if t != "--open"] + ["--duration", "0.05", "--port", "0", "--captures", f"{tmp}/cap"]
    if verb == "resume":
        argv = [t for t in argv if t != "--procedure"]  # a re-posted job would be followed for ever
    if verb in JOB_VERBS and len(argv) > 1:
        argv[1] = rng.choice([*ENDED, f"fz-unknown-{rng.randint(0, 99)}", "", "--"])
        if verb == "resume" and argv[1] in ENDED:
            argv[1] = "fz-unknown-r"
    if verb == "call" and len(argv) > 1:
        argv[1] = rng.choice(CALLABLE + ["nope", "", "robot"])
        argv[2:] = [rng.choice(JSONS)] if rng.random() < 0.7 else argv[2:3]
    if "--endpoint" in argv[:-1] and rng.random() < 0.8:
        argv[argv.index("--endpoint") + 1] = endpoint
    if verb == "replay":  # never waiting for a subscriber; the last --endpoint wins
        argv += ["--no-wait", "--linger", "0", "--endpoint", f"ipc://{tmp}/replay"]
    if "--out" in argv:
        i = argv.index("--out")
        argv[i + 1:i + 2] = [rng.choice(["f.png", "missing/f.png", "."])]
    return ["--timeout", "3", *argv]  # a later --timeout wins


class CaseTimeout(BaseException):
    """Raised by SIGALRM in a case that runs too long (BaseException: main() must not swallow it)."""


def _alarm(signum, frame):
    raise CaseTimeout()


@pytest.fixture(scope="module")
def endpoint(tmp_path_factory):
    with sim_daemon(tmp_path_factory.mktemp("ctlfuzz")) as d:
        ep = d.server.endpoints[0]
        with Client(ep, timeout=10) as c:
            report(c, post_job(c, job="fz-done"), "result", {"procedure": "referencing", "verdict": "ok"})
            report(c, post_job(c, job="fz-failed"), "error", {"message": "boom"})
        yield ep


@pytest.mark.timeout(900)
def test_random_argv_never_traceback_and_exit_codes_are_documented(endpoint, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("RITA_ENDPOINT", endpoint)
    monkeypatch.setenv("RITA_KEYS", str(tmp_path / "laptop-keys"))
    leaves = [(path, p) for path, p in walk(ctl.build_parser()) if p._defaults.get("fn")]
    rng = random.Random(20261123)
    old = signal.signal(signal.SIGALRM, _alarm)
    codes: collections.Counter[int] = collections.Counter()
    per_verb: collections.Counter[tuple[str, ...]] = collections.Counter()
    # every verb gets the count asserted below by rounds over all of them, then random ones: a new verb
    # cannot starve another of its cases by chance
    rounds = math.ceil(scaled(10, *SIZES))
    for i in range(N_CASES):
        path, p = leaves[i % len(leaves)] if i < rounds * len(leaves) else rng.choice(leaves)
        argv = make_safe(draw_argv(rng, path, p), path, rng, str(tmp_path), endpoint)
        monkeypatch.setattr(sys, "stdin", io.StringIO(""))
        signal.setitimer(signal.ITIMER_REAL, CASE_S)
        try:
            code = ctl.main(argv)
        except BaseException as exc:  # noqa: BLE001 - that is the finding
            signal.signal(signal.SIGALRM, old)
            pytest.fail(f"case {i}: ritactl {argv} raised {exc!r} (CaseTimeout: still running after {CASE_S} s)")
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
        out, err = capsys.readouterr()
        assert code in DOCUMENTED, (i, argv, code, err)
        for text in (out, err):
            assert "Traceback" not in text and "unexpected error" not in text, (i, argv, text[-2000:])
        options = argv[:argv.index("--")] if "--" in argv else argv  # after --, "--json" is a value
        own_text = path[0] in OWN_ERROR_TEXT
        if "--json" in options and code in (3, 4, 5, 64) and not {"-h", "--help"} & set(options) and not own_text:
            assert out.strip(), (i, argv, code, err)
            doc = json.loads(out.strip().splitlines()[-1])
            assert doc["exit"] == code and doc["error"] and doc["message"], (i, argv, out)
        codes[code] += 1
        per_verb[path] += 1
    signal.signal(signal.SIGALRM, old)
    assert all(per_verb[path] >= scaled(10, *SIZES) for path, _ in leaves), per_verb
    assert codes[Exit.OK] >= scaled(200, *SIZES) and codes[Exit.REFUSED] >= scaled(50, *SIZES), codes
    assert codes[Exit.USAGE] >= scaled(100, *SIZES), codes
    assert codes[Exit.USAGE] < 0.5 * N_CASES, codes  # most cases get past the parser
