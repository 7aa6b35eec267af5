"""Worker pieces without a daemon: the camera-model install decision and operator-worded failures."""
import json
from pathlib import Path

import pytest

from calibration.errors import CalibrationError
from daemon.worker.__main__ import operator_message
from daemon.worker.job import StepFailed
from daemon.worker.store import install_camera_model
from daemon.bus.client import ClientTimeout
from daemon.bus.protocol import CommandError


class FakeCtx:
    def __init__(self, data_dir: Path, answer):
        self.data_dir = data_dir
        self.answer = answer
        self.asked = []

    def ask(self, question, choices, timeout_s):
        self.asked.append((question, choices))
        if isinstance(self.answer, Exception):
            raise self.answer
        return self.answer


def result(tmp_path: Path, verdict: str) -> dict:
    ds = tmp_path / "procedures" / "job1"
    ds.mkdir(parents=True, exist_ok=True)
    model = {"K": [[1000.0, 0, 10], [0, 1000.0, 10], [0, 0, 1]], "dist": [0, 0, 0, 0, 0], "size": [20, 20]}
    (ds / "camera_model.json").write_text(json.dumps(model))
    return {"verdict": verdict, "camera_model": model, "dataset": str(ds),
            "messages": ["focal length only known to ±9.0 px"] if verdict == "warn" else []}


@pytest.mark.parametrize("verdict,answer,installed", [
    ("ok", None, True), ("warn", "install", True), ("warn", "skip", False),
    ("warn", TimeoutError("no answer"), False), ("fail", None, False)])
def test_camera_model_install_decision(tmp_path, verdict, answer, installed):
    ctx = FakeCtx(tmp_path, answer)
    target = tmp_path / "calibration" / "camera_model.json"
    msg = install_camera_model(ctx, result(tmp_path, verdict))
    assert target.exists() is installed
    assert bool(ctx.asked) is (verdict == "warn")  # only warn asks
    if verdict == "warn":
        question, choices = ctx.asked[0]
        assert choices == ["install", "skip"] and "focal length" in question
    if installed:
        assert msg == f"camera model installed as {target}"
    else:
        assert "NOT installed" in msg and f"{tmp_path / 'procedures' / 'job1' / 'camera_model.json'}" in msg
        assert "--camera-model" in msg


@pytest.mark.parametrize("exc,expected", [
    (CommandError("tracker_MeasurementStatusNotReady", "the tracker is not locked"),
     "the tracker is not locked [tracker_MeasurementStatusNotReady]"),
    (CalibrationError("only 2 of 6 views have >= 30 corners"),
     "the calculation could not give a trustworthy result: only 2 of 6 views have >= 30 corners"),
    (ValueError("params.mark_xy must be the approximate ACS x, y"),
     "params.mark_xy must be the approximate ACS x, y"),
    (KeyError("plate"), "'plate' is missing from the parameters or the stored data"),
    (ClientTimeout("no answer from ritad"), "the daemon did not answer (no answer from ritad)"),
    (StepFailed("the target is not in view"), "the target is not in view"),
])
def test_failure_messages_are_operator_words(exc, expected):
    assert operator_message(exc) == expected


def test_a_bug_keeps_its_class_name_but_not_in_front():
    msg = operator_message(ZeroDivisionError("division by zero"))
    assert msg.startswith("internal error in the calibration worker") and "ZeroDivisionError" in msg


class FakeClient:
    """The bus as the worker sees it: reports are recorded, the inbox is empty."""

    def __init__(self):
        self.reports = []

    def call(self, cmd, timeout=None, **args):
        if cmd == "calib.report":
            self.reports.append((args["kind"], args["data"]))
            return {"ok": True}
        if cmd == "calib.inbox":
            return None
        raise AssertionError(f"unexpected bus call {cmd}")


def test_resume_of_a_failed_calculation_says_nothing_changed(tmp_path):
    """All steps stored, the calculation fails: a resume re-runs it and says the data is unchanged."""
    from daemon.worker.__main__ import run_job

    root = tmp_path / "procedures" / "mm-1"
    root.mkdir(parents=True)
    state = {"schema": 1, "job": "mm-1", "procedure": "measure-mark", "params": {"mark_xy": [1, 2]},
             "status": "running", "done": ["stop"], "obs": {"calibration": {"job": "c"}, "stop": {}}}
    (root / "state.json").write_text(json.dumps(state))
    job = {"job": "mm-1", "procedure": "measure-mark", "params": {}}
    client = FakeClient()
    assert run_job(client, job, tmp_path) is None
    kind, first = client.reports[-1]
    assert kind == "error" and first["message"].startswith("compute the result: ")
    assert "ritactl resume mm-1" in first["message"] and "Error" not in first["message"].split(":")[0]
    assert json.loads((root / "state.json").read_text())["status"] == "failed"

    client = FakeClient()
    assert run_job(client, job, tmp_path) is None
    progress = [d for k, d in client.reports if k == "progress"]
    assert "re-running the failed step (compute the result)" in progress[0]["waiting_for"]
    kind, second = client.reports[-1]
    assert kind == "error" and "failed again on the same stored data" in second["message"]
    assert "ritactl resume" not in second["message"]  # a resume cannot help: it says so
    assert not [d for k, d in client.reports if k == "progress" and d["percent"] == 100]
