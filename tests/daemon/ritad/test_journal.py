"""Journal hygiene: what a console page, ritactl and the worker poll is logged at DEBUG, and a
refusal repeated in a loop is logged once per window with its count."""
from __future__ import annotations

import logging
import time
from typing import Any, Callable

import pytest

from daemon.bus.command_table import COMMANDS
from daemon.bus.protocol import CommandError
from daemon.bus.repeatlog import RepeatGate
from daemon.ritad import server
from tests.ritad_up import ritad_in_process

#: what one open console page sends (daemon/console/bridge.py, static/console.js, procedures.js)
#: and the picture and file-chunk requests of the live view, the forms and ritactl fetch
POLLS = ("state", "status", "tracker.status", "camera.status", "robot.status", "calib.jobs",
         "calib.results", "data.dir", "camera.preview", "files.list", "files.read", "files.hash")


def wait(what: str, cond: Callable[[], Any], timeout: float = 60.0) -> Any:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        got = cond()
        if got:
            return got
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def server_lines(caplog: pytest.LogCaptureFixture, level: int) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == server.__name__ and r.levelno == level]


def test_read_commands_are_reads():
    polled = {n for n, c in COMMANDS.items() if c.polled}
    assert not any(COMMANDS[n].motion for n in polled)
    assert set(POLLS) <= polled


def test_polled_commands_log_at_debug_not_info(tmp_path, caplog):
    caplog.set_level(logging.DEBUG, logger=server.__name__)
    with ritad_in_process(tmp_path / "rt", tmp_path / "data") as (_, c):
        c.call("camera.stream.start")
        wait("a streamed frame", lambda: c.call("camera.status")["frames"] > 0)
        (tmp_path / "data" / "note.txt").write_text("x" * 100)
        caplog.clear()
        for _ in range(3):
            for cmd in POLLS:
                args = {"path": "note.txt"} if cmd in ("files.read", "files.hash") else {}
                c.call_raw(cmd, args, timeout=30)
        c.call("camera.stream.stop")
    info, debug = server_lines(caplog, logging.INFO), server_lines(caplog, logging.DEBUG)
    assert not [m for m in info if any(f"command {cmd} " in m for cmd in POLLS)], info
    for cmd in POLLS:  # still there for a DEBUG session
        assert sum(m.startswith(f"command {cmd} id=") for m in debug) == 3, (cmd, debug)
    assert any(m.startswith("command camera.stream.stop id=") for m in info)  # a change stays INFO


def refuse(c: Any, n: int) -> None:
    for _ in range(n):
        with pytest.raises(CommandError):
            c.call("calib.start", procedure="experiment", params={"directions": "eight", "bogus": 1})


def test_repeated_refusals_are_counted_not_repeated(tmp_path, caplog, monkeypatch):
    monkeypatch.setattr(server, "REFUSAL_WINDOW_S", 1.0)
    caplog.set_level(logging.INFO, logger=server.__name__)
    with ritad_in_process(tmp_path / "rt", ready=False) as (_, c):
        refuse(c, 40)
        first = [m for m in server_lines(caplog, logging.INFO) if "[bad_args]" in m]
        assert len(first) == 1 and "'directions'" in first[0] and "(x" not in first[0], first
        # the 39 held back are reported when the window ends, without another refusal
        counted = wait("the count", lambda: [m for m in server_lines(caplog, logging.INFO)
                                             if "[bad_args]" in m and "(x39 in the last 1 s)" in m], 30)
        assert len(counted) == 1
        time.sleep(1.2)
        refuse(c, 1)  # a new window: logged at once
        again = [m for m in server_lines(caplog, logging.INFO) if "[bad_args]" in m]
        assert len(again) == 3 and "(x" not in again[-1], again


def test_repeat_gate_counts_into_the_next_line_and_flushes():
    now = [0.0]
    gate: RepeatGate[str] = RepeatGate(60.0, clock=lambda: now[0])
    assert gate.admit("a", "first") == 0
    assert [gate.admit("a", f"#{i}") for i in range(36)] == [None] * 36
    assert gate.admit("b") == 0  # another kind is independent
    now[0] = 59.9
    assert gate.overdue() == []
    now[0] = 60.0
    assert gate.overdue() == [("a", 36, "#35")]
    assert gate.overdue() == []
    assert gate.admit("a") is None  # the window restarted at the flush
    now[0] = 120.0
    assert gate.admit("a") == 1
