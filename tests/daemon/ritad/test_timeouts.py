"""One thread for every timeout ritad waits on (daemon/ritad/timeouts.py), and its users: long polls,
motions waiting for their end. Deterministic: events with time limits, no wall-clock asserts."""
from __future__ import annotations

import threading
from concurrent.futures import Future

import pytest

from daemon.bus.command_table import validate
from daemon.bus.protocol import CommandError
from daemon.ritad.calib_jobs import CalibJobs
from daemon.ritad.motion import MotionWaiters
from daemon.ritad.server import Request
from daemon.ritad.timeouts import Timeouts


def test_due_calls_run_in_deadline_order_in_one_thread_and_cancelled_ones_never():
    t = Timeouts()
    ran: list[tuple[str, str]] = []
    done = threading.Event()
    t.call_later(0.2, lambda: (ran.append(("late", threading.current_thread().name)), done.set()))
    t.call_later(0.05, lambda: ran.append(("early", threading.current_thread().name)))  # added later, due first
    t.call_later(0.1, lambda: ran.append(("cancelled", ""))).cancel()
    assert done.wait(10)
    assert [name for name, _ in ran] == ["early", "late"]
    assert {thread for _, thread in ran} == {"timeouts"}
    t.stop()


def test_a_failing_callback_does_not_stop_the_others():
    t = Timeouts()
    done = threading.Event()
    t.call_later(0.0, lambda: 1 / 0)
    t.call_later(0.01, done.set)
    assert done.wait(10)
    t.stop()


def test_after_stop_nothing_runs_and_nothing_is_scheduled():
    t = Timeouts()
    ran = threading.Event()
    t.call_later(0.05, ran.set)
    t.stop()
    assert t.call_later(0.0, ran.set).cancelled
    assert not ran.wait(0.2)


def test_a_poll_with_timeout_zero_schedules_nothing_and_a_long_poll_its_one_entry():
    timeouts = Timeouts()
    jobs = CalibJobs(lambda topic, data: None, timeouts=timeouts)

    def bus(cmd, **args):
        return jobs.handlers()[cmd](Request("1", cmd, validate(cmd, args), "test"))

    job = bus("calib.start", procedure="referencing", params={})["job"]
    for _ in range(200):  # the worker's polls while a job runs
        assert bus("calib.inbox", job=job, timeout_s=0).result(timeout=2) is None
    assert timeouts._thread is None  # no timeout was ever needed
    assert bus("calib.next", timeout_s=0).result(timeout=2)["job"] == job
    waiting = bus("calib.next", timeout_s=0.05)
    assert waiting.result(timeout=10) is None  # expired in the timeouts' thread
    assert timeouts._thread is not None and timeouts._thread.name == "timeouts"
    timeouts.stop()


def test_a_motion_not_done_in_time_fails_with_timeout_from_the_shared_thread():
    timeouts = Timeouts()
    started: Future = Future()
    started.set_result(None)
    waiters = MotionWaiters(lambda fn: started, timeouts)
    done = waiters.start(lambda robot: None, wait=True, timeout=0.05)
    with pytest.raises(CommandError) as e:
        done.result(timeout=10)
    assert e.value.code == "timeout"
    finished = waiters.start(lambda robot: None, wait=True, timeout=60)
    waiters.on_event({"event": "DONE"})
    assert finished.result(timeout=10)["event"] == "DONE"  # its timeout is cancelled, never fires
    timeouts.stop()
