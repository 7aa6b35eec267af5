"""The fake base moves the one simulated world: kinematics, drive errors, tilt."""
from __future__ import annotations

import argparse
import math
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from drivers.base import DeviceURL
from fakes.robot import SimRobot, _param
from fakes.robot_base import FakeBase
from fakes.world import RobotPose, World, WorldParams
from fakes.worlds import sim_url
from tools.harness.robot import wait_idle

pytestmark = pytest.mark.timeout(60)
START = (3000.0, 3000.0, 30.0)  # well off the plate: the support height stays 0


@pytest.fixture
def sim() -> Iterator[Any]:
    made: list[SimRobot] = []

    def make(query: str = "time_scale=0", **params: Any) -> SimRobot:
        world = World(WorldParams(start_pose=START).with_(**params))
        robot = SimRobot(sim_url(world, f"{query}&state_hz=0"))
        made.append(robot)
        robot.open()
        return robot

    yield make
    for r in made:
        r.shutdown()


def _pose(robot: SimRobot) -> RobotPose:
    with robot.world.lock:
        return robot.world.robot


def _wrap(a: float) -> float:
    return math.remainder(a, 360.0)


def test_error_free_drive_is_exact(sim: Any) -> None:
    robot = sim()
    robot.move(200.0, 100.0)
    wait_idle(robot, 5.0)
    p = _pose(robot)
    h = math.radians(30.0)
    assert abs(p.x_mm - (3000.0 + 200.0 * math.cos(h))) < 1e-9
    assert abs(p.y_mm - (3000.0 + 200.0 * math.sin(h))) < 1e-9
    robot.turn(-75.0, 30.0)
    wait_idle(robot, 5.0)
    assert abs(_wrap(_pose(robot).heading_deg - (-45.0))) < 1e-9
    robot.move(-100.0, 100.0)
    wait_idle(robot, 5.0)
    q = _pose(robot)
    assert abs(q.x_mm - (p.x_mm - 100.0 * math.cos(math.radians(-45.0)))) < 1e-9
    assert abs(q.y_mm - (p.y_mm - 100.0 * math.sin(math.radians(-45.0)))) < 1e-9
    assert (q.roll_rad, q.pitch_rad) == (0.0, 0.0)


def test_drive_errors_follow_the_configured_sigmas(sim: Any) -> None:
    sig_lat, sig_head, n, d = 0.05, 0.01, 60, 100.0
    robot = sim(drive_lateral_sigma_mm=sig_lat, drive_heading_sigma_deg=sig_head)
    along, lateral, dheading = [], [], []
    for _ in range(n):
        p0 = _pose(robot)
        robot.move(d, 200.0)
        wait_idle(robot, 5.0)
        p1 = _pose(robot)
        h = math.radians(p0.heading_deg)
        dx, dy = p1.x_mm - p0.x_mm, p1.y_mm - p0.y_mm
        along.append(dx * math.cos(h) + dy * math.sin(h))
        lateral.append(-dx * math.sin(h) + dy * math.cos(h))
        dheading.append(_wrap(p1.heading_deg - p0.heading_deg))
    along_a, lat, dh = np.array(along), np.array(lateral), np.array(dheading)
    assert np.abs(along_a - d).max() < 1e-9  # no scale error configured
    # sample std within ~4 standard errors of sigma (se of a std ≈ sigma/sqrt(2n))
    for values, sigma in ((lat, sig_lat), (dh, sig_head)):
        assert 0.6 * sigma < values.std(ddof=1) < 1.4 * sigma
        assert abs(values.mean()) < 4 * sigma / math.sqrt(n)
    # odometry knows nothing of the errors: it integrates the commands
    st = robot.status()
    assert st.heading_deg == 0.0 and st.x_mm == pytest.approx(n * d, abs=1e-3)


def test_scale_error_is_systematic_and_odometry_stays_nominal(sim: Any) -> None:
    robot = sim(drive_scale_error=0.002)
    p0 = _pose(robot)
    robot.move(500.0, 250.0)
    wait_idle(robot, 5.0)
    p1 = _pose(robot)
    assert math.dist((p0.x_mm, p0.y_mm), (p1.x_mm, p1.y_mm)) == pytest.approx(501.0, abs=1e-9)
    robot.turn(90.0, 90.0)
    st = wait_idle(robot, 5.0)
    assert _wrap(_pose(robot).heading_deg - p1.heading_deg) == pytest.approx(90.18, abs=1e-9)
    assert (st.x_mm, st.heading_deg) == (500.0, 90.0)


def test_drive_errors_are_seeded() -> None:
    def end_pose(seed: int) -> tuple[float, float, float]:
        world = World(WorldParams(seed=seed, start_pose=START, drive_lateral_sigma_mm=1.0,
                                  drive_heading_sigma_deg=0.5))
        robot = SimRobot(sim_url(world, "time_scale=0&state_hz=0"))
        try:
            robot.open()
            for _ in range(3):
                robot.move(100.0, 100.0)
                wait_idle(robot, 5.0)
            p = world.robot
            return (p.x_mm, p.y_mm, p.heading_deg)
        finally:
            robot.shutdown()

    assert end_pose(7) == end_pose(7)
    assert end_pose(7) != end_pose(8)


def test_floor_tilt_is_drawn_at_each_stop_and_reported_by_the_inclinometer(sim: Any) -> None:
    robot = sim(floor_tilt_sigma_mrad=2.0, base_has_inclinometer=True)
    tilts = []
    for _ in range(3):
        robot.move(50.0, 100.0)
        st = wait_idle(robot, 5.0)
        p = _pose(robot)
        tilts.append((p.roll_rad, p.pitch_rad))
        assert st.roll_deg == pytest.approx(math.degrees(p.roll_rad), abs=2e-6)
        assert st.pitch_deg == pytest.approx(math.degrees(p.pitch_rad), abs=2e-6)
    assert len(set(tilts)) == 3 and all(0 < abs(r) < 0.012 for r, _ in tilts)
    blind = sim(floor_tilt_sigma_mrad=2.0)
    blind.move(50.0, 100.0)
    st = wait_idle(blind, 5.0)
    assert _pose(blind).roll_rad != 0.0 and st.roll_deg is None and st.pitch_deg is None


def test_the_reflector_the_tracker_sees_moves_with_the_robot(sim: Any) -> None:
    robot = sim()
    world = robot.world
    before = world.reflectors_abs()
    before_trk = world.reflectors_trk()
    robot.move(200.0, 100.0)
    wait_idle(robot, 5.0)
    after = world.reflectors_abs()
    h = math.radians(START[2])
    moved = after["robot"] - before["robot"]
    assert np.allclose(moved, [200.0 * math.cos(h), 200.0 * math.sin(h), 0.0], atol=1e-9)
    assert np.allclose(after["red"], before["red"])  # nests stay put
    moved_trk = world.reflectors_trk()["robot"] - before_trk["robot"]
    assert np.linalg.norm(moved_trk) == pytest.approx(200.0, abs=1e-9)


def test_the_pose_is_interpolated_during_motion(sim: Any) -> None:
    robot = sim("time_scale=0.25")  # 200 mm at 100 mm/s: 0.5 s of wall time
    x0 = _pose(robot).x_mm
    robot.move(200.0, 100.0)
    seen = []
    deadline = time.monotonic() + 3.0
    idle = False
    while not idle and time.monotonic() < deadline:
        robot.pump(0.02)
        seen.append(_pose(robot).x_mm - x0)
        idle = robot.status().state == "IDLE"
    assert idle
    end = 200.0 * math.cos(math.radians(START[2]))
    middle = [s for s in seen if 0.05 * end < s < 0.95 * end]
    assert len(middle) >= 3, f"no intermediate poses seen: {seen}"
    assert middle == sorted(middle)
    assert _pose(robot).x_mm - x0 == pytest.approx(end, abs=1e-9)


def test_cli_param_parsing() -> None:
    assert _param("drive_lateral_sigma_mm=0.05") == ("drive_lateral_sigma_mm", 0.05)
    assert _param("base_has_inclinometer=true") == ("base_has_inclinometer", True)
    assert _param("seed=4") == ("seed", 4)
    with pytest.raises(argparse.ArgumentTypeError, match="'wheel_size=3'"):
        _param("wheel_size=3")
    with pytest.raises(argparse.ArgumentTypeError, match="value 'big'"):
        _param("drive_scale_error=big")


def test_world_created_when_none_given_and_bad_options_rejected() -> None:
    robot = SimRobot(DeviceURL.parse("sim:?time_scale=0"))
    try:
        assert isinstance(robot.world, World)
        robot.open()
        p0 = robot.world.robot
        robot.move(10.0, 10.0)
        wait_idle(robot, 5.0)
        assert robot.world.robot != p0
    finally:
        robot.shutdown()
    with pytest.raises(ValueError, match="time_scale=-1"):
        SimRobot(DeviceURL.parse("sim:?time_scale=-1"))
    with pytest.raises(ValueError, match="fault_rate=2"):
        FakeBase(World(), fault_rate=2.0)


def test_the_tracker_sees_the_pose_at_each_records_time_without_ticks() -> None:
    """The base's pose is a function of time, not of when it was last ticked: a tracker record's time
    during a move gives the pose of the velocity profile there (within 5 µm), and one after the move's
    end gives the end pose although nothing ticked the base since the start (no lag at the end)."""
    from drivers import robot_protocol as rp

    world = World(WorldParams(start_pose=START))
    base = FakeBase(world, time_scale=0.2)  # 200 mm at 100 mm/s: 0.4 s of wall time
    base.handle_line(rp.encode("HELLO", 1, 1))
    t_cmd = time.monotonic()
    base.handle_line(rp.encode("MOVE", 2, 200, 100))
    motion = base.motion
    assert motion is not None and motion.t0 >= t_cmd
    h = math.radians(START[2])
    for f in (0.25, 0.5, 0.75, 1.0, 1.5):  # queried ahead of and after the motion, as a stream does
        p = world.robot_at(motion.t0 + f * motion.duration)
        along = 200.0 * min(f, 1.0)
        assert math.hypot(p.x_mm - (START[0] + along * math.cos(h)),
                          p.y_mm - (START[1] + along * math.sin(h))) < 0.005, (f, p)
    time.sleep(motion.duration + 0.05)
    reflector_trk = world.robot_reflector_trk_at(time.monotonic())  # the tracker's view, nothing ticked
    end = world.abs_H_rob(RobotPose(START[0] + 200.0 * math.cos(h), START[1] + 200.0 * math.sin(h), START[2]))
    from calibration.frames import apply_H, inv_H

    expected = apply_H(inv_H(world.abs_H_trk), world.robot_reflector_abs(end))
    assert np.linalg.norm(reflector_trk - expected) < 0.005
    base.tick()  # the base finishes the motion: the pose stays where the profile had it
    assert world.robot_at(time.monotonic()).x_mm == pytest.approx(START[0] + 200.0 * math.cos(h), abs=0.005)
