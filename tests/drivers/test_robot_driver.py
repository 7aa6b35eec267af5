"""SerialRobot against the fake base over real pseudo-terminals (and one TCP socket)."""
from __future__ import annotations

import math
import os
import select
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import serial

from daemon.ritad.registry import adapter_class
from drivers import robot_protocol as rp
from drivers.base import DeviceError, DeviceLost, DeviceURL
from drivers.robot import SerialRobot
from fakes.robot import PtyServer, SimRobot
from fakes.robot_base import FakeBase
from fakes.world import World, WorldParams
from fakes.worlds import sim_url
from tools.harness.robot import wait_idle

pytestmark = pytest.mark.timeout(30)
REPO = Path(__file__).resolve().parents[2]


class Sink:
    """Collects what the adapter emits."""

    def __init__(self) -> None:
        self.items: list[tuple[str, Any]] = []

    def __call__(self, topic: str, payload: Any) -> None:
        self.items.append((topic, payload))

    def events(self) -> list[dict[str, Any]]:
        return [p for t, p in self.items if t == "robot.event"]


@pytest.fixture
def make_robot() -> Iterator[Any]:
    made: list[SimRobot] = []

    def make(query: str = "time_scale=0", **params: Any) -> tuple[SimRobot, Sink]:
        sink = Sink()
        world = World(WorldParams(start_pose=(3000.0, 3000.0, 30.0)).with_(**params))
        robot = SimRobot(sim_url(world, query), emit=sink)
        made.append(robot)
        robot.open()
        return robot, sink

    yield make
    for r in made:
        r.shutdown()


def test_handshake_reports_the_base_and_its_capabilities(make_robot: Any) -> None:
    robot, _ = make_robot()
    info = robot.info()
    assert info["protocol"] == rp.PROTOCOL_VERSION and info["model"] == "RITA-SIM-BASE"
    assert info["capabilities"] == ["CLOCK", "STATE", "WATCHDOG"] and info["port"].startswith("/dev/")
    assert info["streams"] == ["robot.odometry"]  # no inclinometer: no INCL stream
    robot2, _ = make_robot(base_has_inclinometer=True)
    assert robot2.info()["capabilities"] == ["INCL", "CLOCK", "STATE", "WATCHDOG"]
    assert robot2.info()["streams"] == ["robot.odometry", "robot.incl"]


def test_move_turn_status_round_trip(make_robot: Any) -> None:
    robot, sink = make_robot()
    st = robot.status()
    assert (st.state, st.x_mm, st.y_mm, st.heading_deg) == ("IDLE", 0.0, 0.0, 0.0)
    assert st.battery_v is not None and st.battery_v > 20
    robot.move(200.0, 100.0)
    st = wait_idle(robot, 5.0)
    assert (st.state, st.x_mm, st.y_mm) == ("IDLE", 200.0, 0.0)
    robot.turn(90.0, 45.0)
    st = wait_idle(robot, 5.0)
    assert st.heading_deg == 90.0
    robot.move(-50.0, 100.0)
    st = wait_idle(robot, 5.0)
    assert st.x_mm == 200.0 and st.y_mm == -50.0
    events = sink.events()
    assert [e["event"] for e in events] == ["DONE"] * 3
    assert [e["result"] for e in events] == ["OK"] * 3
    assert len({e["seq"] for e in events}) == 3
    assert events[-1]["y_mm"] == -50.0


def test_move_while_moving_is_refused_busy_and_stop_stops_early(make_robot: Any) -> None:
    robot, sink = make_robot("time_scale=0.2")  # 200 mm at 50 mm/s: 0.8 s
    x0 = robot.world.robot.x_mm
    robot.move(200.0, 50.0)
    with pytest.raises(DeviceError, match="BUSY") as info:
        robot.move(10.0, 50.0)
    assert info.value.code == "robot_busy"
    robot.pump(0.1)
    assert robot.status().state == "MOVING"
    robot.stop()
    st = wait_idle(robot, 5.0)
    travelled = math.dist((x0, 3000.0), (robot.world.robot.x_mm, robot.world.robot.y_mm))
    assert 1.0 < travelled < 190.0  # truth moved, but less than commanded
    assert st.x_mm == pytest.approx(travelled, abs=1e-3)  # zero drive errors: odometry = truth
    done = sink.events()[-1]
    assert done["event"] == "DONE" and done["result"] == "STOPPED"
    robot.move(10.0, 50.0)  # accepted again once stopped
    assert wait_idle(robot, 5.0).state == "IDLE"


def test_driver_checks_limits_before_sending(make_robot: Any) -> None:
    robot, _ = make_robot()
    sent = robot.fake.counters["rx_lines"]
    for args, name in (((6000.0, 50.0), "distance_mm=6000"), ((10.0, 0.0), "speed_mm_s=0"),
                       ((float("nan"), 10.0), "distance_mm=nan")):
        with pytest.raises(DeviceError, match=name) as info:
            robot.move(*args)
        assert info.value.code == "robot_range"
    with pytest.raises(DeviceError, match="speed_deg_s=500"):
        robot.turn(10.0, 500.0)
    assert robot.fake.counters["rx_lines"] == sent


def test_fault_event_latches_until_stop(make_robot: Any) -> None:
    robot, sink = make_robot("time_scale=0&fault_rate=1")
    robot.move(100.0, 50.0)
    with pytest.raises(DeviceError, match="FAULT: STALL") as info:
        wait_idle(robot, 5.0)
    assert info.value.code == "robot_fault"
    assert sink.events()[-1]["event"] == "FAULT" and sink.events()[-1]["reason"] == "STALL"
    assert 20.0 <= robot.status().x_mm <= 80.0  # stalled part-way
    with pytest.raises(DeviceError, match="FAULT") as info:
        robot.turn(10.0, 10.0)
    assert info.value.code == "robot_fault"
    robot.stop()
    assert robot.status().state == "IDLE"


class RawLink:
    """Talks protocol lines straight to a PtyServer, bypassing the driver."""

    def __init__(self, server: PtyServer) -> None:
        self.port = serial.serial_for_url(server.path, baudrate=115200, timeout=0.05)
        self.lines = rp.LineSplitter()

    def ask(self, line: bytes, count: int = 1, timeout: float = 2.0) -> list[bytes]:
        self.port.write(line)
        got: list[bytes] = []
        deadline = time.monotonic() + timeout
        while len(got) < count and time.monotonic() < deadline:
            got += self.lines.feed(self.port.read(256))
        assert len(got) >= count, f"no reply to {line!r} in {timeout} s (got {got!r})"
        return got


@pytest.fixture
def raw() -> Iterator[tuple[RawLink, FakeBase]]:
    base = FakeBase(World(WorldParams(start_pose=(0.0, 0.0, 0.0))), time_scale=0.0)
    server = PtyServer(base)
    link = RawLink(server)
    yield link, base
    link.port.close()
    server.shutdown()


def test_controller_naks_bad_checksum_unknown_and_malformed_commands(raw: Any) -> None:
    link, base = raw
    good = rp.encode("MOVE", 5, 100, 50)
    bad = good.replace(good[-4:-2], b"00" if good[-4:-2] != b"00" else b"11")
    (nak,) = link.ask(bad)
    msg = rp.decode(nak)
    assert (msg.kind, msg.seq(), msg.fields[1]) == ("NAK", None, "CHECKSUM")
    assert base.counters["bad_checksum"] == 1 and base.odometry == (0.0, 0.0, 0.0)
    msg = rp.decode(link.ask(rp.encode("JUMP", 6, 1))[0])
    assert (msg.kind, msg.seq(), msg.fields[1]) == ("NAK", 6, "UNKNOWN")
    msg = rp.decode(link.ask(rp.encode("MOVE", 7, "far", 50))[0])
    assert (msg.fields[1], "distance_mm='far'" in msg.fields[2]) == ("SYNTAX", True)
    msg = rp.decode(link.ask(rp.encode("MOVE", 8, 9999, 50))[0])
    assert msg.fields[1] == "RANGE"
    msg = rp.decode(link.ask(rp.encode("HELLO", 9, 4))[0])
    assert (msg.kind, msg.fields[1]) == ("NAK", "VERSION")
    # line noise is dropped silently, and the next good line is still understood
    link.port.write(b"\x00\x13garbage\r\n")
    msg = rp.decode(link.ask(rp.encode("STATUS", 10))[0])
    assert msg.kind == "STATUS" and msg.seq() == 10
    assert base.counters["garbage"] == 1


def test_controller_busy_duplicate_and_stop(raw: Any) -> None:
    link, base = raw
    base.time_scale = 1.0  # 100 mm at 10 mm/s: 10 s, far longer than this test
    move = rp.encode("MOVE", 11, 100, 10)
    assert rp.decode(link.ask(move)[0]).kind == "ACK"
    msg = rp.decode(link.ask(rp.encode("TURN", 12, 10, 10))[0])
    assert (msg.kind, msg.seq(), msg.fields[1]) == ("NAK", 12, "BUSY")
    # the same MOVE again (a host retry) repeats the ACK instead of refusing or re-running it
    t0 = base.motion.t0
    assert link.ask(move)[0] == rp.encode("ACK", 11, "MOVE").rstrip()
    assert base.counters["duplicates"] == 1 and base.motion.t0 == t0
    ack, done = link.ask(rp.encode("STOP", 13), count=2)
    assert rp.decode(ack).fields == ("13", "STOP")
    assert rp.decode(done).kind == "DONE" and rp.decode(done).fields[:2] == ("11", "STOPPED")
    assert rp.decode(link.ask(rp.encode("STOP", 14))[0]).kind == "ACK"  # STOP while idle: fine


def test_garbage_and_corrupted_lines_are_counted_and_survived(make_robot: Any) -> None:
    robot, sink = make_robot("time_scale=0&garbage_rate=0.3&corrupt_rate=0.15&timeout=0.1&retries=6")
    robot.inject_garbage(40)
    total = 0.0
    for i in range(12):
        robot.move(10.0 + i, 100.0)
        total += 10.0 + i
        wait_idle(robot, 5.0)
    for _ in range(20):
        assert robot.status().state == "IDLE"
    c = robot.info()["counters"]
    assert c["garbage"] >= 1 and c["bad_checksum"] >= 1 and c["retries"] >= 1
    # every corrupted ACK was retried with the same seq: no MOVE ran twice
    assert robot.status().x_mm == pytest.approx(total, abs=1e-3)
    # one DONE per move, even where the DONE line itself was corrupted (then recovered)
    events = sink.events()
    assert [e["event"] for e in events] == ["DONE"] * 12
    assert len({e["seq"] for e in events}) == 12
    assert c["events"] + c["recovered_events"] == 12


def test_lost_port_raises_device_lost_and_reopen_recovers(make_robot: Any) -> None:
    robot, _ = make_robot()
    robot.move(100.0, 100.0)
    wait_idle(robot, 5.0)
    robot.drop_port()
    with pytest.raises(DeviceLost):
        robot.status()
    robot.close()
    robot.close()  # twice is fine
    robot.open()  # a fresh pty, same (still powered) base
    assert robot.status().x_mm == 100.0


def test_motion_finished_while_disconnected_still_reports_done(make_robot: Any) -> None:
    robot, sink = make_robot("time_scale=0.1")  # 100 mm at 100 mm/s: 0.1 s
    robot.move(100.0, 100.0)
    robot.drop_port()
    with pytest.raises(DeviceLost):
        robot.pump(0.05)
    robot.close()
    time.sleep(0.15)  # the base finishes while nobody listens; its DONE is lost
    robot.open()
    assert robot.status().state == "IDLE"
    done = sink.events()[-1]
    assert done["event"] == "DONE" and done["recovered"] is True and done["x_mm"] == 100.0
    assert robot.info()["counters"]["recovered_events"] == 1


@pytest.mark.parametrize("protocol", [2, 3])
def test_a_motion_started_by_an_earlier_session_is_halted_once(protocol: int) -> None:
    base = FakeBase(World(WorldParams(start_pose=(0.0, 0.0, 0.0))), time_scale=1.0)
    server = PtyServer(base)
    url = DeviceURL.parse(f"serial://{server.path}?state_hz=0&protocol={protocol}&host_timeout=5")
    first, sink = SerialRobot(url), Sink()
    second = SerialRobot(url, emit=sink)
    try:
        first.open()
        first.move(1000.0, 100.0)  # 10 s of motion nobody owns once ``first`` is gone
        first.close()
        second.open()  # the base is still moving (within its long host timeout): not this session's motion
        assert wait_idle(second, 5.0).x_mm < 100.0
        events = sink.events()
        assert [e["event"] for e in events] == ["HALTED", "DONE"]
        assert events[0]["reason"] == "unowned_motion" and events[1]["result"] == "STOPPED"
    finally:
        second.close()
        server.shutdown()


def test_silent_base_is_declared_lost_within_the_timeouts(make_robot: Any) -> None:
    robot, _ = make_robot("time_scale=0&timeout=0.1&retries=1")
    robot.set_line_faults(silent=True)
    t0 = time.monotonic()
    with pytest.raises(DeviceLost, match=r"did not answer STATUS .* 2 tries of 0.1 s"):
        robot.status()  # the two 0.1 s tries ended it, as the message says (how soon: bench/bench_robot.py)
    assert time.monotonic() - t0 >= 0.2 and robot.info()["counters"]["retries"] >= 1
    with pytest.raises(DeviceLost):
        robot.open()  # the handshake times out too
    robot.set_line_faults(silent=False)
    robot.open()
    assert robot.status().state == "IDLE"


def test_pump_publishes_state_at_the_configured_rate(make_robot: Any) -> None:
    robot, sink = make_robot("time_scale=0&state_hz=20")
    sink.items.clear()
    robot.pump(0.5)
    states = [p for t, p in sink.items if t == "robot.state"]
    assert 2 <= len(states) <= 11
    assert set(states[0]) >= {"state", "x_mm", "y_mm", "heading_deg", "battery_v"}
    robot2, sink2 = make_robot("time_scale=0&state_hz=0&stream_hz=0")
    sink2.items.clear()
    robot2.pump(0.2)
    assert sink2.items == []


def test_url_options_are_checked() -> None:
    with pytest.raises(ValueError, match="timeout='soon'"):
        SerialRobot(DeviceURL.parse("serial:///dev/ttyUSB0?timeout=soon"))
    with pytest.raises(ValueError, match="state_hz=-1"):
        SerialRobot(DeviceURL.parse("serial:///dev/ttyUSB0?state_hz=-1"))
    with pytest.raises(ValueError, match="unknown option.*parity"):
        SerialRobot(DeviceURL.parse("serial:///dev/ttyUSB0?parity=E"))
    with pytest.raises(ValueError, match="unknown option.*speed"):
        SimRobot(DeviceURL.parse("sim:?speed=3"))
    with pytest.raises(ValueError, match="names no device path"):
        SerialRobot(DeviceURL.parse("serial:?baudrate=9600"))
    r = SerialRobot(DeviceURL.parse("socket://127.0.0.1:7000?state_hz=5&logging=debug"))
    assert r.port_target() == "socket://127.0.0.1:7000?logging=debug" and r.state_hz == 5.0
    assert SerialRobot(DeviceURL.parse("serial:///dev/ttyUSB3?baudrate=9600")).port_target() == "/dev/ttyUSB3"
    assert adapter_class("robot", DeviceURL.parse("serial:///dev/x")) is SerialRobot
    assert adapter_class("robot", DeviceURL.parse("sim:")) is SimRobot


def test_loop_url_hears_only_its_own_commands_and_gives_up() -> None:
    robot = SerialRobot(DeviceURL.parse("loop://?timeout=0.05&retries=1&boot=0"))  # no boot window: 2 tries
    assert robot.port_target() == "loop://"
    with pytest.raises(DeviceLost, match="did not answer HELLO"):
        robot.open()
    assert robot.counters["unexpected"] == 2 and robot.counters["retries"] == 1
    robot.close()


def test_missing_port_is_device_lost() -> None:
    robot = SerialRobot(DeviceURL.parse("serial:///dev/rita-no-such-port"))
    with pytest.raises(DeviceLost, match="rita-no-such-port"):
        robot.open()
    with pytest.raises(DeviceLost, match="not open"):
        robot.status()


def test_cli_fake_serves_a_serial_url() -> None:
    proc = subprocess.Popen([sys.executable, "-m", "fakes.robot", "--seed", "3", "--time-scale", "0",
                             "--param", "drive_scale_error=0.01"],
                            cwd=REPO, stdout=subprocess.PIPE, text=True)
    try:
        ready, _, _ = select.select([proc.stdout], [], [], 10.0)
        assert ready, "fake robot printed no device path within 10 s"
        path = proc.stdout.readline().strip()  # type: ignore[union-attr]
        assert path.startswith("/dev/") and os.path.exists(path)
        robot = SerialRobot(DeviceURL.parse(f"serial://{path}?baudrate=115200&timeout=0.2&retries=1"))
        robot.open()
        robot.move(100.0, 100.0)
        assert wait_idle(robot, 5.0).x_mm == 100.0  # odometry: the commanded motion
        proc.terminate()
        proc.wait(timeout=10)
        with pytest.raises(DeviceLost):
            robot.status()
        robot.close()
    finally:
        proc.kill()
        proc.wait(timeout=10)
        if proc.stdout:
            proc.stdout.close()


def test_socket_url_reaches_a_base_over_tcp() -> None:
    base = FakeBase(World(WorldParams(start_pose=(0.0, 0.0, 0.0))), time_scale=0.0)
    listener = socket.create_server(("127.0.0.1", 0))
    stop = threading.Event()

    def serve() -> None:
        conn, _ = listener.accept()
        conn.settimeout(0.05)
        lines = rp.LineSplitter()
        with conn:
            while not stop.is_set():
                try:
                    data = conn.recv(4096)
                except TimeoutError:
                    continue
                if not data:
                    return
                for line in lines.feed(data):
                    base.handle_line(line)
                conn.sendall(b"".join(base.drain()))

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    port = listener.getsockname()[1]
    robot = SerialRobot(DeviceURL.parse(f"socket://127.0.0.1:{port}?state_hz=0&timeout=0.5"))
    try:
        robot.open()
        robot.turn(-30.0, 30.0)
        assert wait_idle(robot, 5.0).heading_deg == -30.0
        assert base.world.robot.heading_deg == -30.0
    finally:
        robot.close()
        stop.set()
        thread.join(timeout=5)
        listener.close()


def test_stray_replies_read_with_the_awaited_reply_are_counted_not_lost():
    """The awaited reply and a stale one arrive in one read: the stale one is counted at once."""
    from fakes.world import World
    from fakes.worlds import sim_url

    world = World()
    robot = SimRobot(sim_url(world, "state_hz=0&timeout=0.3"))
    robot.open()
    try:
        seq = rp.next_seq(robot._seq)  # the STATUS the next status() sends
        chunk = rp.encode("STATUS", seq, "IDLE", 0.0, 0.0, 0.0) + rp.encode("ACK", 4242)
        os.write(robot.server.master, chunk)
        before = robot.counters["stale"]
        assert robot.status().state == "IDLE"
        assert robot.counters["stale"] - before >= 1  # before the fix the ACK was dropped uncounted
    finally:
        robot.shutdown()
