"""The latched stop on its own: the latch, the jobs it stops, the motions it refuses.

The daemon-level acceptance (a STOP during a running experiment) is tests/system/test_stop_latch.py;
viewers stopping over CURVE are in test_roles_curve.py.
"""
from __future__ import annotations

import json
from concurrent.futures import Future

import pytest

from daemon.bus.command_table import validate
from daemon.bus.protocol import CommandError
from daemon.ritad.calib_jobs import CalibJobs
from daemon.ritad.motion import MotionWaiters
from daemon.ritad.server import Request
from daemon.ritad.stop_latch import LATCH_FILE, StopLatch


class Bus:
    def __init__(self, tmp_path=None):
        self.published = []
        self.latch = StopLatch(self.publish, None if tmp_path is None else tmp_path / LATCH_FILE)
        self.jobs = CalibJobs(self.publish, data_dir=tmp_path, latch=self.latch)

    def publish(self, topic, data):
        self.published.append((topic, data))

    def __call__(self, cmd, **args):
        return self.jobs.handlers()[cmd](Request("1", cmd, validate(cmd, args), "test"))

    def state(self, job):
        return {j["job"]: j for j in self("calib.jobs")["jobs"]}[job]


def code(fn, *a, **kw) -> str:
    try:
        fn(*a, **kw)
    except CommandError as exc:
        return exc.code
    return "ok"


def test_stop_stops_every_moving_job_at_once_and_not_the_intrinsics():
    bus = Bus()
    running = bus("calib.start", procedure="experiment", params={"mark_xy": [0, 0]})["job"]
    assert bus("calib.next", timeout_s=0).result(1)["job"] == running  # the worker took it
    bus("calib.report", job=running, kind="progress", data={"step": "direction 1/8", "percent": 5})
    queued = bus("calib.start", procedure="referencing", params={})["job"]
    intrinsics = bus("calib.start", procedure="intrinsics", params={})["job"]
    bus.latch.engage("ole (operator)")
    assert sorted(bus.jobs.stop_moving_jobs("ole (operator)")) == sorted([running, queued])
    assert bus.state(running)["state"] == bus.state(queued)["state"] == "stopped"
    assert bus.state(intrinsics)["state"] == "queued"
    # the queued referencing left the queue: the worker's next job is the intrinsics
    assert bus("calib.next", timeout_s=0).result(1)["job"] == intrinsics
    # the running job's worker learns it at its next bus call, before any further step
    assert bus("calib.inbox", job=running, timeout_s=0).result(1) == {"stop": True}
    results = [d for t, d in bus.published if t == "calib.result"]
    assert {d["job"] for d in results} == {running, queued} and all(d["stopped"] for d in results)
    # late progress of the stopped run cannot set it running again
    bus("calib.report", job=running, kind="progress", data={"step": "direction 2/8", "percent": 9})
    assert bus.state(running)["state"] == "stopped"


def test_resume_only_after_release_and_after_the_stopped_run_ended():
    bus = Bus()
    job = bus("calib.start", procedure="experiment", params={"mark_xy": [0, 0]})["job"]
    bus("calib.next", timeout_s=0).result(1)
    bus.latch.engage("vic (viewer)")
    bus.jobs.stop_moving_jobs("vic (viewer)")
    assert code(bus, "calib.resume", job=job) == "stopped"
    assert code(bus, "calib.start", procedure="measure-mark", params={}) == "stopped"
    assert code(bus, "calib.cancel", job=job) == "bad_args"  # nothing runs: there is nothing to cancel
    assert bus.latch.release("ole (operator)")
    assert code(bus, "calib.resume", job=job) == "busy"  # its worker has not ended the stopped run yet
    bus("calib.report", job=job, kind="error", data={"message": "stopped", "stopped": True})
    assert bus("calib.resume", job=job)["job"] == job
    assert bus.state(job)["state"] == "queued"
    assert bus("calib.inbox", job=job, timeout_s=0).result(1) is None  # the old stop does not hit the new run


def test_a_job_adopted_after_a_restart_that_the_stop_ended_is_stopped_not_failed():
    """ritad restarted (the latch persisted), its worker reports the run the stop ended: the job it adopts is
    ``stopped`` and resumable after release, as it would have been without the restart."""
    bus = Bus()
    bus.latch.engage("ole (operator)")
    bus("calib.report", job="exp-7", kind="error", procedure="experiment",
        data={"message": "stopped by ole (operator)", "stopped": True})
    assert bus.state("exp-7")["state"] == "stopped"
    assert code(bus, "calib.resume", job="exp-7") == "stopped"  # latched
    bus.latch.release("ole (operator)")
    assert bus("calib.resume", job="exp-7")["job"] == "exp-7"  # its run has ended: no wait for it
    failed = bus("calib.report", job="int-1", kind="error", procedure="intrinsics", data={"message": "no board"})
    assert failed == {"ok": True} and bus.state("int-1")["state"] == "failed"


def test_the_latch_survives_a_restart_and_refuses_with_who_and_how(tmp_path):
    got = []
    latch = StopLatch(lambda t, d: got.append((t, d)), tmp_path / LATCH_FILE)
    halted, persisted = latch.engage("vic (viewer)")
    assert got[-1][0] == "robot.latch" and got[-1][1]["latched"] and got[-1][1]["by"] == "vic (viewer)"
    assert got[-1][1]["halt_pending"] and not halted.done()  # no robot here: the halt stays owed
    persisted.result(timeout=10)  # written in the latch's own thread, after the halt was requested
    again = StopLatch(lambda t, d: None, tmp_path / LATCH_FILE)  # a watchdog restart of ritad
    assert again.latched and again.by == "vic (viewer)"
    assert again.gate.latched and again.gate.pending  # the restarted daemon owes the base a halt
    with pytest.raises(CommandError) as e:
        again.guard("robot.move", "worker (operator)")
    assert e.value.code == "stopped" and "vic (viewer)" in e.value.args[0] and "robot release" in e.value.args[0]
    assert again.snapshot()["refused"] == 1
    assert again.release("ole (operator)")
    again.close()  # the queued write done
    assert not StopLatch(lambda t, d: None, tmp_path / LATCH_FILE).latched
    assert not again.release("ole (operator)")  # releasing twice is harmless


def test_an_unreadable_latch_file_stays_stopped(tmp_path):
    (tmp_path / LATCH_FILE).write_text("{not json")
    assert StopLatch(lambda t, d: None, tmp_path / LATCH_FILE).latched


def test_abort_fails_every_motion_waiting_for_its_end():
    started: list[Future] = []

    def submit(fn):
        f: Future = Future()
        started.append(f)
        return f

    motions = MotionWaiters(submit)
    done = motions.start(lambda r: None, wait=True, timeout=60)
    started[0].set_result(None)  # the base ACKed the move
    motions.abort("robot stopped")
    with pytest.raises(CommandError) as e:
        done.result(1)
    assert e.value.code == "stopped"
    motions.on_event({"event": "DONE", "result": "STOPPED"})  # the base's DONE after the stop: nothing left


def test_a_motion_queued_before_the_stop_is_refused_when_its_turn_comes(tmp_path):
    """robot.move accepted, then STOP jumps the runner's queue: the queued move must not run after it."""
    from daemon.ritad import config
    from daemon.ritad.commands import _robot
    from tests.ritad_up import unstarted_rigs

    queued = []
    latch = StopLatch(lambda t, d: None)
    robot = unstarted_rigs(config.sim_config(tmp_path), latch).robot
    robot.job = lambda fn, timeout=60.0: queued.append(fn) or Future()  # type: ignore[method-assign]
    handlers = _robot(robot, CalibJobs(lambda t, d: None, latch=latch))
    args = validate("robot.move", {"distance_mm": 10.0, "confirm": True})
    handlers["robot.move"](Request("1", "robot.move", args, "worker", "operator"))
    handlers["robot.stop"](Request("2", "robot.stop", {}, "vic (key)", "viewer"))
    moved = []
    with pytest.raises(CommandError) as e:
        queued[0](type("Base", (), {"move": lambda self, a, v: moved.append(a)})())
    assert e.value.code == "stopped" and moved == []
    assert json.dumps(latch.snapshot())  # JSON-able, as telemetry and the latch file need


def _done(value):
    f: Future = Future()
    f.set_result(value)
    return f
