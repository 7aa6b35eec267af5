"""The simulated world's error model, effect by effect: mean, σ and dependence on distance
and position, and the profiles that select it (fakes/profiles.py)."""
import math

import numpy as np
import pytest

from calibration.frames import inv_H
from drivers import robot_protocol as rp
from fakes import profiles
from fakes.errors import ErrorModel, GROUPS, sources_table
from fakes.robot_base import FakeBase
from fakes.world import RobotPose, World, WorldParams

N = 4000  # samples per statistic: σ estimates to ~1 %


class ZeroRng:
    """Stands in for a generator: no random part, only the systematic one."""

    def standard_normal(self, shape):
        return np.zeros(shape)


def only(*groups: str, seed: int = 1, **params) -> World:
    """A world with just the named error groups of the paper profile on."""
    p = profiles.apply("paper", WorldParams(seed=seed, **params))
    return World(p.with_(errors=p.errors.without(*(g for g in GROUPS if g not in groups))))


# ---------------------------------------------------------------------------- tracker


def test_tracker_noise_is_spherical_and_its_systematic_part_grows_with_distance():
    w = only("tracker")
    t = w.params.errors.tracker
    k = t.mpe_to_sigma
    u = np.array([0.6, -0.7, -0.2]) / np.linalg.norm([0.6, -0.7, -0.2])  # one beam direction
    rng = np.random.default_rng(0)
    sys_len = {}
    for D in (2000.0, 8000.0):
        P = u * D
        sys = w.effects.tracker_measure(P[None, :], ZeroRng())[0] - P
        sys_len[D] = sys
        dev = w.effects.tracker_measure(np.repeat(P[None, :], N, axis=0), rng) - P - sys
        radial = dev @ u
        transverse = dev - np.outer(radial, u)
        assert abs(radial.mean()) < 4 * k * t.range_a_mm / math.sqrt(N)  # the random part is unbiased
        assert radial.std() == pytest.approx(k * t.range_a_mm, rel=0.05)  # range σ (ADM) ...
        # ... and two transverse axes of σ_t each, independent of the distance
        assert np.sqrt((transverse ** 2).sum(axis=1).mean() / 2) == pytest.approx(k * t.transverse_a_mm,
                                                                                 rel=0.05)
    # the station's systematic part: the same direction at 4x the distance, 4x the error
    np.testing.assert_allclose(sys_len[8000.0], 4 * sys_len[2000.0], rtol=1e-9, atol=1e-12)
    # and it differs between directions (a pattern, not a constant shift)
    v = np.array([-0.3, 0.9, 0.1]) / np.linalg.norm([-0.3, 0.9, 0.1])
    other = w.effects.tracker_measure((v * 2000.0)[None, :], ZeroRng())[0] - v * 2000.0
    assert np.linalg.norm(other - sys_len[2000.0]) > 1e-4


def test_tracker_systematic_part_over_stations_has_the_typical_sigma():
    """Over many stations (worlds) the systematic transverse error at D has σ = ½·b·D per axis."""
    D, u = 5000.0, np.array([1.0, 0.0, 0.0])
    offs = np.array([only("tracker", seed=s).effects.tracker_measure((u * D)[None, :], ZeroRng())[0] - u * D
                     for s in range(400)])
    t = ErrorModel.paper().tracker
    expect = t.mpe_to_sigma * t.transverse_b_mm_per_m * D / 1000.0
    assert abs(offs[:, 1].mean()) < 4 * expect / math.sqrt(400)
    assert offs[:, 1].std() == pytest.approx(expect, rel=0.15)
    assert offs[:, 2].std() == pytest.approx(expect, rel=0.15)


def test_fake_tracker_readings_and_stream_use_the_model():
    from fakes.tracker_model import TrackerModel

    w = only("tracker")
    tm = TrackerModel(w)
    tm.lock("robot")
    true = w.reflectors_trk()["robot"]
    rec = tm.measure_records(2000, 0.0, 0.001)
    xyz = np.column_stack([rec["val1"], rec["val2"], rec["val3"]]) / tm.state.length_unit()
    sys = w.effects.tracker_measure(true[None, :], ZeroRng())[0] - true
    assert np.linalg.norm(xyz.mean(axis=0) - true - sys) < 0.002  # centred on truth + systematic
    assert np.linalg.norm(tm.measure_point() - true) < 0.2


# ---------------------------------------------------------------------------- reflectors


def test_nest_seating_offsets_have_the_centring_and_reseat_sigma():
    w = only("reflector")
    r = w.params.errors.reflector
    offs = []
    for _ in range(N // 3):
        w.effects.reseat_nests()
        offs.extend(w.effects.nest_offsets.values())
    offs = np.array(offs)
    sigma = math.sqrt(r.smr_centring_mm ** 2 / 3 + r.nest_reseat_mm ** 2)  # uniform direction + Gaussian
    assert np.all(np.abs(offs.mean(axis=0)) < 4 * sigma / math.sqrt(len(offs)))
    np.testing.assert_allclose(offs.std(axis=0), sigma, rtol=0.06)
    seated, true = w.nests_seated_abs(), w.nests_abs()
    for n in true:
        np.testing.assert_allclose(seated[n] - true[n], w.effects.nest_offsets[n])


def test_robot_reflector_eccentricity_turns_with_heading_in_the_robot_frame():
    """The mount faces the tracker: fixed in ACS, so in RCS the SMR centre moves with heading."""
    w = only("reflector")
    ecc = w.params.errors.reflector.mount_eccentricity_mm
    x, y = 2000.0, 1300.0
    acs, rcs = [], []
    for h in np.arange(0.0, 360.0, 45.0):
        H = w.abs_H_rob(RobotPose(x, y, float(h)))  # same reflector position at every heading
        P = w.robot_reflector_abs(H)
        acs.append(P - H[:3, 3])
        rcs.append((inv_H(H) @ [*P, 1.0])[:3])
    acs, rcs = np.array(acs), np.array(rcs)
    np.testing.assert_allclose(acs - acs[0], 0.0, atol=1e-9)  # same bearing to the tracker, same ACS offset
    assert np.linalg.norm(acs[0]) == pytest.approx(np.linalg.norm(w.effects.mount_offset), rel=1e-9)
    assert np.ptp(rcs[:, 0]) > 1.5 * ecc  # in the robot frame it sweeps a circle of radius ~ecc


# ---------------------------------------------------------------------------- IMU, target, plate


def test_inclinometer_reports_true_tilt_plus_bias_plus_noise_over_the_protocol():
    w = profiles.world("paper+imu", seed=4, start_pose=(2100.0, 1400.0, 30.0))
    w = World(w.params.with_(errors=w.params.errors.without("robot")))
    imu = w.params.errors.imu
    base = FakeBase(w, time_scale=0.0)
    base.handle_line(rp.encode("HELLO", 1, 1).strip())
    assert "INCL" in base.drain()[0].decode()
    rolls = []
    for i in range(400):
        base.handle_line(rp.encode("STATUS", 2 + i).strip())
        msg = rp.decode(base.drain()[0].strip())
        rolls.append((msg.number(5, "roll"), msg.number(6, "pitch")))
    err = np.radians(np.array(rolls)) - [w.robot.roll_rad, w.robot.pitch_rad]
    np.testing.assert_allclose(err.mean(axis=0), w.effects.imu_bias_rad,
                               atol=4 * math.radians(imu.noise_sigma_deg) / 20)
    np.testing.assert_allclose(np.degrees(err.std(axis=0)), imu.noise_sigma_deg, rtol=0.12)
    # without the IMU (paper profile) the base has no inclinometer at all
    assert not profiles.world("paper").params.base_has_inclinometer


def test_target_print_scale_and_shear():
    scales, shears = [], []
    for s in range(300):
        w = only("target", seed=s)
        A = w.effects.print_A
        scales.append(A[0, 0] - 1.0)
        scales.append(w.board_print_scale[0] - 1.0)  # the hand-held board's print (fakes/board.py)
        shears.append(A[0, 1])
        c = w.board_centre_ref()
        P = np.array([[c[0] + 30.0, c[1] - 20.0, 0.0]])
        Q = w.effects.board_true(P)
        back = w.effects.board_nominal(Q[:, 0], Q[:, 1])
        np.testing.assert_allclose(np.column_stack(back), P[:, :2], atol=1e-12)
    t = ErrorModel.paper().target
    assert np.std(scales) == pytest.approx(t.scale_sigma, rel=0.15)
    assert np.std(shears) == pytest.approx(t.shear_sigma_rad, rel=0.15)
    assert abs(np.mean(scales)) < 4 * t.scale_sigma / math.sqrt(len(scales))


def test_plate_thickness_is_drawn_within_tolerance():
    th = np.array([profiles.world("paper", seed=s).params.plate_thickness_mm for s in range(300)])
    tol = ErrorModel.paper().plate.thickness_tol_mm
    assert np.all(np.abs(th - profiles.NOMINAL_PLATE_MM) <= tol)
    assert th.std() == pytest.approx(2 * tol / math.sqrt(12), rel=0.15)  # uniform over ±tol


# ---------------------------------------------------------------------------- profiles


def test_ideal_profile_is_todays_world_and_draws_nothing():
    p = WorldParams(seed=3)
    assert profiles.apply("ideal", p) is p
    w = World(p)
    assert not w.effects.active and w.truth().keys() == {"rob_H_cam", "abs_H_ref", "abs_H_trk", "abs_H_rob",
                                                         "nests_abs", "marks"}
    H = w.abs_H_cam()
    assert w.effects.floor_view_H(H) is H and w.settle(w.robot) is w.robot


def test_unknown_profile_names_the_value_and_lists_the_profiles():
    with pytest.raises(ValueError, match=r"'papr'.*ideal, paper, paper\+imu"):
        profiles.apply("papr", WorldParams())
    from fakes.worlds import params_from

    assert params_from({"seed": 2, "profile": "paper"}).errors == ErrorModel.paper()


def test_paper_truth_carries_the_error_draws_and_the_mark_height():
    truth = profiles.world("paper+imu", seed=2).truth()
    assert set(truth["errors"]["magnitudes"]) == set(GROUPS)
    assert all("z_mm" in m for m in truth["marks"])
    assert len(truth["robot_reflector_abs"]) == 3
    assert set(truth["nests_seated_abs"]) == {"red", "green", "blue"}


def test_every_magnitude_has_a_source_in_the_docs_table():
    from pathlib import Path

    table = sources_table()
    doc = (Path(__file__).resolve().parents[2] / "docs" / "accuracy.md").read_text(encoding="utf-8")
    assert table in doc, ("docs/accuracy.md 'Simulated error sources' is stale: "
                          "paste fakes.errors.sources_table()")
