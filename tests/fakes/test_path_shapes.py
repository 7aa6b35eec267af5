"""The simulated path shapes (fakes/path_shapes.py): consistent geometry, none larger than the sourced arc."""
from __future__ import annotations

import math

import numpy as np
import pytest

from fakes import path_shapes
from fakes.errors import ErrorModel, RobotErrors
from fakes.simulate import SimConfig, Simulation
from fakes.world import World, WorldParams

D = 200.0
NEW = ("early", "late", "kink", "kink-end")


def robot_world(shape: str = "arc") -> World:
    return World(WorldParams(seed=3, errors=ErrorModel(robot=RobotErrors(path_shape=shape))))


@pytest.mark.parametrize("shape", NEW)
def test_offset_from_the_chord_has_the_heading_as_its_slope(shape):
    w = robot_world(shape)
    lat, turn_deg = w.effects.bend(D, np.random.default_rng(11))
    f = np.linspace(0.0, 1.0, 4001)
    side, dh = w.effects.bend_profile(f, lat, D)
    assert side[0] == pytest.approx(0.0, abs=1e-12) and side[-1] == pytest.approx(0.0, abs=1e-12)
    theta = dh + math.radians(turn_deg) * f  # the heading's departure from the start
    slope = np.gradient(side, f * D) + lat / D  # d(offset from the start line)/ds
    inner = np.abs(f - 0.5) < 0.499
    if shape.startswith("kink"):  # a step: compare away from it
        inner &= np.abs(f - w.effects._kinks[lat]) > 2e-3
    np.testing.assert_allclose(slope[inner], theta[inner], atol=abs(lat) / D * 1e-2)
    assert theta[-1] == pytest.approx(math.radians(turn_deg), abs=1e-15)


@pytest.mark.parametrize("shape", NEW)
def test_no_shape_exceeds_the_arc_in_end_offset_or_turn(shape):
    for seed in range(200):
        at = path_shapes.kink_at(shape, np.random.default_rng(seed))
        side, turn = path_shapes.end(shape, 1.0, at)  # per unit κd; the arc: (1/2, 1)
        assert abs(side) <= 0.5 + 1e-12 and abs(turn) <= 1.0 + 1e-12
        assert abs(side) == pytest.approx(0.5) or abs(turn) == pytest.approx(1.0)  # one of them is the arc's


def test_final_heading_off_the_chord_per_shape():
    # per unit κd (σ 500 µrad): the arc's 1/2 is the 250 µrad of calibration.md §4.4
    off = {s: (lambda e: e[1] - e[0])(path_shapes.end(s, 1.0, 0.95)) for s in path_shapes.SHAPES}
    assert off == pytest.approx({"arc": 0.5, "s": -0.5, "early": 0.3 / 2 / 1.7, "late": 0.85, "kink": 0.95,
                                 "kink-end": 0.95})


def test_kink_end_falls_in_the_last_tenth_and_turns_as_the_arc():
    fs = [path_shapes.kink_at("kink-end", np.random.default_rng(s)) for s in range(100)]
    assert min(fs) >= 0.9 and max(fs) <= 1.0
    assert path_shapes.end("kink-end", 2e-3, 0.95) == pytest.approx((2e-3 * 0.05, 2e-3))


def test_default_shapes_draw_as_before_and_an_experiment_can_change_its_shape():
    arc, late = robot_world(), robot_world("late")
    a = arc.effects.bend(D, np.random.default_rng(5))
    assert late.effects.bend(D, np.random.default_rng(5), "arc") == a  # same κ draw, arc geometry
    lat, turn = late.effects.bend(D, np.random.default_rng(5))
    assert turn == pytest.approx(a[1]) and lat == pytest.approx(a[0] * path_shapes.PART)
    w = World(WorldParams(seed=4, errors=ErrorModel.paper()))
    arc_obs = Simulation(w, SimConfig(seed=4)).validation().observations[0]
    kink_obs = Simulation(w, SimConfig(seed=4, path_shape="kink-end")).validation().observations[0]
    assert np.abs(arc_obs.stream - kink_obs.stream).max() > 1e-3  # mm: another path
    with pytest.raises(ValueError, match="'zigzag'"):
        SimConfig(path_shape="zigzag")


def test_the_fake_bases_path_follows_a_kink():
    """fakes/robot_motion.py's poses along a MOVE (which the base knows by its end offset) find the kink."""
    from dataclasses import replace

    from fakes.robot_motion import Motion, pose_on_path
    from fakes.world import RobotPose

    w = robot_world("kink")
    lat, turn = w.effects.bend(D, np.random.default_rng(2))
    at = w.effects._kinks[lat]
    start = RobotPose(0.0, 0.0, 0.0)
    end = replace(start, x_mm=D, y_mm=lat, heading_deg=turn)
    m = Motion(1, start, end, (0.0, 0.0, 0.0), (D, 0.0, 0.0), 0.0, 1.0, D, None, lat)
    before, after = pose_on_path(w, m, at / 2), pose_on_path(w, m, (1 + at) / 2)
    assert before.y_mm == pytest.approx(0.0, abs=1e-12)  # straight on the start heading before the kink
    assert after.heading_deg == pytest.approx(turn) and before.heading_deg == pytest.approx(0.0, abs=1e-12)
