"""Base protocol version 2: the codec's new messages, v1/v2 negotiation both ways, the STATE command.

Over real pseudo-terminals with the fake base (fakes/robot_base.py), as tests/drivers/test_robot_driver.py.
"""
from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import pytest

from drivers import robot_protocol as rp
from drivers.base import DeviceURL
from drivers.robot import SerialRobot
from fakes.robot import PtyServer
from fakes.robot_base import FakeBase
from fakes.world import World, WorldParams
from tests.drivers.test_robot_driver import RawLink, Sink
from tools.harness.robot import wait_idle

pytestmark = pytest.mark.timeout(30)


def test_state_incl_and_clocked_status_round_trip() -> None:
    s = rp.StateSample(123_456_789_012, 1234.5678, -0.25, -179.5, 99.5, -100.0)
    line = s.encode()
    assert line == (b"$STATE,123456789012,1234.5678,-0.25,-179.5,99.5,-100*"
                    + rp.checksum(line[1:-5]).encode() + b"\r\n")
    assert rp.StateSample.decode(rp.decode(line)) == s
    i = rp.InclSample(7, 0.012345, -1.5)
    assert rp.InclSample.decode(rp.decode(i.encode())) == i
    status = rp.decode(rp.encode("STATUS", 4, "IDLE", 1, 2, 3, None, None, 25.2, "", 987654321))
    assert rp.device_us(status, 9) == 987654321
    # the longest lines stay within the frame limit
    worst = rp.StateSample(10 ** 18, -99999.9999, -99999.9999, -179.999999, -300.0, -300.0).encode()
    assert len(worst) <= rp.MAX_LINE
    for bad in (b"$STATE,-5,0,0,0,0,0", b"$STATE,1.5,0,0,0,0,0", b"$INCL,1,x,0"):
        body = bad[1:].decode()
        with pytest.raises(rp.ProtocolError) as exc:
            msg = rp.decode(f"${body}*{rp.checksum(body)}".encode())
            (rp.StateSample if msg.kind == "STATE" else rp.InclSample).decode(msg)
        assert exc.value.kind == "syntax"
    assert rp.state_rate_error(0) is None and rp.state_rate_error(100) is None
    assert "rate_hz=0.5" in (rp.state_rate_error(0.5) or "")
    assert "rate_hz=101" in (rp.state_rate_error(101) or "")
    assert rp.capabilities("INCL+CLOCK+STATE") == ["INCL", "CLOCK", "STATE"] and rp.capabilities("") == []


@pytest.fixture
def served() -> Iterator[Any]:
    made: list[tuple[PtyServer, SerialRobot]] = []

    def serve(base: FakeBase, query: str = "") -> tuple[SerialRobot, Sink]:
        server = PtyServer(base)
        sink = Sink()
        robot = SerialRobot(DeviceURL.parse(f"serial://{server.path}?state_hz=0{query}"), emit=sink)
        made.append((server, robot))
        robot.open()
        return robot, sink

    yield serve
    for server, robot in made:
        robot.close()
        server.shutdown()


def _base(max_protocol: int = 2, time_scale: float = 0.0) -> FakeBase:
    return FakeBase(World(WorldParams(base_has_inclinometer=True)), time_scale=time_scale,
                    max_protocol=max_protocol)


def test_v2_host_with_a_v1_base_falls_back(served: Any) -> None:
    base = _base(max_protocol=1)
    robot, sink = served(base)
    info = robot.info()
    assert info["protocol"] == 1 and info["capabilities"] == ["INCL"] and info["streams"] == []
    assert base.counters["naks"] == 2  # HELLO,3 and HELLO,2 refused, then HELLO,1
    st = robot.status()
    assert st.t_us is None and st.roll_deg is not None
    robot.move(100.0, 50.0)
    assert wait_idle(robot, 5.0).x_mm == 100.0
    robot.pump(0.2)
    assert not [t for t, _ in sink.items if t in ("robot.odometry", "robot.incl")]


def test_v2_host_with_a_base_that_answers_version_1(served: Any) -> None:
    base = _base(max_protocol=1)
    hello = base._hello
    base._hello = (  # type: ignore[method-assign]
        lambda seq, msg: hello(seq, rp.Message("HELLO", (str(seq), "1"))))
    robot, _ = served(base)
    assert robot.info()["protocol"] == 1 and base.counters["naks"] == 0 and robot.streams() == []
    assert robot.status().t_us is None


def test_v1_host_with_a_v2_base_gets_version_1(served: Any) -> None:
    base = _base()
    robot, sink = served(base, "&protocol=1")
    assert robot.info()["protocol"] == 1 and robot.info()["capabilities"] == ["INCL"]
    assert base.session == 1 and base.streams.state_hz == 0
    assert robot.status().t_us is None
    robot.pump(0.2)
    assert not [t for t, _ in sink.items if t in ("robot.odometry", "robot.incl")]


def test_v2_host_with_a_v2_base_streams_samples(served: Any) -> None:
    base = _base(time_scale=0.02)
    robot, sink = served(base, "&stream_hz=50")
    assert robot.info()["protocol"] == 2 and robot.streams() == ["robot.odometry", "robot.incl"]
    st1 = robot.status()
    robot.move(200.0, 100.0)
    wait_idle(robot, 5.0)
    robot.pump(0.3)
    st2 = robot.status()
    assert st1.t_us is not None and st2.t_us is not None and st2.t_us > st1.t_us
    odo = [p for t, p in sink.items if t == "robot.odometry"]
    incl = [p for t, p in sink.items if t == "robot.incl"]
    t_us = [t for p in odo for t in p["t_us"]]
    assert len(t_us) >= 10 and t_us == sorted(t_us)
    x = [v for p in odo for v in p["x_mm"]]
    # along the move, at its times
    assert x[-1] == 200.0 and x == sorted(x) and any(0 < v < 200 for v in x), x
    # INCL at the inclinometer's 10 Hz of simulated time: every 2 ms of the base's clock here
    ti = [t for p in incl for t in p["t_us"]]
    assert len(ti) >= 50 and all(d == 2000 for d in (b - a for a, b in zip(ti, ti[1:])) if d < 4000)


def test_state_command_range_and_v1_sessions() -> None:
    base = _base()
    server = PtyServer(base)
    link = RawLink(server)
    try:
        msg = rp.decode(link.ask(rp.encode("STATE", 1, 5))[0])
        assert (msg.kind, msg.fields[1]) == ("NAK", "UNKNOWN")  # before HELLO,2 the session is version 1
        msg = rp.decode(link.ask(rp.encode("HELLO", 2, 2))[0])
        assert (msg.kind, msg.fields[1], msg.fields[5]) == ("VERSION", "2", "INCL+CLOCK+STATE")
        msg = rp.decode(link.ask(rp.encode("STATE", 3, 500))[0])
        assert (msg.kind, msg.fields[1]) == ("NAK", "RANGE") and "rate_hz=500" in msg.fields[2]
        msg = rp.decode(link.ask(rp.encode("STATE", 4, 100))[0])
        assert (msg.kind, msg.fields[1]) == ("ACK", "STATE")
        time.sleep(0.1)
        got = link.ask(rp.encode("STATE", 5, 0))
        deadline = time.monotonic() + 2.0
        while b"$ACK,5,STATE" not in b"".join(got) and time.monotonic() < deadline:
            got += link.lines.feed(link.port.read(256))
        kinds = [rp.decode(g).kind for g in got]
        assert {"STATE", "INCL"} <= set(kinds) and kinds[-1] == "ACK", kinds
        time.sleep(0.05)
        link.port.reset_input_buffer()
        msg = rp.decode(link.ask(rp.encode("STATUS", 6))[0])  # the stream is off: the next line is the reply
        assert msg.kind == "STATUS" and len(msg.fields) == 10
    finally:
        link.port.close()
        server.shutdown()


def test_url_options_accept_the_new_ones_and_refuse_typos() -> None:
    r = SerialRobot(DeviceURL.parse("serial:///dev/ttyUSB0?protocol=1&stream_hz=20"))
    assert (r.protocol, r.stream_hz) == (1, 20.0)
    for query, fragment in (("stream_hzz=5", "stream_hzz"), ("stream_hz=500", "stream_hz"),
                            ("protocol=4", "protocol")):
        with pytest.raises(ValueError, match=fragment):
            SerialRobot.check_url(DeviceURL.parse(f"serial:///dev/ttyUSB0?{query}")) if "hzz" in query else \
                SerialRobot(DeviceURL.parse(f"serial:///dev/ttyUSB0?{query}"))


def test_stop_is_answered_through_a_stream_the_host_read_late(served: Any) -> None:
    # the host does not read for a while: samples pile up (and overflow the pty), but the STOP's
    # ACK is never lost behind them and the base stops at once
    base = _base(time_scale=1.0)
    robot, sink = served(base, "&stream_hz=100")
    robot.move(1000.0, 100.0)  # 10 s
    time.sleep(1.0)
    robot.stop()
    deadline = time.monotonic() + 5.0
    while not [p for p in sink.events() if p.get("result") == "STOPPED"] and time.monotonic() < deadline:
        robot.pump(0.05)
    assert [p for p in sink.events() if p.get("result") == "STOPPED"], sink.events()
    assert robot.counters["retries"] == 0 and base.motion is None and base.state == "IDLE"
    assert 50.0 < base.odometry[0] < 400.0, base.odometry
