"""The robot's motion gate at the line level: what the base receives, in which order, when a STOP comes.

Over real pseudo-terminals with the fake base at real-time speed (fakes/robot_base.py): the base records
every line it handles, so each test asserts the order on the wire (STOP before anything after HELLO, a
STOP ahead of a pending command, no motion line after a latch) and whether the base moves, not times.
"""
from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator
from concurrent.futures import Future
from typing import Any

import pytest

from drivers import robot_protocol as rp
from drivers.base import DeviceError, DeviceLost, DeviceURL
from drivers.motion_gate import MotionGate
from drivers.robot import SerialRobot
from fakes.robot import PtyServer
from fakes.robot_base import FakeBase
from fakes.robot_motion import fraction_at
from fakes.world import World, WorldParams

pytestmark = pytest.mark.timeout(60)


class Rig:
    """A fake base that records the kinds of the lines it handled, and a driver on its pty."""

    def __init__(self, protocol: int = 3, query: str = "", latched: bool = False) -> None:
        self.base = FakeBase(World(WorldParams(seed=1, start_pose=(0.0, 0.0, 0.0))), time_scale=1.0,
                             max_protocol=protocol)
        self.heard: list[str] = []
        handle = self.base.handle_line
        self.drop: Any = lambda line: False  # a line the "cable" loses on its way to the base

        def recording(line: bytes) -> None:
            if self.drop(line):
                return
            self.heard.append(line.split(b",", 1)[0].lstrip(b"$").decode(errors="replace"))
            handle(line)

        self.base.handle_line = recording  # type: ignore[method-assign]
        self.server = PtyServer(self.base)
        self.gate = MotionGate(latched=latched)
        self.robot = SerialRobot(DeviceURL.parse(f"serial://{self.server.path}?state_hz=0&stream_hz=0{query}"),
                                 settings=self.gate)

    def moving(self) -> bool:
        with self.base._lock:
            self.base.tick()
            return self.base.moving

    def pump_for(self, seconds: float) -> None:
        """What ritad's owner thread does between jobs."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.robot.pump(0.02)


@pytest.fixture
def rig() -> Iterator[Any]:
    made: list[Rig] = []

    def make(**kw: Any) -> Rig:
        made.append(Rig(**kw))
        return made[-1]

    yield make
    for r in made:
        r.robot.close()
        r.server.shutdown()


def test_the_gate_counts_requests_and_answers_each_once_acknowledged() -> None:
    gate, woken = MotionGate(), []
    gate.bind(lambda: woken.append(1))
    assert not gate.latched and gate.halt_due() is None
    first = gate.engage()
    second = gate.engage()
    assert gate.latched and gate.halt_due() == 2 and len(woken) == 2
    gate.halted(1)  # a STOP written for the first request only
    assert first.result(timeout=1) is True and not second.done() and gate.pending
    gate.release()
    assert not gate.latched and gate.pending  # released, but the halt is still owed to the base
    gate.halted(2)
    assert second.done() and not gate.pending
    restarted = MotionGate(latched=True)  # a latch file read at start owes the base a halt
    assert restarted.latched and restarted.halt_due() == 1


def test_while_latched_stop_is_the_first_command_after_hello(rig: Any) -> None:
    r = rig(latched=True)
    r.robot.open()
    hello = r.heard.index("HELLO")
    assert r.heard[hello + 1] == "STOP" and set(r.heard[:hello]) <= {"STOP"}, r.heard  # (a blind one first)
    assert not r.gate.pending
    r.robot.close()
    r.heard.clear()
    r.robot.open()  # every reconnect while latched, not only the first (nothing owed now: no blind STOP)
    assert r.heard[:2] == ["HELLO", "STOP"], r.heard
    with pytest.raises(DeviceError) as exc:
        r.robot.move(100.0, 100.0)
    assert exc.value.code == "stopped" and "MOVE" not in r.heard


def test_a_stop_goes_ahead_of_a_pending_command_and_is_answered(rig: Any) -> None:
    r = rig(protocol=2)
    r.robot.open()
    r.robot.move(2000.0, 100.0)
    r.drop = lambda line: line.startswith(b"$STATUS")  # the base never hears the poll: its reply never comes
    done: list[BaseException | None] = []
    poll = threading.Thread(target=lambda: _catch(r.robot.status, done))
    poll.start()
    time.sleep(0.1)  # the poll waits for its reply (shapes the scenario; nothing is timed)
    halted = r.gate.engage()  # what robot.stop does in ritad's command thread
    poll.join(timeout=10)
    assert halted.result(timeout=1) is True  # answered while the poll still waited
    assert not r.moving() and "STOP" in r.heard
    assert isinstance(done[0], DeviceLost)  # the poll itself still failed on its own terms


def _catch(fn: Any, out: list[BaseException | None]) -> None:
    try:
        fn()
        out.append(None)
    except BaseException as exc:  # noqa: BLE001 - handed to the test
        out.append(exc)


@pytest.mark.parametrize("protocol", [2, 3])
def test_a_resent_motion_line_is_not_written_once_the_stop_is_latched(rig: Any, protocol: int) -> None:
    r = rig(protocol=protocol)
    r.robot.open()
    lost: list[bytes] = []
    r.drop = lambda line: line.startswith(b"$MOVE") and not lost and not lost.append(line)  # the first MOVE
    got: list[BaseException | None] = []
    mover = threading.Thread(target=lambda: _catch(lambda: r.robot.move(1000.0, 100.0), got))
    mover.start()
    time.sleep(0.1)  # the driver waits for the ACK of a MOVE the base never heard
    halted = r.gate.engage()
    mover.join(timeout=10)
    assert isinstance(got[0], DeviceError) and got[0].code == "stopped"  # the resend was refused
    assert halted.result(timeout=5) is True
    r.pump_for(0.5)
    assert not r.moving() and r.heard.count("MOVE") == 0, r.heard


def test_a_stop_between_the_motions_gate_check_and_its_line_still_halts_the_base(rig: Any) -> None:
    r = rig()
    r.robot.open()
    transact, futs = r.robot._transact, []

    def racing(kind: str, *fields: object, expect: str) -> Any:
        if kind == "MOVE" and not futs:  # the command thread's STOP lands right here
            futs.append(r.gate.engage())
        return transact(kind, *fields, expect=expect)

    r.robot._transact = racing  # type: ignore[method-assign]
    with pytest.raises(DeviceError) as exc:
        r.robot.move(1000.0, 100.0)
    assert exc.value.code == "stopped"
    r.pump_for(0.3)
    assert futs[0].done() and not r.moving() and "MOVE" not in r.heard


def test_one_lost_reply_during_a_motion_does_not_trip_the_host_watchdog(rig: Any) -> None:
    r = rig(protocol=3)
    r.robot.open()
    r.robot.move(2000.0, 100.0)
    r.pump_for(0.3)
    status, lost = r.base._status, []

    def reply_lost(seq: int, msg: rp.Message) -> None:
        if not lost:  # the base hears the poll; its reply is lost on the line
            lost.append(seq)
            return
        status(seq, msg)

    r.base._status = reply_lost  # type: ignore[method-assign]
    r.robot.state_hz = 20.0  # polls due: one of them loses its reply and is resent after its timeout
    r.pump_for(1.5)
    assert lost and r.moving() and r.base.fault == ""


def test_the_fake_base_halts_at_its_timer_on_a_virtual_clock() -> None:
    now = [0.0]
    base = FakeBase(World(WorldParams(seed=1, start_pose=(0.0, 0.0, 0.0))), time_scale=1.0,
                    clock=lambda: now[0], max_protocol=3)
    base.handle_line(rp.encode("HELLO", 1, 3, 300).strip())
    base.handle_line(rp.encode("MOVE", 2, 1000, 100).strip())
    motion = base.motion
    assert motion is not None
    now[0] = 0.2
    base.handle_line(rp.encode("STATUS", 3).strip())  # heard at 0.2: the timer runs to 0.5
    now[0] = 0.45
    base.tick()
    assert base.moving
    now[0] = 0.7  # the base ticked late: it halted at its timer all the same
    base.tick()
    assert not base.moving and base.fault == rp.FAULT_HOST_LOST
    assert base.odometry[0] == pytest.approx(1000.0 * fraction_at(motion, 0.5))  # 50 mm, not 70


def test_halt_reply_waits_for_the_acknowledgement_or_says_it_is_owed() -> None:
    from daemon.ritad.commands import halt_reply
    from daemon.ritad.timeouts import Timeouts

    timeouts = Timeouts()
    halted, persisted = Future(), Future()
    persisted.set_result(None)
    reply = halt_reply(halted, persisted, ["exp-1"], wait_s=30.0, timeouts=timeouts)
    assert not reply.done()
    halted.set_result(True)
    assert reply.result(timeout=1) == {"stopped": True, "latched": True, "jobs_stopped": ["exp-1"]}
    owed = halt_reply(Future(), persisted, [], wait_s=0.05, timeouts=timeouts)
    got = owed.result(timeout=10)
    assert got["stopped"] is False and got["latched"] is True
    assert "as soon as the base answers" in got["message"]


def test_a_fake_thread_late_between_its_read_and_its_tick_does_not_trip_the_host_watchdog() -> None:
    """The pty server stalls after a read, before its tick (a loaded test machine), while the host writes
    on time: those lines arrived within the host timeout, so the base drives on (a UART's receive interrupt
    would have taken them); once the host really goes quiet, the base halts with HOST_LOST all the same."""
    base = FakeBase(World(WorldParams(seed=1, start_pose=(0.0, 0.0, 0.0))), time_scale=1.0, max_protocol=3)
    tick, stalls, stalled, resumed = base.tick, [1], threading.Event(), threading.Event()

    def late_tick() -> None:
        if base.moving and stalls:
            stalls.pop()
            stalled.set()
            time.sleep(0.45)  # 1.5 host timeouts between the server's read and this tick
            tick()
            resumed.set()
        tick()

    base.tick = late_tick  # type: ignore[method-assign]
    server = PtyServer(base)
    host = os.open(server.path, os.O_RDWR | os.O_NOCTTY)
    try:
        os.write(host, rp.encode("HELLO", 1, 3, 300) + rp.encode("MOVE", 2, 2000, 100))
        assert stalled.wait(10)
        for seq in range(3, 9):  # a keep-alive every 0.1 s, as the driver writes them
            os.write(host, rp.encode("STATUS", seq))
            time.sleep(0.1)
        assert resumed.wait(10) and base.moving and base.fault == "", base.fault
        t_quiet = time.monotonic()
        end = t_quiet + 10
        while base.moving and time.monotonic() < end:
            time.sleep(0.01)
        assert base.fault == rp.FAULT_HOST_LOST and base.last_halt - t_quiet <= 0.3 + 0.1
    finally:
        os.close(host)
        server.shutdown()
