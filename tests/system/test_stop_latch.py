"""STOP means stop: a latched stop during a running 8-direction experiment, through the bus.

ritad --sim with its calibration worker. To keep this about the stop, not about accuracy,
the referencing that gives the experiment its calibration uses the world's own camera
model and the plate's design file (the closed loop with measured inputs is
test_worker_e2e.py). The STOP comes at a random moment of a move (seeded), from an
operator's client and from a viewer's key over CURVE.
"""
from __future__ import annotations

import json
import random
import time
from typing import Any

import pytest

from daemon.bus.client import Client, ClientTimeout
from daemon.bus.protocol import CommandError
from fakes.demo import operator_files
from fakes.launch import start_ritad
from fakes.operator import lock_on_robot, rough_mark
from tools.harness.load import hang_s

pytestmark = pytest.mark.slow


def _jobs(c: Client) -> dict[str, dict[str, Any]]:
    return {j["job"]: j for j in c.call("calib.jobs")["jobs"]}


def wait_for(pred: Any, timeout: float, what: str, poll: float = 0.02) -> Any:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        got = pred()
        if got:
            return got
        time.sleep(poll)
    raise AssertionError(f"not within {timeout} s: {what}")


def wait_end(c: Client, job: str, timeout: float = 400) -> dict[str, Any]:
    def ended() -> dict[str, Any] | None:
        entry = _jobs(c)[job]  # read once: the state tested is the state returned
        return entry if entry["state"] in ("done", "failed", "stopped") else None

    return wait_for(ended, timeout, f"job {job} ended", poll=0.5)


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("stop")
    with start_ritad(tmp=tmp, args=["--seed", "3"], timeout=90) as r:
        try:
            r.wait_ready(timeout=90, worker=True)
        except ClientTimeout as exc:
            raise AssertionError(f"daemon not ready: {exc}\n{r.log_tail()}") from None
        with r.client(timeout=30) as c:
            files = operator_files(c, tmp)
            truth = c.call("sim.truth")
            p = lock_on_robot(c)
            params = {"plate": json.loads(files["plate_design"].read_text()),
                      "nests_approx_trk": json.loads(files["nests"].read_text()),
                      "robot_approx_trk": [p["x"], p["y"], p["z"]], "camera_model": truth["camera_model"]}
            job = c.call("calib.start", procedure="referencing", params=params)["job"]
            end = wait_end(c, job)
            assert end["state"] == "done", end
            yield r, c


def stop_mid_move(c: Client, stopper: Client, rng: random.Random) -> str:
    """Start an experiment, STOP at a random moment of one of its moves, wait for the base idle; the job.
    How soon the base is idle after the STOP: bench/bench_console_latency.py (and bench/bench_stop.py)."""
    _, mark = rough_mark(c)
    job = c.call("calib.start", procedure="experiment", params={"mark_xy": mark, "repetitions": 1})["job"]
    for _ in range(rng.randint(1, 3)):  # past a few motions: the STOP lands inside the procedure
        wait_for(lambda: c.call("robot.status")["state"] == "MOVING", 120, "the experiment moves the robot")
        wait_for(lambda: c.call("robot.status")["state"] == "IDLE", 120, "the motion ends")
    wait_for(lambda: c.call("robot.status")["state"] == "MOVING", 120, "the experiment moves the robot")
    time.sleep(rng.uniform(0.0, 0.05))  # a random moment of the move (the fake base runs 50x real time)
    reply = stopper.call("robot.stop")
    assert reply["latched"] and job in reply["jobs_stopped"], reply
    wait_for(lambda: c.call("robot.status")["state"] == "IDLE", hang_s(5), "the base idle after STOP",
             poll=0.005)
    return job


def assert_still(c: Client, seconds: float) -> None:
    """No motion for ``seconds``: the base idle and its odometry unchanged."""
    first = c.call("robot.status")
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        st = c.call("robot.status")
        assert st["state"] == "IDLE", st
        assert abs(st["x_mm"] - first["x_mm"]) < 1e-3 and abs(st["y_mm"] - first["y_mm"]) < 1e-3, (first, st)
        time.sleep(0.1)


def code_of(c: Client, cmd: str, **args: Any) -> str:
    try:
        c.call(cmd, **args)
    except CommandError as exc:
        return exc.code
    return "ok"


def check_stopped_then_resume(c: Client, job: str) -> None:
    assert_still(c, 10.0)  # no motion after the STOP
    j = _jobs(c)[job]
    assert j["state"] == "stopped", j
    assert c.call("state")["latch"]["latched"]
    assert code_of(c, "robot.move", distance_mm=10, confirm=True) == "stopped"
    assert code_of(c, "calib.resume", job=job) == "stopped"  # not before the latch is cleared
    assert code_of(c, "calib.start", procedure="experiment", params={"mark_xy": [0, 0]}) == "stopped"
    assert c.call("robot.release") == {"released": True, "was_latched": True}
    wait_for(lambda: code_of(c, "calib.resume", job=job) == "ok", 30, "resume accepted after release",
             poll=0.5)
    end = wait_end(c, job)
    assert end["state"] == "done", (end["error"], end["result"])


def test_stop_from_an_operator_latches_and_the_job_resumes_after_release(rig):
    _, c = rig
    job = stop_mid_move(c, c, random.Random(19))
    check_stopped_then_resume(c, job)


def test_ritactl_robot_stop_latches_the_same_way(rig):
    """`ritactl robot stop` mid-experiment: the same latch, the same stopped job, `ritactl robot release`."""
    r, c = rig
    from daemon.ctl import main as ctl

    class Ritactl:  # a Client-like stopper that goes through ritactl's command line
        def call(self, cmd: str) -> dict[str, Any]:
            assert cmd == "robot.stop"
            assert ctl.main(["--endpoint", r.endpoint, "robot", "stop"]) == 0
            return {"latched": True,
                    "jobs_stopped": [j for j, v in _jobs(c).items() if v["state"] == "stopped"]}

    job = stop_mid_move(c, Ritactl(), random.Random(7))
    assert ctl.main(["--endpoint", r.endpoint, "robot", "release"]) == 0
    assert not c.call("state")["latch"]["latched"]
    c.call("robot.stop")  # latched again: the helper below releases it itself
    check_stopped_then_resume(c, job)
