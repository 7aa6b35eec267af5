"""ritactl without a daemon: --version, bare ritactl, usage (64), bad endpoint, no answer (3), JSON errors, closed pipe."""
from __future__ import annotations

import json
import subprocess
import sys
import types
from pathlib import Path

import pytest

from daemon import __version__
from daemon.ctl import main as ctl
from daemon.ctl.exitcodes import Exit

ROOT = Path(__file__).resolve().parents[3]


def run(*argv: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "daemon.ctl.main", *argv], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT)


def test_version():
    res = run("--version")
    assert res.returncode == 0 and res.stdout.strip() == f"ritactl {__version__}" and not res.stderr


def test_bare_ritactl_prints_help_and_exits_64():
    res = run()
    assert res.returncode == 64
    assert "usage: ritactl" in res.stderr and "tracker" in res.stderr and "required" not in res.stderr
    assert "Traceback" not in res.stderr


def test_a_group_without_its_verb_prints_its_help(capsys):
    assert ctl.main(["tracker"]) == 64
    err = capsys.readouterr().err
    assert "aim" in err and "find" in err and "--yes" not in err
    assert ctl.main(["tracker", "stream"]) == 64
    assert "start" in capsys.readouterr().err


def test_usage_error_in_json(capsys):
    assert ctl.main(["--json", "robot", "move", "abc"]) == 64
    out = capsys.readouterr().out
    err = json.loads(out)
    assert err["error"] == "usage" and err["exit"] == 64 and "'abc' is not a number" in err["message"]


@pytest.mark.parametrize("endpoint", ["127.0.0.1:5555", "tcp://127.0.0.1", "tcp://127.0.0.1:99999", "http://x:1",
                                      "tcp://*:5555x"])
def test_bad_endpoint_is_named(endpoint, capsys):
    assert ctl.main(["--endpoint", endpoint, "robot", "status"]) == 64
    err = capsys.readouterr().err
    assert repr(endpoint) in err and "tcp://HOST:PORT" in err and "Traceback" not in err


def test_bad_endpoint_from_the_environment(monkeypatch, capsys):
    monkeypatch.setenv("RITA_ENDPOINT", "localhost:5555")
    assert ctl.main(["status"]) == 64
    assert "'localhost:5555'" in capsys.readouterr().err


def test_no_daemon_is_exit_3_in_json_too(tmp_path, capsys):
    ep = f"ipc://{tmp_path}/none"
    assert ctl.main(["--endpoint", ep, "--timeout", "0.2", "jobs", "--json"]) == Exit.NO_ANSWER
    err = json.loads(capsys.readouterr().out)
    assert err["error"] == "no_answer" and ep in err["message"]
    assert ctl.main(["jobs", "--endpoint", ep, "--timeout", "0.2"]) == Exit.NO_ANSWER  # options after the verb
    assert "no answer from ritad" in capsys.readouterr().err


def test_local_file_problems_are_exit_5(tmp_path, capsys):
    ep = f"ipc://{tmp_path}/none"
    assert ctl.main(["--endpoint", ep, "calibrate", "--plate", str(tmp_path / "missing.json")]) == Exit.BAD_INPUT
    assert "missing.json" in capsys.readouterr().err
    (tmp_path / "bad.json").write_text("{not json")
    assert ctl.main(["--json", "--endpoint", ep, "intrinsics", "--board", str(tmp_path / "bad.json")]) == 5
    assert json.loads(capsys.readouterr().out)["error"] == "bad_input"


def test_call_with_bad_json_is_a_usage_error(tmp_path, capsys):
    ep = f"ipc://{tmp_path}/none"
    assert ctl.main(["--endpoint", ep, "call", "ping", "{x"]) == 64
    assert ctl.main(["--endpoint", ep, "call", "ping", "[1, 2]"]) == 64
    assert "JSON object" in capsys.readouterr().err


def test_status_exits_4_when_a_device_is_not_ready(capsys):
    """The mapping of `status`, on the daemon's own health payload shape (a live one is in test_ctl_follow)."""
    dev = {"state": "READY", "reason": "", "reconnects": 0, "jobs_done": 1, "jobs_failed": 0}
    health = {"version": "x", "uptime_s": 1.0, "alive": True, "telemetry": {"sent": 1, "dropped": {}},
              "frames": {"sent": 0, "dropped": 0}, "commands": {"requests": 1, "errors": 0},
              "devices": {"tracker": dict(dev), "robot": dict(dev, state="BUSY"), "camera": dict(dev)}}
    client = types.SimpleNamespace(call=lambda cmd, **kw: health)
    args = types.SimpleNamespace(json=False)
    assert ctl.cmd_status(client, args) == Exit.OK
    health["devices"]["tracker"].update(state="FAULT", reason="connection refused")
    assert ctl.cmd_status(client, args) == Exit.REFUSED
    out = capsys.readouterr()
    assert "connection refused" in out.out and "not ready: tracker FAULT" in out.err
    # jobs in words: "jobs=1/0 failed" read as one job of none, or as one failed
    health["devices"]["robot"].update(jobs_done=1, jobs_failed=2)
    ctl.cmd_status(client, args)
    robot = next(ln for ln in capsys.readouterr().out.splitlines() if ln.strip().startswith("robot"))
    assert "jobs 1 done, 2 failed; reconnects 0" in robot and "jobs=" not in robot, robot
    assert ctl.cmd_status(client, types.SimpleNamespace(json=True)) == Exit.REFUSED


def test_closed_stdout_pipe_is_quiet():
    """`ritactl completion bash | head -c0`: the reader is gone before the first write."""
    proc = subprocess.Popen([sys.executable, "-m", "daemon.ctl.main", "completion", "bash"], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert b"Traceback" not in err and b"BrokenPipe" not in err and b"Exception ignored" not in err


def test_key_and_config_problems_are_exit_5_naming_the_file(tmp_path, capsys):
    """main() uses ctl_keys.resolve_connection: --key/--keys/--config, never a silent plaintext fallback."""
    missing = tmp_path / "nope.toml"
    assert ctl.main(["--config", str(missing), "--endpoint", "tcp://127.0.0.1:1", "status"]) == Exit.BAD_INPUT
    assert str(missing) in capsys.readouterr().err
    assert ctl.main(["--key", "bob", "--keys", str(tmp_path), "--endpoint", "tcp://127.0.0.1:1", "--json",
                     "status"]) == Exit.BAD_INPUT
    err = json.loads(capsys.readouterr().out)
    assert err["error"] == "bad_input" and "bob.key_secret" in err["message"]
    (tmp_path / "ritactl.toml").write_text('endpoint = "127.0.0.1:5555"\n')
    assert ctl.main(["--config", str(tmp_path / "ritactl.toml"), "status"]) == Exit.BAD_INPUT
    assert "endpoint" in capsys.readouterr().err


@pytest.mark.parametrize("given, want", [(None, "1"), ("2", "2")])
def test_a_fresh_ritactl_uses_one_blas_thread_unless_told(given, want):
    """numpy's OpenBLAS reads OPENBLAS_NUM_THREADS when it loads: ritactl sets 1 first, a user's value wins,
    and a process that loaded numpy already (a library caller, this test) is left alone."""
    import os

    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if given is not None:
        env["OPENBLAS_NUM_THREADS"] = given
    code = ("import os, sys\nfrom daemon.ctl.main import main\nmain(['--version'])\nimport numpy\n"
            "print(os.environ.get('OPENBLAS_NUM_THREADS'))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, cwd=ROOT, env=env)
    assert res.stdout.split()[-1] == want, res
    before = os.environ.get("OPENBLAS_NUM_THREADS")
    import numpy  # noqa: F401

    ctl._one_blas_thread()
    assert os.environ.get("OPENBLAS_NUM_THREADS") == before


def test_recompute_runs_opencv_without_its_worker_threads(tmp_path):
    """ritactl recompute sets OPENCV_FOR_THREADS_NUM=1 before OpenCV loads (its steps split work themselves)."""
    import os

    env = {k: v for k, v in os.environ.items() if k != "OPENCV_FOR_THREADS_NUM"}
    code = ("import sys\nfrom daemon.ctl.main import main\nprint(main(['recompute', sys.argv[1]]))\nimport cv2\n"
            "print(cv2.getNumThreads())")
    res = subprocess.run([sys.executable, "-c", code, str(tmp_path / "missing")], capture_output=True, text=True,
                         timeout=60, cwd=ROOT, env=env)
    assert res.stdout.split()[-2:] == [str(int(Exit.BAD_INPUT)), "1"], res


def test_motion_verbs_print_one_line_and_json_keeps_the_raw_reply(capsys):
    """`ritactl robot move/turn`: how the motion ended and where, in words; --json: the daemon's fields."""
    from daemon.ctl.device import cmd_device

    done = {"event": "DONE", "seq": 7, "host_time_ns": 1795802312082961761, "result": "OK", "x_mm": 100.04,
            "y_mm": -0.2, "heading_deg": 0.013}
    client = types.SimpleNamespace(call_raw=lambda cmd, args, timeout: (dict(done), []))
    args = dict(arg_distance_mm=100.0, arg_confirm=True, json=False, timeout=None, command="robot.move")
    assert cmd_device(client, types.SimpleNamespace(**args)) == Exit.OK
    out = capsys.readouterr().out
    assert out == "robot move done; odometry x 100.0 mm, y -0.2 mm, heading 0.01°\n", out
    assert cmd_device(client, types.SimpleNamespace(**{**args, "json": True})) == Exit.OK
    assert json.loads(capsys.readouterr().out) == done
    turn = dict(args, command="robot.turn", arg_angle_deg=90.0)
    done.update(result="STOPPED")
    assert cmd_device(client, types.SimpleNamespace(**turn)) == Exit.OK
    assert capsys.readouterr().out.startswith("robot turn STOPPED before its end; odometry x 100.0 mm")


@pytest.mark.parametrize("reply, want", [
    ({"started": True},
     "robot move started; not waiting for its end (`ritactl robot status` shows the robot)"),
    ({"event": "DONE", "recovered": True, "result": "UNKNOWN", "x_mm": 1.0, "y_mm": 2.0, "heading_deg": 3.0},
     "robot move ended (its DONE event was lost: whether it completed is not known); odometry x 1.0 mm, "
     "y 2.0 mm, heading 3.00°"),
    ({"event": "DONE", "result": "ODD"}, "robot move ended (ODD)")])
def test_motion_text_says_how_the_motion_ended(reply, want):
    from daemon.ctl.device import motion_text

    assert motion_text("move", reply) == (want, Exit.OK)


@pytest.mark.parametrize("command, reply, want", [
    ("robot.stop", {"stopped": True, "latched": True, "jobs_stopped": []},
     "robot halted; latched: no motion until `ritactl robot release`"),
    ("robot.stop", {"stopped": False, "latched": True, "jobs_stopped": ["j1"],
                    "message": "latched; the halt is sent as soon as the base answers"},
     "robot NOT YET HALTED (latched; the halt is sent as soon as the base answers); latched: no motion until "
     "`ritactl robot release`; 1 job(s) stopped: j1"),
    ("robot.release", {"released": True, "was_latched": True},
     "released the STOP latch: motions are allowed (a stopped job continues with `ritactl resume JOB`)"),
    ("robot.release", {"released": True, "was_latched": False},
     "nothing to release (no STOP latched): motions are allowed (a stopped job continues with "
     "`ritactl resume JOB`)")])
def test_stop_and_release_print_one_line_and_json_keeps_the_reply(command, reply, want, capsys):
    """`ritactl robot stop/release` (issue 35, motion verbs): one line in words; --json: the reply."""
    from daemon.ctl.device import cmd_device

    client = types.SimpleNamespace(call_raw=lambda cmd, args, timeout: (dict(reply), []))
    args = dict(json=False, timeout=None, command=command)
    assert cmd_device(client, types.SimpleNamespace(**args)) == Exit.OK
    assert capsys.readouterr().out == want + "\n"
    assert cmd_device(client, types.SimpleNamespace(**{**args, "json": True})) == Exit.OK
    assert json.loads(capsys.readouterr().out) == reply
