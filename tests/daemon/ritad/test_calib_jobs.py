"""The calibration job mailbox on its own: final states stay final, answers are checked
against the prompt's choices, unknown job ids are clear errors, resume re-queues only
failed or cancelled jobs (also ones found on disk after a daemon restart)."""
import json

import pytest

from daemon.bus.command_table import validate
from daemon.ritad.calib_jobs import CalibJobs
from daemon.bus.protocol import CommandError
from daemon.ritad.server import Request


class Bus:
    def __init__(self, tmp_path=None):
        self.published = []
        self.jobs = CalibJobs(lambda topic, data: self.published.append((topic, data)), data_dir=tmp_path)

    def __call__(self, cmd, **args):  # as ritad's dispatch: the command table validates first
        return self.jobs.handlers()[cmd](Request("1", cmd, validate(cmd, args), "test"))

    def state(self, job):
        return {j["job"]: j for j in self("calib.jobs")["jobs"]}[job]


def take(bus):
    """What the worker gets from calib.next (timeout 0: never blocks)."""
    return bus("calib.next", timeout_s=0).result(timeout=1)


def error_of(fn, *a, **kw) -> CommandError:
    with pytest.raises(CommandError) as e:
        fn(*a, **kw)
    return e.value


def test_done_job_stays_done_after_a_late_progress_report():
    bus = Bus()
    job = bus("calib.start", procedure="referencing", params={})["job"]
    assert take(bus)["job"] == job and bus.state(job)["state"] == "queued"
    bus("calib.report", job=job, kind="progress", data={"step": "x", "percent": 50})
    assert bus.state(job)["state"] == "running"
    bus("calib.report", job=job, kind="result", data={"verdict": "ok", "procedure": "referencing"})
    r = bus("calib.report", job=job, kind="progress", data={"step": "done", "percent": 100})
    assert "ignored" in r
    st = bus.state(job)
    assert st["state"] == "done" and st["result"]["verdict"] == "ok" and st["error"] is None
    assert [t for t, d in bus.published if t == "calib.progress" and d.get("percent") == 100] == []


def test_cancelled_and_failed_are_told_apart():
    bus = Bus()
    a = bus("calib.start", procedure="experiment", params={"mark_xy": [0, 0]})["job"]
    b = bus("calib.start", procedure="experiment", params={"mark_xy": [0, 0]})["job"]
    bus("calib.report", job=a, kind="error", data={"message": "stopped", "cancelled": True})
    bus("calib.report", job=b, kind="error", data={"message": "the tracker lost the beam"})
    sa, sb = bus.state(a), bus.state(b)
    assert sa["state"] == "cancelled" and sa["result"]["failed"] and sa["result"]["state"] == "cancelled"
    assert sb["state"] == "failed" and sb["error"] == "the tracker lost the beam"
    results = [d for t, d in bus.published if t == "calib.result"]
    assert [d["state"] for d in results] == ["cancelled", "failed"]


@pytest.mark.parametrize("cmd,args", [("calib.cancel", {}), ("calib.answer", {"answer": "ok"}),
                                      ("calib.resume", {}), ("calib.inbox", {"timeout_s": 0})])
def test_unknown_job_is_a_clear_error(cmd, args):
    bus = Bus()
    e = error_of(bus, cmd, job="no-such-job", **args)
    assert e.code == "not_found" and "no-such-job" in str(e) and cmd in str(e)
    e = error_of(bus, cmd, job="../etc", **args)
    assert e.code == "bad_args" and "'../etc'" in str(e)


def test_answer_must_be_one_of_the_choices():
    bus = Bus()
    job = bus("calib.start", procedure="referencing", params={})["job"]
    e = error_of(bus, "calib.answer", job=job, answer="ok")
    assert e.code == "bad_args" and "not asking" in str(e)
    bus("calib.report", job=job, kind="prompt", data={"question": "lock on the red nest", "choices": ["ok"]})
    assert bus.state(job)["state"] == "waiting"
    e = error_of(bus, "calib.answer", job=job, answer="yes")
    assert e.code == "bad_args" and "['ok']" in str(e) and "'yes'" in str(e)
    assert bus("calib.inbox", job=job, timeout_s=0).result(timeout=2) is None  # nothing was delivered
    assert bus("calib.answer", job=job, answer="ok")["delivered"]
    assert bus("calib.inbox", job=job, timeout_s=0).result(timeout=2) == {"answer": "ok"}
    assert bus.state(job)["state"] == "running"


def test_cancel_of_a_finished_job_is_refused_and_leaves_no_stale_cancel():
    bus = Bus()
    job = bus("calib.start", procedure="intrinsics", params={})["job"]
    take(bus)
    bus("calib.report", job=job, kind="error", data={"message": "no target in view"})
    e = error_of(bus, "calib.cancel", job=job)
    assert e.code == "bad_args" and "already failed" in str(e)
    bus("calib.resume", job=job)
    assert take(bus) == {"job": job, "procedure": "intrinsics", "params": {"board": None}}  # resolved: installed
    assert bus.state(job)["state"] == "queued" and bus.state(job)["result"] is None
    assert bus("calib.inbox", job=job, timeout_s=0).result(timeout=2) is None


def test_resume_only_failed_or_cancelled():
    bus = Bus()
    job = bus("calib.start", procedure="referencing", params={})["job"]
    e = error_of(bus, "calib.resume", job=job)
    assert e.code == "bad_args" and "still queued" in str(e)
    e = error_of(bus, "calib.start", procedure="referencing", job=job, params={})
    assert "still queued" in str(e)
    bus("calib.report", job=job, kind="result", data={"verdict": "ok"})
    e = error_of(bus, "calib.resume", job=job)
    assert e.code == "bad_args" and "is done" in str(e)


def test_resume_finds_a_job_of_an_earlier_daemon_run_on_disk(tmp_path):
    root = tmp_path / "procedures" / "old-job"
    root.mkdir(parents=True)
    (root / "state.json").write_text(json.dumps({"job": "old-job", "procedure": "experiment", "status": "cancelled"}))
    bus = Bus(tmp_path)
    bus("calib.resume", job="old-job")
    assert take(bus)["procedure"] == "experiment"
    e = error_of(bus, "calib.resume", job="never-ran")
    assert e.code == "not_found" and "never-ran" in str(e)
