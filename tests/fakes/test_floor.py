"""Floor and plate surfaces, the tilt they give the robot, and the drive's path errors
(fakes/floor.py, fakes/errors.py): statistics and repeatability."""
import math

import numpy as np
import pytest

from drivers import robot_protocol as rp
from fakes import profiles
from fakes.errors import GROUPS, ErrorModel
from fakes.floor import HeightField
from fakes.robot_base import FakeBase
from fakes.world import RobotPose, World, WorldParams

START = (2200.0, 1500.0, 20.0)  # on the floor, well away from the plate


def only(*groups: str, seed: int = 1, **params) -> World:
    p = profiles.apply("paper", WorldParams(seed=seed, **params))
    return World(p.with_(errors=p.errors.without(*(g for g in GROUPS if g not in groups))))


def test_height_field_has_its_rms_slope_and_correlation_length():
    rms, ell = 0.2, 400.0
    x = np.linspace(0.0, 20000.0, 2001)
    h, h_ell, dh = [], [], []
    for s in range(60):
        f = HeightField(np.random.default_rng(s), rms, ell)
        h.append(f(x, 0.0))
        h_ell.append(f(x + ell, 0.0))
        dh.append((f(x + 0.5, 0.0) - f(x - 0.5, 0.0)) / 1.0)
    h, h_ell, dh = map(np.concatenate, (h, h_ell, dh))
    assert abs(h.mean()) < 0.05 * rms
    assert h.std() == pytest.approx(rms, rel=0.1)
    assert np.corrcoef(h, h_ell)[0, 1] == pytest.approx(math.exp(-0.5), abs=0.08)  # Gaussian correlation at ℓ
    assert dh.std() == pytest.approx(rms / ell, rel=0.1)  # rms slope per axis = σ/ℓ


def test_fixed_floor_gives_the_same_tilt_for_the_same_pose_and_another_when_the_heading_changes():
    w = only("floor", start_pose=START)
    a = w.settle(RobotPose(*START))
    b = w.settle(RobotPose(*START))
    assert (a.roll_rad, a.pitch_rad, a.z_mm) == (b.roll_rad, b.pitch_rad, b.z_mm)
    c = w.settle(RobotPose(START[0], START[1], START[2] + 90.0))
    assert math.hypot(c.roll_rad - a.roll_rad, c.pitch_rad - a.pitch_rad) > 1e-5
    # the same through the simulated base: turn away and back, read the inclinometer
    w2 = World(w.params.with_(base_has_inclinometer=True))
    base = FakeBase(w2, time_scale=0.0)
    seq = iter(range(1, 100))

    def tilt() -> tuple[float, float]:
        base.handle_line(rp.encode("STATUS", next(seq)).strip())
        m = rp.decode(base.drain()[-1].strip())
        return m.number(5, "roll"), m.number(6, "pitch")

    base.handle_line(rp.encode("HELLO", next(seq), 1).strip())
    t0 = tilt()
    base.handle_line(rp.encode("TURN", next(seq), 90, 45).strip())
    t90 = tilt()
    base.handle_line(rp.encode("TURN", next(seq), -90, 45).strip())
    assert tilt() == pytest.approx(t0, abs=1e-6) and t0 != pytest.approx(t90, abs=1e-4)


def test_tilt_from_the_wheel_contacts_follows_the_floor_statistics():
    """Roll = (h_left − h_right)/track: σ = σ_h·√(2(1 − ρ(track)))/track; the slope adds its mean."""
    f = ErrorModel.paper().floor
    r = ErrorModel.paper().robot
    rolls = []
    for s in range(40):
        w = only("floor", "robot", seed=s, start_pose=START)
        slope = w.effects.floor.slope
        rng = np.random.default_rng(s)
        for _ in range(50):
            h = rng.uniform(-180, 180)
            p = w.settle(RobotPose(START[0] + rng.uniform(-3000, 3000), START[1] + rng.uniform(1000, 4000),
                                   h))
            a = math.radians(h)
            # minus the slope's part
            rolls.append(p.roll_rad - (-math.sin(a) * slope[0] + math.cos(a) * slope[1]))
    rolls = np.array(rolls)
    sigma_h = f.rms_slope_mrad * 1e-3 * f.correlation_mm
    expect = (sigma_h * math.sqrt(2 * (1 - math.exp(-r.wheel_track_mm ** 2 / (2 * f.correlation_mm ** 2))))
              / r.wheel_track_mm)
    assert abs(rolls.mean()) < 4 * expect / math.sqrt(40)
    assert rolls.std() == pytest.approx(expect, rel=0.15)


def test_plate_rests_on_the_floor_and_has_its_flatness():
    w = only("floor", "plate", seed=3)
    n = -w.abs_H_ref[:3, 2]  # PCS z points into the plate
    assert n[2] > 0.999 and math.degrees(math.acos(n[2])) > 1e-4  # tilted with the floor under it
    assert np.linalg.det(w.abs_H_ref[:3, :3]) == pytest.approx(1.0)
    c = w.nests_abs()["red"]
    xs = c[0] + np.linspace(-200, 200, 41)
    from fakes.floor import plane_height

    dev = np.array([w.support_height(x, c[1]) - plane_height(w.abs_H_ref, x, c[1]) for x in xs])
    assert 0.2 * w.params.errors.plate.flatness_rms_mm < dev.std() < 3 * w.params.errors.plate.flatness_rms_mm


@pytest.mark.parametrize("dist", [200.0, 400.0])
def test_moves_bend_on_an_arc_and_slip(dist: float):
    """Per move: lateral σ = 50 µm·(d/200)², heading σ = 2·50 µm·d/200², distance σ = 0.2 %·d."""
    w = only("robot", start_pose=START)
    r = w.params.errors.robot
    base = FakeBase(w, time_scale=0.0)
    start = w.robot
    a = math.radians(start.heading_deg)
    out = []
    for i in range(1500):
        w.set_robot(start)
        base.handle_line(rp.encode("MOVE", 1 + i % 9000, dist, 100).strip())
        base.drain()
        e = w.robot
        dx, dy = e.x_mm - start.x_mm, e.y_mm - start.y_mm
        out.append((dx * math.cos(a) + dy * math.sin(a) - dist, -dx * math.sin(a) + dy * math.cos(a),
                    math.radians(e.heading_deg - start.heading_deg)))
    along, lateral, turn = np.array(out).T
    kappa = 2 * r.lateral_sigma_mm / r.lateral_ref_mm ** 2
    assert lateral.std() == pytest.approx(kappa * dist ** 2 / 2, rel=0.08)
    assert turn.std() == pytest.approx(kappa * dist, rel=0.08)
    assert np.corrcoef(lateral, turn)[0, 1] > 0.99  # one arc: lateral and heading deviate together
    assert along.std() == pytest.approx(r.slip_sigma * dist, rel=0.08)
    assert abs(along.mean()) < 4 * r.slip_sigma * dist / math.sqrt(len(along))
