"""A STOP during ``robot.commission``'s conformance kit reaches the base at once and aborts the kit.

The kit runs on the robot's owner thread with its own line to the base (daemon/ritad/commission.py); the
operator's STOP engages the robot's motion gate meanwhile (drivers/motion_gate.py). Here the owner thread
is the test's own thread running ``run_on_port`` on a driver with that gate, over a real pty to the fake
base at real-time speed (fakes/robot_base.py, tests/drivers/test_robot_conformance_stop.py's Base),
which records each line it handles: the tests assert what the base heard, in which order, and whether
it still moves, not how fast.
"""
from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest

from daemon.ritad.commission import KIT_CHECKS, run_on_port
from drivers.base import DeviceError, DeviceURL
from drivers.motion_gate import MotionGate
from drivers.robot import SerialRobot
from drivers.robot_conformance_link import STOPPED
from tests.drivers.test_robot_conformance_stop import Base
from tools.harness.stop_rig import wait_for

pytestmark = pytest.mark.timeout(90)

#: the driver's reply timeout: it only catches a hang on a loaded machine
HANG_S = 2.0


@pytest.fixture
def base() -> Iterator[Base]:
    b = Base()
    yield b
    b.server.shutdown()


def driver(base: Base, gate: MotionGate) -> SerialRobot:
    """ritad's driver of ``base`` with ``gate``, opened (no polls or streams: only the kit's lines)."""
    url = f"serial://{base.server.path}?state_hz=0&stream_hz=0&timeout={HANG_S:g}"
    robot = SerialRobot(DeviceURL.parse(url), settings=gate)
    robot.open()
    return robot


def commission_in_thread(robot: SerialRobot, out: dict[str, Any]) -> threading.Thread:
    """``run_on_port`` as the owner thread runs it, its result or exception in ``out``."""
    def run() -> None:
        try:
            out["result"] = run_on_port(robot, True, 0.5)
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            out["error"] = exc
    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def test_a_stop_during_the_kits_move_halts_the_base_and_names_the_stop(base: Base) -> None:
    gate = MotionGate()
    robot = driver(base, gate)
    try:
        out: dict[str, Any] = {}
        kit = commission_in_thread(robot, out)
        wait_for(base.moving, 60, "the kit's MOVE under way")
        t_stop = time.monotonic()
        halted = gate.engage()  # what robot.stop does in ritad's command thread
        assert halted.result(timeout=5) is True  # acknowledged by the base while the kit was running
        assert not base.moving()
        x = base.x()
        kit.join(timeout=30)
        assert not kit.is_alive() and "error" not in out, out
        heard = base.since(t_stop)
        assert "STOP" in heard and not {"MOVE", "TURN"} & set(heard), heard  # nothing moved it after the STOP
        assert not base.moving() and base.x() == x  # odometry no longer advancing
        checks = {c["name"]: c for c in out["result"]["checks"]}
        stopped = [c for c in checks.values() if c["value"] == STOPPED]
        assert stopped and {c["verdict"] for c in stopped} == {"fail"}, checks
        assert checks["watchdog"]["value"] == STOPPED, checks
        assert "acknowledged by the base" in checks["watchdog"]["detail"], checks
        reopened = heard[heard.index("HELLO", heard.index("STOP")):]  # the driver's port, opened again
        assert reopened[:2] == ["HELLO", "STOP"], heard  # latched: STOP first after HELLO, as at any connect
        with pytest.raises(DeviceError) as exc:
            robot.move(10.0, 10.0)
        assert exc.value.code == "stopped" and "MOVE" not in base.since(t_stop)
    finally:
        robot.close()


def test_a_stop_latched_before_the_kit_writes_no_motion_line(base: Base) -> None:
    """Latched and acknowledged before the kit began (the STOP came after the handler's check): the kit's
    first motion line is refused, as the driver refuses one."""
    gate = MotionGate()
    robot = driver(base, gate)
    try:
        halted = gate.engage()
        wait_for(lambda: robot.pump(0.02) or halted.done(), 5, "the owner wrote the STOP, acknowledged")
        t0 = time.monotonic()
        out: dict[str, Any] = {}
        commission_in_thread(robot, out).join(timeout=60)
        assert "error" not in out, out
        assert not {"MOVE", "TURN"} & set(base.since(t0)), base.since(t0)
        checks = {c["name"]: c for c in out["result"]["checks"]}
        assert checks["stop_braking"]["value"] == STOPPED and "latched" in checks["stop_braking"]["detail"]
        assert checks["latency"]["verdict"] == "pass"  # what needs no motion ran
    finally:
        robot.close()


def test_a_whole_kit_run_reports_exactly_the_checks_a_stop_would_name(base: Base) -> None:
    # KIT_CHECKS is what a STOP mid-kit reports as not run: a check missing from it would go unreported
    robot = driver(base, MotionGate())
    try:
        out = run_on_port(robot, True, 0.5)
    finally:
        robot.close()
    assert {c["name"] for c in out["checks"]} - {"t_us_width"} == set(KIT_CHECKS), out["checks"]
