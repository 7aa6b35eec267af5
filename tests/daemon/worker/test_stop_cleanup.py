"""A STOP stays the job's outcome when the cleanup after it fails (``JobContext.afterwards``).

Seen under load: a STOP ended the recorded move, then ``tracker.stream.stop`` failed with the tracker's
connection closed (its StopMeasurement unanswered in time, the client hung up to resynchronise), and that
error replaced ``Stopped``: the job failed instead of stopping. The rule: the first error ends the job; a
cleanup that fails after it is a note on that error and a log line, never the outcome. A cleanup that fails
after a body that ended well fails the job, as any call does.

A scripted bus (no daemon): the job's inbox posts the STOP once the move is sent, as ritad's
``stop_moving_jobs`` does, and the tracker's stream stop answers ``device_lost`` as ritad's runner answers
a job whose emScon connection is gone.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from daemon.bus.client import Client
from daemon.bus.protocol import CommandError, ErrorCode
from daemon.worker.__main__ import operator_message
from daemon.worker.job import Cancelled, JobContext, StepFailed, Stopped, ended_with
from daemon.worker.stream import record_move
from drivers.emscon.enums import ES_Command, ES_ResultStatus
from fakes.operator import lock_on_robot
from tests.ritad_up import SMALL_CAMERA, ritad_in_process

CLOSED = "tracker: emScon connection to 127.0.0.1:7000 is closed"


class NoMessages:
    def recv(self, timeout: float) -> None:
        return None

    def close(self) -> None:
        pass


class Bus:
    """ritad as the worker sees it: a STOP posted once ``robot.move`` was sent; the stream stop fails."""

    def __init__(self, stream_stop_fails: bool = True) -> None:
        self.sent: list[str] = []
        self.stopped = False
        self.stream_stop_fails = stream_stop_fails

    def call(self, cmd: str, timeout: float | None = None, **args: Any) -> Any:
        self.sent.append(cmd)
        if cmd == "calib.inbox":
            return {"stop": True} if self.stopped else None
        if cmd == "robot.move":
            self.stopped = True  # the operator's STOP lands while the base drives
            return {"accepted": True}
        if cmd == "tracker.stream.stop" and self.stream_stop_fails:
            raise CommandError(ErrorCode.DEVICE_LOST, CLOSED)
        if cmd == "tracker.stream.start":
            return {"streaming": True, "rate_hz": 10.0}
        if cmd == "robot.status":
            return {"state": "MOVING", "streams": [], "host_time_ns": 0}
        return {}

    def subscriber(self, topics: list[str]) -> NoMessages:
        return NoMessages()


def _ctx(tmp_path: Path, bus: Bus) -> JobContext:
    job = {"job": "j1", "procedure": "measure-mark", "params": {}}
    return JobContext(bus, job, tmp_path)  # type: ignore[arg-type]


def test_a_stop_during_the_recorded_move_stays_stopped_when_the_stream_stop_fails(tmp_path: Path) -> None:
    bus = Bus()
    with pytest.raises(Stopped) as got:
        record_move(_ctx(tmp_path, bus), 150.0, 25.0, np.eye(4), None)
    assert bus.sent.count("tracker.stream.stop") == 1  # the stream was still asked to end
    assert "stopped" in str(got.value)
    assert got.value.__notes__ == [f"tracker.stream.stop failed after it: {CLOSED} [device_lost]"]
    told = ended_with(got.value)  # what the operator reads: stopped first, the failed cleanup beside it
    assert told.startswith("job j1 stopped") and "is closed" in told, told


def test_a_stop_with_a_stream_stop_that_works_leaves_no_note(tmp_path: Path) -> None:
    bus = Bus(stream_stop_fails=False)
    with pytest.raises(Stopped) as got:
        record_move(_ctx(tmp_path, bus), 150.0, 25.0, np.eye(4), None)
    assert bus.sent.count("tracker.stream.stop") == 1 and not getattr(got.value, "__notes__", None)
    assert ended_with(got.value) == str(got.value)


@pytest.mark.parametrize("ending", [Stopped("job j1 stopped"), Cancelled("job j1 cancelled"),
                                    StepFailed("run0: the base did not move"),
                                    CommandError(ErrorCode.DEVICE_ERROR, "robot FAULT")])
def test_the_first_error_is_the_outcome_and_the_failed_cleanup_a_note(tmp_path: Path,
                                                                      ending: Exception) -> None:
    ctx = _ctx(tmp_path, Bus())
    with pytest.raises(type(ending)) as got:
        with ctx.afterwards("tracker.stream.stop"):
            raise ending
    assert got.value is ending and "is closed" in operator_message(got.value)


def test_a_cleanup_that_fails_after_a_good_body_fails_the_job(tmp_path: Path) -> None:
    ctx = _ctx(tmp_path, Bus())
    with pytest.raises(CommandError, match="is closed"):
        with ctx.afterwards("tracker.stream.stop"):
            pass  # the move ended well: a stream left running is the job's error


class StopAfterMove:
    """The worker's bus client, with the operator's STOP sent the moment the recorded move was accepted."""

    def __init__(self, client: Client) -> None:
        self.client = client

    def call(self, cmd: str, timeout: float | None = None, **args: Any) -> Any:
        got = self.client.call(cmd, timeout=timeout, **args)
        if cmd == "robot.move":
            assert self.client.call("robot.stop")["latched"]
        return got

    def subscriber(self, topics: list[str]) -> Any:
        return self.client.subscriber(topics)


def test_through_ritad_a_stream_stop_refused_after_a_stop_leaves_the_job_stopped(tmp_path: Path) -> None:
    """ritad in-process on the fakes; the fake tracker refuses StopMeasurement (a fault knob, set once the
    stream runs): ritad answers the stream stop with the tracker's error, the job still ends Stopped."""
    with ritad_in_process(tmp_path / "rt", tmp_path / "data", camera=SMALL_CAMERA,
                          robot="sim:?time_scale=0.1") as (d, c):
        lock_on_robot(c)
        c.call("calib.start", procedure="measure-mark", params={"mark_xy": [0.0, 0.0]})
        job = c.call("calib.next", timeout=20, timeout_s=2)  # taken as the worker takes it: it is running
        ctx = JobContext(StopAfterMove(c), job, tmp_path / "data")  # type: ignore[arg-type]
        fake = d.rigs.tracker.runner.device.server.faults
        fake.fail[ES_Command.StopMeasurement] = ES_ResultStatus.InternalProcessActive
        with pytest.raises(Stopped) as got:
            record_move(ctx, 150.0, 25.0, np.eye(4), None)
        fake.fail.clear()
        (note,) = got.value.__notes__
        assert note.startswith("tracker.stream.stop failed after it: tracker: "), note
        assert "InternalProcessActive" in note, note
        assert c.call("calib.jobs")["jobs"][0]["state"] == "stopped"
