"""DeviceRunner: state machine, reconnect with backoff, jobs in arrival order, pump delivery."""
import threading
import time

import pytest

from daemon.bus.protocol import CommandError, ErrorCode
from daemon.ritad.runner import DeviceRunner
from drivers.base import Device, DeviceError, DeviceLost, DeviceState, DeviceURL


class FlakyDevice(Device):
    """Fails to open ``fail_opens`` times; ``lose()`` makes the next call raise DeviceLost."""

    kind = "test"

    def __init__(self, fail_opens=0):
        super().__init__(DeviceURL.parse("test:"))
        self.fail_opens = fail_opens
        self.opens = self.closes = self.pumps = 0
        self.lost = False
        self.log = []

    def open(self):
        if self.fail_opens > 0:
            self.fail_opens -= 1
            raise ConnectionRefusedError("not there yet")
        self.opens += 1
        self.lost = False

    def close(self):
        self.closes += 1

    def pump(self, timeout):
        self.pumps += 1
        if self.lost:
            raise DeviceLost("cable pulled")
        time.sleep(timeout)

    def work(self, tag):
        if self.lost:
            raise DeviceLost("cable pulled")
        self.log.append(tag)
        return tag


def wait_for(pred, timeout=5.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.01)
    return False


@pytest.fixture
def events():
    return []


def make(dev, events):
    r = DeviceRunner("test", lambda: dev, lambda topic, data: events.append((topic, data)),
                     backoff_min=0.05, backoff_max=0.2)
    r.start()
    return r


def test_connect_retries_with_backoff_then_ready(events):
    dev = FlakyDevice(fail_opens=3)
    r = make(dev, events)
    try:
        assert wait_for(lambda: r.state is DeviceState.READY)
        states = [d["state"] for t, d in events if t == "daemon.state"]
        assert states.count("FAULT") == 3 and states[-1] == "READY"
        assert "not there yet" in [d for t, d in events if d["state"] == "FAULT"][0]["reason"]
        assert r.submit(lambda d: d.work("a")).result(2) == "a"
    finally:
        r.stop()
    assert dev.closes >= 1 and r.state is DeviceState.DISCONNECTED


def test_jobs_fail_fast_when_not_connected(events):
    r = make(FlakyDevice(fail_opens=1000), events)
    try:
        assert wait_for(lambda: r.state is DeviceState.FAULT)
        with pytest.raises(CommandError) as err:
            r.submit(lambda d: d.work("x")).result(1)
        assert err.value.code == ErrorCode.NOT_READY and "not there yet" in str(err.value)
    finally:
        r.stop()


def test_device_lost_reconnects_and_reports(events):
    dev = FlakyDevice()
    r = make(dev, events)
    try:
        assert wait_for(lambda: r.state is DeviceState.READY)
        dev.lost = True
        assert wait_for(lambda: r.reconnects == 1 and r.state is DeviceState.READY)
        assert dev.opens == 2 and dev.closes >= 1
        assert any(d.get("state") == "DISCONNECTED" and "cable pulled" in d["reason"] for _, d in events)
        dev.lost = True
        fut = r.submit(lambda d: d.work("y"))
        with pytest.raises(CommandError):
            fut.result(2)
        assert wait_for(lambda: r.state is DeviceState.READY)
        assert r.submit(lambda d: d.work("z")).result(2) == "z"
    finally:
        r.stop()


def test_device_error_keeps_connection(events):
    dev = FlakyDevice()
    r = make(dev, events)
    try:
        assert wait_for(lambda: r.state is DeviceState.READY)

        def bad(d):
            raise DeviceError("reflector not found", code="tracker_NoTargetFound")

        with pytest.raises(CommandError) as err:
            r.submit(bad).result(2)
        assert err.value.code == "tracker_NoTargetFound"
        assert r.state is DeviceState.READY and dev.opens == 1 and r.jobs_failed == 1
    finally:
        r.stop()


def test_jobs_run_in_arrival_order(events):
    dev = FlakyDevice()
    r = make(dev, events)
    try:
        assert wait_for(lambda: r.state is DeviceState.READY)
        gate = threading.Event()
        first = r.submit(lambda d: gate.wait(2) and d.work("first"))
        time.sleep(0.05)
        normal = [r.submit(lambda d, i=i: d.work(f"n{i}")) for i in range(3)]
        gate.set()
        for f in [first, *normal]:
            f.result(2)
        assert dev.log == ["first", "n0", "n1", "n2"]
    finally:
        r.stop()


def test_a_queued_job_wakes_the_device(events):
    """submit() calls the device's wake(), so a device whose pump can be cut short starts the job at once."""
    dev = FlakyDevice()
    woken = []
    dev.wake = lambda: woken.append(True)
    r = make(dev, events)
    try:
        assert wait_for(lambda: r.state is DeviceState.READY)
        assert r.submit(lambda d: d.work("a")).result(5) == "a"
        assert woken
    finally:
        r.stop()
