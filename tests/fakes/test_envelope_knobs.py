"""The error model's sensitivity knobs: the tracker's random share, the path shape, tweaked models."""
from __future__ import annotations

import math

import numpy as np
import pytest

from fakes import profiles
from fakes.errors import GROUPS, ErrorModel, RobotErrors
from fakes.world import World, WorldParams


class ZeroRng:
    """Stands in for a generator: no random part, only the systematic one."""

    def standard_normal(self, shape):
        return np.zeros(shape)


def world_with(*tweak, groups=("tracker",), seed: int = 1) -> World:
    p = profiles.apply("paper", WorldParams(seed=seed))
    errors = p.errors.without(*(g for g in GROUPS if g not in groups)).tweaked(tuple(tweak))
    return World(p.with_(errors=errors))


def test_default_split_keeps_the_whole_distance_part_systematic():
    assert ErrorModel.paper().tracker.random_share_b == 0.0


def test_random_share_moves_the_distance_part_from_the_pattern_to_each_reading():
    P = (np.array([0.6, -0.7, -0.2]) / np.linalg.norm([0.6, -0.7, -0.2]) * 8000.0)[None, :]
    full, half = world_with(), world_with(("tracker", "random_share_b", 0.5))
    sys_full = full.effects.tracker_measure(P, ZeroRng())[0] - P[0]
    sys_half = half.effects.tracker_measure(P, ZeroRng())[0] - P[0]
    u = P[0] / np.linalg.norm(P[0])
    across = np.eye(3) - np.outer(u, u)  # the transverse part; the range's distance part stays systematic
    np.testing.assert_allclose(across @ sys_half, math.sqrt(0.5) * across @ sys_full, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(u @ sys_half, u @ sys_full, rtol=1e-9, atol=1e-12)
    t = half.params.errors.tracker
    n = 4000
    dev = half.effects.tracker_measure(np.repeat(P, n, axis=0), np.random.default_rng(0)) - P - sys_half
    transverse = dev - np.outer(dev @ u, u)
    k = t.mpe_to_sigma
    expect = math.sqrt((k * t.transverse_a_mm) ** 2 + 0.5 * (k * t.transverse_b_mm_per_m * 8.0) ** 2)
    assert np.sqrt((transverse ** 2).sum(axis=1).mean() / 2) == pytest.approx(expect, rel=0.05)


def test_s_path_ends_as_far_to_the_side_but_turns_back():
    arc, s = world_with(groups=("robot",)), world_with(("robot", "path_shape", "s"), groups=("robot",))
    lat_a, turn_a = arc.effects.bend(200.0, np.random.default_rng(5))
    lat_s, turn_s = s.effects.bend(200.0, np.random.default_rng(5))
    assert lat_s == lat_a != 0.0 and turn_s == 0.0 and turn_a != 0.0
    f = np.linspace(0.0, 1.0, 2001)
    side, dh = s.effects.bend_profile(f, lat_s, 200.0)
    assert side[0] == pytest.approx(0.0, abs=1e-15) and side[-1] == pytest.approx(0.0, abs=1e-12)
    # left of the chord on one half, right on the other
    np.testing.assert_allclose(side, -side[::-1], atol=1e-12)
    # the heading along the path is the slope of the path: d(side)/ds = heading − chord angle
    slope = np.gradient(side, f * 200.0)
    np.testing.assert_allclose(slope[1:-1], (dh - lat_s / 200.0)[1:-1], atol=abs(lat_s) * 1e-3)
    side_a, dh_a = arc.effects.bend_profile(f, lat_a, 200.0)
    np.testing.assert_allclose(side_a, (f * f - f) * lat_a)
    np.testing.assert_array_equal(dh_a, 0.0)


def test_tweaks_name_what_cannot_be_set():
    with pytest.raises(ValueError, match="robot.wobble"):
        ErrorModel.paper().tweaked((("robot", "wobble", 1.0),))
    with pytest.raises(ValueError, match="imu.noise_sigma_deg"):
        ErrorModel.paper().tweaked((("imu", "noise_sigma_deg", 0.0035),))  # the paper profile has no IMU
    with pytest.raises(ValueError, match="'zigzag'"):
        RobotErrors(path_shape="zigzag")
