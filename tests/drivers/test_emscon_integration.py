"""Client/adapter against the fake AT901 over TCP on 127.0.0.1."""
from __future__ import annotations

import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any
from urllib.parse import parse_qsl

import numpy as np
import pytest

from daemon.ritad.registry import build_device
from drivers.base import DeviceError, DeviceLost, DeviceTimeout, DeviceURL
from drivers.emscon.client import EmsconClient, EmsconStatusError
from drivers.emscon.codec import TO_CLIENT, encode_request
from drivers.emscon.enums import ES_Command as Cmd
from drivers.emscon.enums import ES_ResultStatus as RS
from drivers.emscon.enums import ES_SystemStatusChange as SSC
from drivers.emscon.framer import Framer
from fakes.tracker import FakeTrackerServer, FakeTrackerThread, SimTracker
from fakes.world import NEST_NAMES, World
from fakes.worlds import sim_url

pytestmark = pytest.mark.timeout(60)
ROOT = Path(__file__).resolve().parents[2]
SIGMA = 0.010
FAST = "time_scale=0.01&timeout=5&init_timeout=10&connect_timeout=2"


class Sink:
    """Collects emitted messages."""

    def __init__(self) -> None:
        self.msgs: list[tuple[str, Any]] = []
        self.lock = threading.Lock()

    def __call__(self, topic: str, payload: Any) -> None:
        with self.lock:
            self.msgs.append((topic, payload))

    def topic(self, name: str) -> list[Any]:
        with self.lock:
            return [p for t, p in self.msgs if t == name]


@pytest.fixture
def world() -> World:
    return World()


@pytest.fixture
def make(world: World):
    made: list[SimTracker] = []

    def _make(opts: str = "", sink: Sink | None = None) -> SimTracker:
        merged = dict(parse_qsl(FAST))
        merged.update(parse_qsl(opts))  # the test's options override the fast defaults
        url = sim_url(world, "&".join(f"{k}={v}" for k, v in merged.items()))
        t = SimTracker(url, emit=sink or Sink())
        made.append(t)
        return t

    yield _make
    for t in made:
        t.shutdown()


@pytest.fixture
def server(world: World):
    srv = FakeTrackerThread(FakeTrackerServer(world, time_scale=0.01))
    srv.start(0)
    yield srv
    srv.close()


def lock_on(t: SimTracker, world: World, name: str, offset=(8.0, -6.0, 4.0)) -> np.ndarray:
    truth = world.reflectors_trk()[name]
    t.aim(tuple(truth + np.array(offset)))
    t.find_reflector()
    return truth


def assert_within_5_sigma(p, truth: np.ndarray) -> None:
    err = np.array([p.x, p.y, p.z]) - truth
    assert np.all(np.abs(err) < 5 * SIGMA), f"error {err} mm exceeds 5σ"


def test_registry_builds_sim_tracker(world: World) -> None:
    t = build_device("tracker", sim_url(world, FAST).raw, emit=Sink())
    assert isinstance(t, SimTracker) and t.world is world


def test_init_sequence_and_reconnect_without_reinit(make) -> None:
    t = make()
    t.open()
    seen = [Cmd(c) for c in t.server.server.commands_seen]
    order = [Cmd.SetUnits, Cmd.GetSystemStatus, Cmd.Initialize, Cmd.SetMeasurementMode,
             Cmd.SetStationaryModeParams, Cmd.SetCoordinateSystemType]
    assert [c for c in seen if c in order] == order
    st = t.server.server.model.state
    assert st.initialized and st.units["length_unit"] == 1 and st.units["angle_unit"] == 1
    assert st.settings["send_unsolicited_messages"] == 1
    assert t.info()["tracker_type"] == "AT901_LR"
    t.close()
    t.server.server.commands_seen.clear()
    t.open()  # the tracker stays initialised: no second Initialize
    assert Cmd.Initialize not in t.server.server.commands_seen
    assert Cmd.SetUnits in t.server.server.commands_seen


def test_stationary_measurement_of_robot_reflector(make, world: World) -> None:
    sink = Sink()
    t = make("meas_time_ms=500", sink)
    t.open()
    truth = lock_on(t, world, "robot")
    p = t.measure()
    assert_within_5_sigma(p, truth)
    assert p.std == (SIGMA, SIGMA, SIGMA) and p.tracker_status == "Ready"
    (msg,) = sink.topic("tracker.point")
    assert msg["n"] == 1 and msg["x"] == [p.x] and msg["mode"] == "stationary" and msg["seq"] == 0


@pytest.mark.parametrize("nest", NEST_NAMES)
def test_aim_find_measure_each_nest(make, world: World, nest: str) -> None:
    t = make()
    t.open()
    truth = lock_on(t, world, nest)
    assert_within_5_sigma(t.measure(), truth)
    assert t.server.server.model.state.locked == nest


def test_measurement_follows_moving_robot(make, world: World) -> None:
    t = make()
    t.open()
    lock_on(t, world, "robot")
    r = world.robot
    world.set_robot(type(r)(r.x_mm + 100.0, r.y_mm, r.heading_deg))
    assert_within_5_sigma(t.measure(), world.reflectors_trk()["robot"])


def test_find_with_nothing_near_is_a_named_error(make, world: World) -> None:
    t = make()
    t.open()
    t.aim((1000.0, 1000.0, 1000.0))  # empty direction
    with pytest.raises(EmsconStatusError) as ei:
        t.find_reflector(1500.0)
    assert ei.value.code == "tracker_ModuleTimedOut" and "FindReflector" in str(ei.value)
    with pytest.raises(EmsconStatusError, match="MeasurementStatusNotReady"):
        t.measure()  # nothing locked


def test_not_initialized_and_server_busy(server: FakeTrackerThread) -> None:
    c = EmsconClient("127.0.0.1", server.port, timeout=5)
    c.connect()
    with pytest.raises(EmsconStatusError) as ei:
        c.measure()
    assert ei.value.code == "tracker_TrackerNotInitialized" and ei.value.status == 39
    assert "StartMeasurement" in str(ei.value) and "(39)" in str(ei.value)
    c.close()
    # two requests back to back on a raw socket: the second hits the running Initialize
    with socket.create_connection(("127.0.0.1", server.port), timeout=5) as s:
        s.sendall(encode_request(Cmd.Initialize) + encode_request(Cmd.GetSystemStatus))
        f, got = Framer(TO_CLIENT), []
        while len([p for p in got if p.kind == "answer"]) < 2:
            got += f.feed(s.recv(4096))
        answers = [(p.command, p.status) for p in got if p.kind == "answer"]
        assert answers == [(Cmd.GetSystemStatus, RS.ServerBusy), (Cmd.Initialize, RS.AllOK)]


def test_streaming_rate_and_format(make, world: World) -> None:
    sink = Sink()
    t = make("packet_rate_hz=8", sink)
    t.open()
    truth = lock_on(t, world, "green")
    t.start_stream(200.0)
    assert t.status()["streaming"] and t.status()["rate_hz"] == 200.0
    t0 = time.monotonic()
    while time.monotonic() - t0 < 1.5:
        t.pump(0.05)
    t.stop_stream()
    msgs = sink.topic("tracker.point")
    n = sum(m["n"] for m in msgs)
    assert 6 <= len(msgs) <= 20, f"{len(msgs)} packets in 1.5 s (expect ~8/s)"
    assert 200 <= n <= 400, f"{n} points in 1.5 s at 200 Hz"
    seqs = [m["seq"] for m in msgs]
    assert seqs == [sum(m["n"] for m in msgs[:i]) for i in range(len(msgs))]
    t1, t2 = (np.concatenate([m["device_time"][k] for m in msgs]) for k in (0, 1))
    dt = np.diff(t1 + t2 * 1e-6)
    assert np.allclose(dt, 0.005, atol=2e-6)
    xyz = np.array([np.concatenate([m[k] for m in msgs]) for k in "xyz"]).T
    assert np.all(np.abs(xyz - truth) < 6 * SIGMA)
    assert abs(xyz.std(axis=0).mean() - SIGMA) < 0.3 * SIGMA
    assert all(m["status"] == [0] * m["n"] for m in msgs)
    assert t.status()["counters"]["points"] == n and not t.status()["streaming"]
    assert_within_5_sigma(t.measure(), truth)  # back in stationary mode


def test_stream_without_lock_fails_and_leaves_stationary_mode(make, world: World) -> None:
    t = make()
    t.open()
    with pytest.raises(EmsconStatusError, match="MeasurementStatusNotReady"):
        t.start_stream(100.0)
    assert not t.status()["streaming"]
    truth = lock_on(t, world, "red")
    assert_within_5_sigma(t.measure(), truth)


def test_get_reflectors_collects_every_answer(server: FakeTrackerThread) -> None:
    c = EmsconClient("127.0.0.1", server.port, timeout=5)
    c.connect()
    rows = c.get_reflectors()
    assert [r["name"] for r in rows] == ["RRR 1.5in", "RRR 0.5in", "CatEye"]
    assert [r["reflector_id"] for r in rows] == [0, 1, 2] and rows[0]["total_reflectors"] == 3
    assert c.request(Cmd.GetTrackerStatus)["tracker_status"] == 0  # conversation still in step
    c.close()


def test_kill_mid_measurement_then_reconnect(make, world: World) -> None:
    t = make("meas_time_ms=20000")  # 200 ms at time_scale 0.01
    t.open()
    truth = lock_on(t, world, "blue")
    timer = threading.Timer(0.05, t.server.stop)
    timer.start()
    with pytest.raises(DeviceLost, match="lost"):
        t.measure()
    timer.join()
    t.close()
    with pytest.raises(DeviceLost, match="unreachable"):
        t.open()  # server still down
    port = t.server.port
    assert t.server.restart(reset_state=True) == port
    t.open()  # re-initialises and re-applies units and modes
    assert t.server.server.model.state.initialized
    assert t.server.server.model.state.units["length_unit"] == 1
    truth = lock_on(t, world, "blue")
    assert_within_5_sigma(t.measure(), truth)
    assert t.status()["counters"]["opens"] == 2


@pytest.mark.parametrize("opts,cmd,status", [
    ("fail=GoPosition=NoAdm", Cmd.GoPosition, RS.NoAdm),
    ("fail=StartMeasurement=10014", Cmd.StartMeasurement, RS.SystemNotReadyForMeasurement),
])
def test_error_status_surfaces_by_name(make, world: World, opts: str, cmd: Cmd, status: RS) -> None:
    t = make(opts)
    t.open()
    truth = world.reflectors_trk()["red"]
    with pytest.raises(EmsconStatusError) as ei:
        if cmd == Cmd.GoPosition:
            t.aim(tuple(truth))
        else:
            t.measure()
    assert isinstance(ei.value, DeviceError) and ei.value.code == f"tracker_{status.name}"
    assert ei.value.command == cmd and cmd.name in str(ei.value)


def test_events_delivered_through_pump(make) -> None:
    sink = Sink()
    t = make("", sink)
    t.open()
    before = len(sink.topic("tracker.event"))
    t.server.send_event(SSC.MeasStatus_Busy)
    t.server.send_error(Cmd.StartMeasurement, RS.NoStationaryResult)
    t0 = time.monotonic()
    while len(sink.topic("tracker.event")) < before + 2 and time.monotonic() - t0 < 3:
        t.pump(0.05)
    ev = sink.topic("tracker.event")[before:]
    assert ev[0]["event"] == "status_change" and ev[0]["change_name"] == "MeasStatus_Busy"
    assert ev[1]["event"] == "error" and ev[1]["status_name"] == "NoStationaryResult"
    assert ev[1]["command_name"] == "StartMeasurement"
    assert t.status()["tracker_status"] == "Busy"


@pytest.mark.parametrize("opts", ["split=1", "result_first=1", "delay_ms=20"])
def test_benign_faults_still_work(make, world: World, opts: str) -> None:
    t = make(opts)
    t.open()
    truth = lock_on(t, world, "red")
    assert_within_5_sigma(t.measure(), truth)


def test_delay_beyond_timeout(make) -> None:
    t = make("delay_ms=400&timeout=0.2")
    with pytest.raises(DeviceTimeout, match="SetUnits"):
        t.open()
    t.server.faults.delay_ms = 0
    t.open()
    t.server.faults.delay_ms = 400
    with pytest.raises(DeviceTimeout, match="GoPosition: no answer within 0.2 s"):
        t.aim((1000.0, 0.0, 0.0))
    assert not t.status()["connected"]  # hung up: the late answer must not match a later command
    with pytest.raises(DeviceLost, match="resynchronise"):
        t.pump(0.01)


def test_a_stream_stop_unanswered_in_time_says_why_the_connection_is_gone(make, world: World) -> None:
    """StopMeasurement late (a loaded host): the client hangs up to resynchronise; the stop names that, not
    a bare "connection is closed" from the next command sent on the closed socket."""
    t = make("timeout=0.2")
    t.open()
    lock_on(t, world, "green")
    t.start_stream(100.0)
    t.pump(0.05)
    t.server.faults.delay_ms = 400
    with pytest.raises(DeviceLost, match="StopMeasurement: no answer within 0.2 s; connection closed to re"):
        t.stop_stream()
    assert not t.status()["connected"]


@pytest.mark.parametrize("opts,match", [("garbage_after=3", "protocol error"),
                                        ("drop_after=3", "EOF|reset|lost")])
def test_fatal_faults_are_device_lost(make, opts: str, match: str) -> None:
    t = make(opts)
    with pytest.raises(DeviceLost, match=match):
        t.open()
    if "garbage" in opts:
        assert t.status()["counters"]["protocol_errors"] == 1
    t.server.faults.garbage_after = t.server.faults.drop_after = 0
    t.open()  # healthy again once the fault is gone
    assert t.status()["connected"]


def test_reflector_option_selects_by_name(make) -> None:
    t = make("reflector=RRR 0.5in")
    t.open()
    assert t.server.server.model.state.reflector_id == 1
    bad = make("reflector=nope")
    with pytest.raises(DeviceError, match="nope"):
        bad.open()


def test_sigma_option_and_bad_sim_options(make, world: World) -> None:
    t = make("sigma_mm=0")
    t.open()
    truth = lock_on(t, world, "green")
    m = t.measure()
    assert np.allclose([m.x, m.y, m.z], truth, atol=1e-9)  # noise-free: exactly the world's truth
    with pytest.raises(ValueError, match="fail='GoPosition'"):
        make("fail=GoPosition")
    with pytest.raises(ValueError, match="split='maybe'"):
        make("split=maybe")


def test_url_errors() -> None:
    from drivers.emscon.adapter import EmsconTracker

    with pytest.raises(ValueError, match="no host"):
        EmsconTracker(DeviceURL.parse("emscon:")).endpoint()
    with pytest.raises(ValueError, match="timeout='soon'"):
        EmsconTracker(DeviceURL.parse("emscon://10.0.0.1?timeout=soon"))
    with pytest.raises(ValueError, match="temperature_c"):
        EmsconTracker(DeviceURL.parse("emscon://10.0.0.1?temperature_c=20"))
    assert EmsconTracker(DeviceURL.parse("emscon://10.0.0.1")).endpoint() == ("10.0.0.1", 700)
    with pytest.raises(ValueError, match="rate_hz"):
        EmsconTracker(DeviceURL.parse("emscon://10.0.0.1")).start_stream(0)


def test_cli_serves_until_killed() -> None:
    proc = subprocess.Popen([sys.executable, "-m", "fakes.tracker", "--host", "127.0.0.1", "--port", "0",
                             "--time-scale", "0.01"], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()  # type: ignore[union-attr]
        assert line.startswith("port ")
        c = EmsconClient("127.0.0.1", int(line.split()[1]), timeout=5)
        c.connect()
        st = c.request(Cmd.GetSystemStatus)
        assert st["tracker_serial_number"] == 901001 and st["major_version"] == 3
        c.close()
    finally:
        proc.kill()
        proc.wait(5)
