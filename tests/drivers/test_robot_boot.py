"""Day one on a real base: an open that does not reset it, a base that boots, banners, restarts, permissions.

The bases here are the simulated one with the behaviours of an Arduino-class controller
(fakes/robot_boot.py): reset when DTR is asserted (seen through RFC 2217, fakes/robot_rfc2217.py),
silent while it boots, a banner ending in a prompt without a line end, everything forgotten after.
"""
from __future__ import annotations

import errno
import os
import termios
from collections.abc import Iterator
from typing import Any

import pytest
import serial

from drivers.base import DeviceLost, DeviceURL
from drivers.robot import SerialRobot
from drivers.robot_port import open_error
from fakes.robot import PtyServer
from fakes.robot_base import FakeBase
from fakes.robot_boot import Boot
from fakes.robot_rfc2217 import Rfc2217Base
from fakes.world import World, WorldParams
from tools.harness.robot import wait_idle

pytestmark = pytest.mark.timeout(60)


def _base(**boot: Any) -> FakeBase:
    return FakeBase(World(WorldParams(start_pose=(0.0, 0.0, 0.0))), time_scale=0.0, boot=Boot(**boot))


@pytest.fixture
def rfc2217_base() -> Iterator[Rfc2217Base]:
    server = Rfc2217Base(_base(boot_s=1.0, reset_on_dtr=True, at_power_on=False))
    yield server
    server.close()


def test_an_open_holds_dtr_low_so_an_auto_reset_base_keeps_its_state(rfc2217_base: Rfc2217Base) -> None:
    url = f"{rfc2217_base.url}?state_hz=0&timeout=0.3&retries=1"
    robot = SerialRobot(DeviceURL.parse(url))
    robot.open()  # pyserial's defaults assert DTR here: the base would reset, and miss this HELLO
    robot.move(100.0, 100.0)
    assert wait_idle(robot, 5.0).x_mm == 100.0
    robot.close()
    robot.open()  # a reconnect: still no reset, the odometry is the base's memory
    assert robot.status().x_mm == 100.0
    robot.close()
    assert rfc2217_base.base.boot.resets == 0
    assert True not in rfc2217_base.uart.dtr_changes  # DTR was never asserted


def test_with_dtr_1_the_base_resets_and_the_boot_window_rides_through_it(rfc2217_base: Rfc2217Base) -> None:
    robot = SerialRobot(DeviceURL.parse(f"{rfc2217_base.url}?state_hz=0&timeout=0.3&retries=1&dtr=1&boot=3"))
    robot.open()  # the base resets at the open, boots for 1 s, prints its banner, then answers
    counters = robot.info()["counters"]
    assert rfc2217_base.base.boot.resets == 1 and counters["boot_waits"] >= 1
    assert counters["garbage"] >= 2  # the banner's lines, and the prompt the VERSION reply shared a line with
    assert robot.info()["protocol"] == 3
    robot.close()
    lost = SerialRobot(DeviceURL.parse(f"{rfc2217_base.url}?state_hz=0&timeout=0.3&retries=1&dtr=1&boot=0"))
    with pytest.raises(DeviceLost, match="did not answer HELLO"):
        lost.open()  # without the boot window the reset costs the connection
    lost.close()


def test_a_base_powered_on_with_its_host_is_waited_for() -> None:
    server = PtyServer(_base(boot_s=1.5, at_power_on=False))
    try:
        robot = SerialRobot(DeviceURL.parse(f"serial://{server.path}?state_hz=0&timeout=0.2&retries=1"))
        server.base.reset()  # powered on now, with its host
        robot.open()  # silent for 1.5 s: HELLO asked again within the 3 s boot window
        assert robot.info()["counters"]["boot_waits"] >= 1 and server.base.counters["lost_booting"] >= 2
        assert robot.status().state == "IDLE"
        robot.close()
    finally:
        server.shutdown()


def test_a_prompt_without_a_line_end_before_a_reply_costs_nothing() -> None:
    server = PtyServer(_base())
    try:
        robot = SerialRobot(DeviceURL.parse(f"serial://{server.path}?state_hz=0&timeout=0.3&retries=0"))
        robot.open()
        server.inject(b"\x00\xfe\r\nready> ")  # bootloader bytes, a line end, then a prompt
        assert robot.status().state == "IDLE"  # its reply shared the prompt's line: read all the same
        assert robot.info()["counters"]["garbage"] == 2
        robot.close()
    finally:
        server.shutdown()


def test_a_base_that_restarted_mid_session_ends_the_session_and_a_reconnect_restores_it() -> None:
    server = PtyServer(_base())
    try:
        robot = SerialRobot(DeviceURL.parse(f"serial://{server.path}?state_hz=0&timeout=0.3&stream_hz=0"))
        robot.open()
        robot.move(50.0, 100.0)
        wait_idle(robot, 5.0)
        server.base.reset()  # a brown-out: the base forgot the session (version 1 until a HELLO)
        with pytest.raises(DeviceLost, match="restarted"):
            robot.status()
        robot.open()
        state = robot.status()
        assert robot.info()["protocol"] == 3 and state.x_mm == 0.0 and state.t_us is not None
        robot.close()
    finally:
        server.shutdown()


def test_permission_denied_names_the_device_the_user_the_groups_and_the_unit_setting(tmp_path: Any) -> None:
    device = tmp_path / "ttyUSB9"
    device.write_bytes(b"")
    text = open_error(str(device), serial.SerialException(errno.EACCES, f"could not open port {device}"))
    assert str(device) in text and "permission denied" in text
    assert "runs as user " in text and "in groups " in text
    assert "SupplementaryGroups=" in text and "PrivateUsers=yes" in text and "#41994" in text
    if os.geteuid() != 0:  # as root the open would succeed whatever the mode
        device.chmod(0)
        robot = SerialRobot(DeviceURL.parse(f"serial://{device}"))
        with pytest.raises(DeviceLost, match="PrivateUsers=yes"):
            robot.open()
    assert "permission denied" not in open_error("/dev/x", serial.SerialException(errno.ENOENT, "no such"))


def test_with_dtr_1_a_close_leaves_dtr_up_hupcl_cleared() -> None:
    server = PtyServer(_base())

    def termios_of() -> int:
        return termios.tcgetattr(server._slave)[2] & termios.HUPCL

    try:
        attrs = termios.tcgetattr(server._slave)
        attrs[2] |= termios.HUPCL  # the kernel's default for a tty
        termios.tcsetattr(server._slave, termios.TCSANOW, attrs)
        robot = SerialRobot(DeviceURL.parse(f"serial://{server.path}?state_hz=0&timeout=0.3"))
        robot.open()
        assert termios_of()  # dtr=0 (the default): DTR is low anyway, HUPCL left as found
        robot.close()
        robot = SerialRobot(DeviceURL.parse(f"serial://{server.path}?state_hz=0&timeout=0.3&dtr=1"))
        robot.open()
        assert not termios_of()  # dtr=1: the next open finds DTR up, no edge
        robot.close()
    finally:
        server.shutdown()
