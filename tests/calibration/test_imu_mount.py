"""calibration/imu_mount.py: the inclinometer's mounting as a rotation, what one or two runs resolve, the check."""
from __future__ import annotations

import numpy as np
import pytest

from calibration.imu_mount import body_tilt, imu_mount, rot2

OFFSET = np.array([0.03, -0.02])  # deg
H_MM = 350.0


def read(t, yaw, rng, sigma=0.002):
    return rot2(-yaw) @ np.asarray(t, float) + OFFSET + rng.normal(0, sigma, 2)


@pytest.mark.parametrize("yaw", [2.0, -3.5, 0.7])
def test_a_yawed_sensor_is_resolved_by_the_reversal(yaw):
    """Plate tilted 1.1°: the 180° run sees the body's tilt turned around; the yaw comes out within 0.1°."""
    rng = np.random.default_rng(int(yaw * 10) + 50)
    plate = np.array([0.8, -0.75])  # |t| = 1.1°
    tilts = [plate, -plate]
    m = imu_mount(tilts, [read(t, yaw, rng) for t in tilts], [0.002, 0.002], H_MM)
    assert m.yaw_deg == pytest.approx(yaw, abs=0.1) and m.offset_deg == pytest.approx(OFFSET, abs=0.003)
    assert m.verdict == "ok" and "yawed" in m.messages[0]
    # at use, on another tilt, the body's tilt comes back
    t = np.array([-0.2, 0.4])
    assert body_tilt(read(t, yaw, rng, 0.0), m.offset_deg, m.yaw_deg) == pytest.approx(t, abs=0.004)


def test_an_unyawed_sensor_stays_unyawed_and_the_offsets_agree():
    rng = np.random.default_rng(1)
    tilts = [np.array([0.5, 0.2]), np.array([-0.5, -0.2])]
    m = imu_mount(tilts, [read(t, 0.0, rng) for t in tilts], [0.002, 0.002], H_MM)
    assert m.yaw_deg == 0.0 and m.verdict == "ok" and m.messages == []
    assert m.offset_deg == pytest.approx(OFFSET, abs=0.003)


def test_a_single_run_on_a_tilted_plate_says_what_it_cannot_give():
    rng = np.random.default_rng(2)
    m = imu_mount([[0.8, -0.75]], [read([0.8, -0.75], 2.0, rng)], [0.002], H_MM)
    assert m.verdict == "warn" and m.yaw_deg is None and "--reversal" in m.messages[0]
    level = imu_mount([[0.05, 0.02]], [read([0.05, 0.02], 2.0, rng)], [0.002], H_MM)
    assert level.verdict == "ok" and level.messages == []  # a level plate: the yaw cannot matter much


def test_offsets_no_yaw_explains_are_refused_not_used():
    """A run recorded as if driven forward but driven backwards: the offsets disagree by twice the tilt."""
    rng = np.random.default_rng(3)
    plate = np.array([0.8, -0.75])
    readings = [read(plate, 0.0, rng), read(plate, 0.0, rng)]  # both runs saw the same body tilt ...
    m = imu_mount([plate, -plate], readings, [0.002, 0.002], H_MM)  # ... but the poses say it turned around
    assert m.verdict == "warn" and m.offset_deg is None and "not calibrated" in m.messages[0]


def test_the_robots_seating_on_an_uneven_plate_is_no_mounting_fault():
    """Seed 102 of the paper+imu world: the plate tilts 0.02°, the robot stands on it 0.005° off its normal per
    run (20 µm of unevenness under the wheels). The runs' offsets differ by 0.011°, within their σ once the
    seating counts; a yaw fit over so small a tilt spread wanders (gain 0.80) and must not refuse the offset."""
    tilts = [(-0.023976, -0.012743), (0.023155, 0.011826)]
    readings = [(-0.027647, -0.002102), (0.008318, 0.020200)]
    m = imu_mount(tilts, readings, [0.0006, 0.0011], 350.0)
    assert m.verdict == "ok" and m.messages == [] and m.yaw_deg == 0.0
    assert m.offset_deg == pytest.approx(np.mean(np.subtract(readings, tilts), axis=0))
    # without the seating's share (the reading's noise alone) the same data were refused
    assert imu_mount(tilts, readings, [0.0006, 0.0011], 350.0, seating_sigma_deg=0.0).offset_deg is None
