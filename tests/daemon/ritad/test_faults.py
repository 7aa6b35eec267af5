"""Fault injection on a running daemon: devices lost mid-work come back by themselves.

Each test runs an in-process ``Daemon`` on the simulated world, breaks one device
the way the field breaks it (the tracker's server dies during a measurement, the
camera link drops, the robot's serial port vanishes) and checks that the command in
flight gets a clear error, that the runner reconnects on its own (visible in
``daemon.state`` telemetry and ``daemon.health``) and that the device works again.
"""
from __future__ import annotations

import contextlib
import itertools
import threading
import time
from typing import Any, Callable, Iterator

import pytest

from daemon.bus.client import Client, ClientTimeout, Subscriber
from fakes.operator import lock_on_robot
from daemon.ritad.daemon import Daemon
from daemon.ritad.notify import Notifier
from daemon.bus.protocol import CommandError
from drivers.emscon.enums import ES_Command
from tests.ritad_up import SMALL_CAMERA, ritad_in_process
from tools.harness.load import hang_s



def wait_for(pred: Callable[[], Any], timeout: float, what: str) -> Any:
    end = time.monotonic() + timeout
    while True:
        value = pred()
        if value:
            return value
        assert time.monotonic() < end, f"timed out after {timeout} s waiting for {what}"
        time.sleep(0.02)


@pytest.fixture
def make_daemon(tmp_path) -> Iterator[Callable[..., tuple[Daemon, Client]]]:
    """Start a sim daemon with some device URLs replaced; stopped (and fakes shut down) after the test."""
    count = itertools.count()
    with contextlib.ExitStack() as stack:
        def make(**devices: str) -> tuple[Daemon, Client]:
            return stack.enter_context(ritad_in_process(tmp_path / f"rt{next(count)}", timeout=30, **devices))

        yield make


def live_subscriber(c: Client, device: str) -> Subscriber:
    """A telemetry subscriber proven live: it has seen the BUSY of a ``<device>.status`` job."""
    sub = c.subscriber(["daemon.state", "daemon.health"])

    def probe() -> bool:
        c.call(f"{device}.status")
        while (msg := sub.recv(0.1)) is not None:
            if msg[0] == "daemon.state" and msg[1]["data"]["device"] == device:
                return True
        return False

    wait_for(probe, 10, "the telemetry subscription")
    return sub


def states(sub: Subscriber, device: str, until: str, timeout: float, since_loss: bool = True) -> list[dict[str, Any]]:
    """``daemon.state`` messages of ``device`` from the loss (DISCONNECTED) to the first ``until`` after it.

    With ``since_loss`` false the messages are collected from now on.
    """
    seen: list[dict[str, Any]] = []
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        msg = sub.recv(0.2)
        if msg is None or msg[0] != "daemon.state" or msg[1]["data"]["device"] != device:
            continue
        data = msg[1]["data"]
        if seen or data["state"] == "DISCONNECTED" or not since_loss:
            seen.append(data)
        if seen and data["state"] == until:
            return seen
    raise AssertionError(f"{device} never reached {until} after a loss within {timeout} s; saw {seen}")


def test_tracker_server_killed_mid_measurement(make_daemon) -> None:
    # a 20 s measurement at the fake's time scale 0.05 lasts 1 s: long enough to kill the server under it
    d, c = make_daemon(tracker="sim:?meas_time_ms=20000")
    first = lock_on_robot(c)
    fake = d.rigs.tracker.runner.device.server
    sub = live_subscriber(c, "tracker")
    seen_before = len(fake.server.commands_seen)
    out: dict[str, Any] = {}

    def measure() -> None:
        with Client(d.server.endpoints[0], timeout=30) as c2:  # its own client: one per thread
            try:
                out["result"] = c2.call("tracker.measure")
            except CommandError as exc:
                out["error"] = exc

    t = threading.Thread(target=measure)
    t.start()
    wait_for(lambda: ES_Command.StartMeasurement in fake.server.commands_seen[seen_before:], 10,
             "StartMeasurement at the server")
    time.sleep(0.2)  # in flight: the fake answers only after 1 s
    fake.stop()
    t.join(hang_s(10))
    assert not t.is_alive()
    assert "result" not in out, "the measurement cannot succeed when the server died under it"
    # the loss answered the call, not its 30 s deadline: a deadline raises ClientTimeout ("no answer", code
    # no_answer/timeout), never a device_lost error naming the tracker
    assert not isinstance(out["error"], ClientTimeout) and out["error"].code == "device_lost"
    assert "tracker" in str(out["error"]) and "lost" in str(out["error"])
    down = states(sub, "tracker", "FAULT", 10)  # reconnecting against a dead server fails
    assert [s["state"] for s in down] == ["DISCONNECTED", "CONNECTING", "FAULT"]
    assert down[0]["reconnects"] == 1 and "EOF" in down[0]["reason"]
    assert "refused" in down[-1]["reason"].lower() or "unreachable" in down[-1]["reason"]
    with pytest.raises(CommandError) as not_ready:
        c.call("tracker.measure")
    assert not_ready.value.code == "not_ready"
    fake.start()  # same port, like the controller coming back
    up = states(sub, "tracker", "READY", 40, since_loss=False)
    # every attempt after the loss is a reconnect, the failed ones included (the count shows the retries)
    attempts = [s["reconnects"] for s in down + up if s["state"] == "CONNECTING"]
    assert len(attempts) >= 2 and attempts == list(range(1, len(attempts) + 1)), down + up
    assert up[-1]["reconnects"] == len(attempts)
    h = c.call("status")["devices"]["tracker"]
    assert (h["state"], h["reconnects"], h["opens"]) == ("READY", len(attempts), 2)
    second = lock_on_robot(c)  # the operator re-locks onto the reflector; then it measures again
    assert [round(second[k] - first[k], 1) for k in "xyz"] == [0.0, 0.0, 0.0]
    sub.close()


def test_camera_lost_and_back(make_daemon) -> None:
    d, c = make_daemon(camera=SMALL_CAMERA + "&disconnect_after=2")
    notify = Notifier("")  # a no-op notifier: supervise only for its daemon.health messages
    sup = threading.Thread(target=d.supervise, args=(notify,), daemon=True)
    sup.start()
    sub = live_subscriber(c, "camera")
    before = c.call("camera.status")
    frames = [c.call("camera.capture", save=False)["header"]["frame_id"] for _ in range(2)]
    with pytest.raises(CommandError) as lost:
        c.call("camera.capture", save=False)
    assert lost.value.code == "device_lost" and "disconnect_after=2" in str(lost.value)
    seen = states(sub, "camera", "READY", 10)
    assert [s["state"] for s in seen] == ["DISCONNECTED", "CONNECTING", "READY"]
    assert seen[-1]["reconnects"] == 1
    assert "link lost" in seen[0]["reason"]
    frame = c.call("camera.capture", save=False)["header"]
    assert frame["frame_id"] > frames[-1]
    st = c.call("camera.status")
    assert (before["opens"], before["applies"]) == (1, 1)
    assert (st["opens"], st["applies"], st["disconnects"]) == (2, 2, 1)  # settings re-applied on reopen
    assert st["applied"] == before["applied"]

    def health_shows_reconnect() -> dict[str, Any] | None:
        msg = sub.recv(0.5)
        if msg and msg[0] == "daemon.health" and msg[1]["data"]["devices"]["camera"]["reconnects"] == 1:
            return msg[1]["data"]
        return None

    h = wait_for(health_shows_reconnect, 5, "daemon.health with the camera reconnect")
    assert h["devices"]["camera"]["opens"] == 2 and h["devices"]["camera"]["state"] == "READY"
    assert h["devices"]["tracker"]["reconnects"] == 0 and h["devices"]["robot"]["reconnects"] == 0
    assert h["alive"] is True
    d.stop_event.set()
    sup.join(5)
    sub.close()


def test_serial_port_closed(make_daemon) -> None:
    d, c = make_daemon()
    runner = d.rigs.robot.runner
    sub = live_subscriber(c, "robot")
    before = c.call("robot.status")
    old_server = runner.device.server
    runner.device.drop_port()
    seen = states(sub, "robot", "READY", 15)
    assert seen[0]["state"] == "DISCONNECTED" and "robot port" in seen[0]["reason"]
    assert [s["state"] for s in seen][-2:] == ["CONNECTING", "READY"]
    assert seen[-1]["reconnects"] == 1
    assert not old_server.alive and runner.device.server is not old_server  # a new port was opened
    after = c.call("robot.status")
    assert after["state"] == "IDLE" and after["battery_v"] == pytest.approx(before["battery_v"])
    end = time.monotonic() + 5  # the runner's own status poll shows BUSY for a moment: READY between them
    while (h := c.call("status")["devices"]["robot"])["state"] == "BUSY" and time.monotonic() < end:
        time.sleep(0.05)
    assert (h["state"], h["reconnects"], h["opens"]) == ("READY", 1, 2)
    sub.close()
