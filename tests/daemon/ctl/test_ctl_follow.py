"""ritactl against a running simulated daemon: follow ends, prompts, Ctrl-C, status, a closed pipe.

The test plays the calibration worker (``calib.report``), so every job end is exact.
"""
from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from unittest import mock

import pytest

from daemon.ctl import main as ctl
from daemon.bus.client import Client, Subscriber
from daemon.ctl.exitcodes import Exit
from tests.ctl_sim import post_job, report, sim_daemon

ROOT = Path(__file__).resolve().parents[3]
RESULT = {"procedure": "referencing", "verdict": "ok", "messages": ["fine"], "dataset": "d1", "files": []}


@pytest.fixture(scope="module")
def endpoint(tmp_path_factory):
    with sim_daemon(tmp_path_factory.mktemp("ctlfollow")) as d:
        yield d.server.endpoints[0]


@pytest.fixture
def c(endpoint):
    with Client(endpoint, timeout=10) as client:
        yield client


def follow(endpoint: str, job: str, *extra: str) -> tuple[int, int]:
    """``ritactl follow``'s exit code and how many times it waited on the bus for news (0: at once)."""
    waits = [0]
    recv = Subscriber.recv

    def counted(self: Subscriber, *args: object, **kw: object) -> object:
        waits[0] += 1
        return recv(self, *args, **kw)

    with mock.patch.object(Subscriber, "recv", counted):
        code = ctl.main(["--endpoint", endpoint, "follow", job, *extra])
    return code, waits[0]


class TtyInput(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_status_of_a_ready_daemon_is_0(endpoint, capsys):
    assert ctl.main(["--endpoint", endpoint, "status"]) == Exit.OK
    assert "READY" in capsys.readouterr().out


@pytest.mark.parametrize("end, data, want, shown", [
    ("result", RESULT, Exit.OK, "verdict=ok"),
    ("result", {**RESULT, "verdict": "warn"}, Exit.WARN, "verdict=warn"),
    ("result", {**RESULT, "verdict": "fail"}, Exit.FAIL, "verdict=fail"),
    ("error", {"message": "tracker lost the reflector"}, Exit.FAIL, "FAILED: tracker lost the reflector"),
    ("error", {"message": "job cancelled by the operator", "cancelled": True}, Exit.FAIL, "CANCELLED"),
])
def test_follow_an_ended_job_returns_at_once(endpoint, c, capsys, end, data, want, shown):
    job = post_job(c)
    report(c, job, end, data)
    # a late word from the worker changes nothing
    report(c, job, "progress", {"step": "done", "percent": 100})
    code, waits = follow(endpoint, job)
    assert code == want and waits == 0  # from the job's record, without waiting for news on the bus
    assert shown in capsys.readouterr().out


def test_follow_an_unknown_job(endpoint, capsys):
    code, waits = follow(endpoint, "no-such-job-17")
    assert code == Exit.REFUSED and waits == 0
    assert "no such job 'no-such-job-17'" in capsys.readouterr().err
    code, _ = follow(endpoint, "no-such-job-17", "--json")
    assert json.loads(capsys.readouterr().out)["error"] == "not_found" and code == Exit.REFUSED


def test_follow_a_running_job_until_its_result(endpoint, c, capsys):
    job = post_job(c, "experiment")
    out: list[int] = []
    t = threading.Thread(target=lambda: out.append(follow(endpoint, job, "--json")[0]))
    t.start()
    for pct in (10, 50, 90):
        time.sleep(0.3)
        report(c, job, "progress", {"step": f"step {pct}", "percent": pct})
    report(c, job, "result", {**RESULT, "procedure": "experiment", "verdict": "warn"})
    t.join(10)
    assert not t.is_alive() and out == [Exit.WARN]
    cap = capsys.readouterr()
    assert json.loads(cap.out)["verdict"] == "warn"  # stdout: only the result document
    assert "step 90" in cap.err


def run_prompted(endpoint: str, c: Client, stdin: io.StringIO, monkeypatch) -> tuple[str, list[int]]:
    """follow a job that asks a question, with ``stdin`` as the keyboard; then end the job."""
    job = post_job(c, "intrinsics")
    report(c, job, "prompt", {"question": "place the target", "choices": ["ok"]})
    monkeypatch.setattr(sys, "stdin", stdin)
    out: list[int] = []
    t = threading.Thread(target=lambda: out.append(follow(endpoint, job)[0]))
    t.start()
    time.sleep(1.5)  # follow shows the pending prompt from calib.jobs and reads the keyboard
    report(c, job, "result", {**RESULT, "procedure": "intrinsics"})
    t.join(10)
    assert not t.is_alive()
    return job, out


def test_eof_at_the_answer_prompt_keeps_following(endpoint, c, capsys, monkeypatch):
    job, out = run_prompted(endpoint, c, TtyInput(""), monkeypatch)
    assert out == [Exit.OK]
    cap = capsys.readouterr()
    assert "place the target" in cap.out and f"ritactl answer {job}" in cap.out
    assert "Traceback" not in cap.err + cap.out
    assert c.call("calib.inbox", job=job, timeout_s=0) is None  # nothing was answered


def test_answer_at_the_prompt_is_delivered(endpoint, c, capsys, monkeypatch):
    job, out = run_prompted(endpoint, c, TtyInput("\n"), monkeypatch)
    assert out == [Exit.OK]
    assert c.call("calib.inbox", job=job, timeout_s=0) == {"answer": "ok"}  # Enter takes the only choice


def _as_from_a_terminal() -> None:
    """Ctrl-C reaches ritactl as it does at a terminal, even when the suite itself runs in the
    background (`make test &`: a non-interactive shell starts it with SIGINT ignored, and an
    ignored signal stays ignored in every child, so Python would install no KeyboardInterrupt)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


class Ritactl:
    """ritactl as a process, its output collected by threads (for real SIGINTs)."""

    def __init__(self, endpoint: str, *argv: str) -> None:
        self.proc = subprocess.Popen([sys.executable, "-m", "daemon.ctl.main", "--endpoint", endpoint, *argv],
                                     cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True,
                                     env={**os.environ, "PYTHONPATH": str(ROOT), "PYTHONFAULTHANDLER": "1"},
                                     preexec_fn=_as_from_a_terminal)
        self.text = {"out": "", "err": ""}
        for name, stream in (("out", self.proc.stdout), ("err", self.proc.stderr)):
            threading.Thread(target=self._read, args=(name, stream), daemon=True).start()

    def _read(self, name: str, stream) -> None:
        for ch in iter(lambda: stream.read(1), ""):
            self.text[name] += ch

    def wait_for(self, what: str, name: str, timeout: float = 20, poke=None) -> None:
        end = time.monotonic() + timeout
        while what not in self.text[name]:
            if time.monotonic() > end and self.proc.poll() is None:
                self.proc.send_signal(signal.SIGABRT)  # faulthandler: where ritactl was, for the message
                time.sleep(1.0)
            assert time.monotonic() < end and self.proc.poll() is None, \
                f"waiting for {what!r}: exit {self.proc.returncode}\n" \
                f"--- stdout\n{self.text['out']}\n--- stderr\n{self.text['err']}"
            if poke:
                poke()
            time.sleep(0.2)


@pytest.mark.parametrize("keys, stopped", [("y\n", True), ("\n", False), (None, True), ("", False)])
def test_ctrl_c_during_a_motion_procedure_asks_to_stop_the_robot(endpoint, c, keys, stopped):
    """y: the latched stop (the job stopped too); Enter or EOF: detach with the hint; a second
    Ctrl-C: stop."""
    job = post_job(c, "referencing")
    f = Ritactl(endpoint, "follow", job)
    try:
        f.wait_for("moving", "out", poke=lambda: report(c, job, "progress", {"step": "drive", "percent": 20,
                                                                              "waiting_for": "robot moving"}))
        f.proc.send_signal(signal.SIGINT)
        f.wait_for("stop the robot (and the job)? [y/N]", "err")
        if keys is None:
            f.proc.send_signal(signal.SIGINT)
        else:
            f.proc.stdin.write(keys)
            f.proc.stdin.flush()
            if keys == "":
                f.proc.stdin.close()
        assert f.proc.wait(20) == Exit.INTERRUPTED
        time.sleep(0.2)
        assert "Traceback" not in f.text["err"] + f.text["out"]
        inbox = c.call("calib.inbox", job=job, timeout_s=0)
        if stopped:
            # (a queued job just leaves the queue)
            assert "robot stopped and latched" in f.text["out"], f.text
            assert c.call("state")["latch"]["latched"]
            assert {j["job"]: j for j in c.call("calib.jobs")["jobs"]}[job]["state"] == "stopped"
        else:
            assert inbox is None and not c.call("state")["latch"]["latched"]
            assert f"ritactl cancel {job}" in f.text["out"] and "ritactl robot stop" in f.text["out"]
    finally:
        if f.proc.poll() is None:
            f.proc.kill()
            f.proc.wait(10)
        c.call("robot.release")


def test_closed_pipe_after_a_daemon_answer(endpoint):
    """`ritactl robot status | head -0`."""
    proc = subprocess.Popen([sys.executable, "-m", "daemon.ctl.main", "--endpoint", endpoint,
                             "robot", "status"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert b"Traceback" not in err and b"Exception ignored" not in err


def wait_robot(c: Client, state: str, timeout: float = 20) -> None:
    end = time.monotonic() + timeout
    while c.call("robot.status")["state"] != state:
        assert time.monotonic() < end, f"robot not {state} within {timeout} s"
        time.sleep(0.05)


@pytest.mark.parametrize("keys", ["y\n", None, "\n"])
def test_ctrl_c_during_robot_move_offers_to_stop_it(endpoint, c, keys):
    # 300 mm at 2 mm/s: 150 s of motion, 3 s of wall time at the fake base's time_scale 0.02 (at 20 mm/s
    # it was 0.3 s, and a loaded machine sent the Ctrl-C after the move had ended)
    f = Ritactl(endpoint, "robot", "move", "-300", "--yes", "--speed", "2")
    try:
        wait_robot(c, "MOVING")
        f.proc.send_signal(signal.SIGINT)
        f.wait_for("stop the robot? [y/N]", "err")
        if keys is None:
            f.proc.send_signal(signal.SIGINT)  # a second Ctrl-C: yes
        else:
            f.proc.stdin.write(keys)
            f.proc.stdin.flush()
        assert f.proc.wait(20) == Exit.INTERRUPTED
        if keys == "\n":
            st = c.call("robot.status")
            assert st["state"] == "MOVING" and "ritactl robot stop" in f.text["out"], (st, f.text)
            c.call("robot.stop")
        wait_robot(c, "IDLE", 5)
        assert "Traceback" not in f.text["err"] + f.text["out"]
        assert c.call("state")["latch"]["latched"]  # Ctrl-C's "stop the robot" latches like any STOP
    finally:
        if f.proc.poll() is None:
            f.proc.kill()
            f.proc.wait(10)
        c.call("robot.release")


def test_daemon_errors_name_the_option_to_type(endpoint, capsys):
    """`tracker find` before any aim: the operator is told the option to type, never a bare API name."""
    assert ctl.main(["--endpoint", endpoint, "tracker", "find"]) == Exit.REFUSED
    err = capsys.readouterr().err
    assert "--distance" in err and "Traceback" not in err
    assert "approx_distance_mm" not in err or "approx_distance_mm (ritactl: --distance)" in err
