"""calibration/compensation.py: each compensation's geometry, its refusals, and what it buys."""
from __future__ import annotations

import math

import numpy as np
import pytest

from calibration import compensation
from calibration.bend_fit import bend_fit, fit_heading
from calibration.compensation import (Compensation, Stop, apply_bias, compensate, ground_chord,
                                      ground_point, imu_offset_deg, reflector_height_mm, tilt_of_pose)
from calibration.frames import apply_H, make_H, rot_x, rot_y, rot_z
from calibration.measure import robot_pose_at

H_MM = 350.0
#: a calibration's rob_H_scn: SCS plane 350 mm below the reflector, z up
ROB_H_SCN = make_H(np.eye(3), np.array([200.0, 50.0, -H_MM]), "rob_H_scn")


def pose(heading: float, roll: float, pitch: float, P=(0.0, 0.0, 0.0)) -> np.ndarray:
    R = rot_z(math.radians(heading)) @ rot_y(math.radians(pitch)) @ rot_x(math.radians(roll))
    return make_H(R, np.asarray(P, float), "abs_H_rob")


def test_parse_names_and_refusal():
    assert Compensation.parse(None).names() == [] and Compensation.parse("none").names() == []
    assert Compensation.parse("all").names() == ["tilt", "heading_fit", "bias", "mount"]
    assert Compensation.parse("bias, tilt").names() == ["tilt", "bias"]
    with pytest.raises(ValueError, match="'tlit'"):
        Compensation.parse(["tlit"])


def test_a_registered_compensation_runs_after_the_built_in_ones(monkeypatch):
    """The seam docs/architecture.md's "Add a compensation" uses: named, parsed, run after the built-in
    ones (it sees what they applied), its input read from the calibration document, skipped with a reason."""
    seen = []

    def trim(out, stop, calibration):
        seen.append(list(out.applied))
        if calibration.get("yaw_trim_deg") is None:
            out.skipped["trim"] = "the calibration holds no yaw trim"
            return
        out.applied.append("trim")

    monkeypatch.setattr(compensation, "STEPS", {})
    compensation.register("trim")(trim)
    assert Compensation.parse("all").names() == [*compensation.BUILT_IN, "trim"]
    comp = Compensation.parse("trim, bias")
    assert comp.names() == ["bias", "trim"]
    stop = Stop(np.array([0.0, 0.0, H_MM]), np.array([200.0, 0.0, H_MM]))
    a = compensate(comp, stop, ROB_H_SCN, bias_b_mm=[0.01, 0.0], calibration={"yaw_trim_deg": 0.1})
    assert a.applied == ["bias", "trim"] and seen == [["bias"]]
    assert compensate(comp, stop, ROB_H_SCN).skipped["trim"] == "the calibration holds no yaw trim"
    assert "trim" not in compensate(Compensation.parse("bias"), stop, ROB_H_SCN).skipped
    with pytest.raises(ValueError, match="'tilt' is registered twice"):
        compensation.register("tilt")(trim)


def test_the_bus_lists_the_same_compensations():
    """``ritactl validate`` checks names without this package (common.schema.json): the same, in order."""
    import json

    from daemon.bus.datasets import schema_text

    assert json.loads(schema_text("common"))["$defs"]["compensation"]["enum"] == list(compensation.names_known())


def test_tilt_of_pose_round_trip_and_offset():
    H = pose(123.0, 0.07, -0.05)
    assert tilt_of_pose(H) == pytest.approx((0.07, -0.05), abs=1e-12)
    # the inclinometer reads the plate's tilt plus its offset: the offset comes back
    assert imu_offset_deg(H, 0.07 + 0.01, -0.05 - 0.02) == pytest.approx((0.01, -0.02), abs=1e-12)
    with pytest.raises(ValueError, match="roll_deg=nan"):
        imu_offset_deg(H, float("nan"), 0.0)


def test_ground_point_follows_the_tilted_axis():
    assert ground_point([1, 2, 3], 40.0, 0.0, 0.0, H_MM) == pytest.approx([1, 2, 3 - H_MM])
    g = ground_point([0, 0, 0], 90.0, 0.1, 0.0, H_MM)  # rolled while heading +y: the z axis leans to +x
    assert g[0] == pytest.approx(-H_MM * math.sin(math.radians(0.1)), rel=1e-6)
    assert reflector_height_mm(ROB_H_SCN) == pytest.approx(H_MM)


def test_ground_chord_removes_the_tilt_difference():
    """The reflector leans with the floor; the chord between the ground points does not."""
    heading = 30.0
    u = np.array([math.cos(math.radians(heading)), math.sin(math.radians(heading)), 0.0])
    g_prev, g_at = np.zeros(3), 200.0 * u
    tilts = [(0.06, -0.02), (-0.04, 0.05)]  # deg: 1.7 mrad of roll difference
    P_prev, P_at = (apply_H(pose(heading, *t, g), [0, 0, H_MM]) for t, g in zip(tilts, (g_prev, g_at)))
    v_raw = P_at - P_prev
    raw_err = math.atan2(v_raw[1], v_raw[0]) - math.radians(heading)
    assert abs(raw_err) > 1e-3  # ~1.7 mrad of heading error from the tilt alone
    v = P_at - ground_chord(P_prev, P_at, tilts[0], tilts[1], H_MM)
    assert abs(math.atan2(v[1], v[0]) - math.radians(heading)) < 2e-6


def arc(kappa: float, d: float, n: int, heading: float = 0.0) -> np.ndarray:
    s = np.linspace(0.0, d, n)
    a = math.radians(heading)
    # exact circular arc starting at the origin with heading a
    return np.column_stack([(np.sin(a + kappa * s) - math.sin(a)) / kappa,
                            (math.cos(a) - np.cos(a + kappa * s)) / kappa, np.zeros(n)])


def test_fit_heading_finds_the_end_tangent_of_a_bent_move():
    kappa, d = 2.5e-6, 200.0  # 50 µm sideways at the end of 200 mm (the assumed path deviation, docs/accuracy.md)
    P = arc(kappa, d, 41, heading=25.0)
    truth = math.radians(25.0) + kappa * d
    u = fit_heading(P, P[0], P[-1])
    chord = P[-1] - P[0]
    assert abs(math.atan2(chord[1], chord[0]) - truth) > 2e-4  # the chord is off by κd/2 = 250 µrad
    assert abs(math.atan2(u[1], u[0]) - truth) < 1e-6
    rng = np.random.default_rng(3)
    # with noise the fit may keep the chord when the bend is not shown (then fit_heading raises)
    errs = [math.atan2(*bend_fit(P + rng.normal(0, 0.01, P.shape) * [1, 1, 0], P[0], P[-1],
                                 anchor_sigma_mm=0.001).direction[1::-1]) - truth for _ in range(200)]
    assert np.sqrt(np.mean(np.square(errs))) < 1.5e-4  # 10 µm per stream point: better than the chord
    with pytest.raises(ValueError, match="3 stream points"):
        fit_heading(P[:3], P[0], P[-1])


def test_apply_bias_and_its_refusal():
    H = apply_bias(ROB_H_SCN, [0.03, -0.01])
    assert H[:3, 3] == pytest.approx([199.97, 50.01, -H_MM])
    with pytest.raises(ValueError, match="6.000 mm"):
        apply_bias(ROB_H_SCN, [6.0, 0.0])


def test_compensate_says_why_it_skips():
    stop = Stop(np.array([0.0, 0.0, H_MM]), np.array([200.0, 0.0, H_MM]))
    a = compensate(Compensation.parse("all"), stop, ROB_H_SCN)
    assert a.applied == []
    assert set(a.skipped) == {"tilt", "heading_fit", "bias", "mount"}
    assert "offset" in a.skipped["tilt"] and "stream" in a.skipped["heading_fit"]
    assert "no reflector mount offset" in a.skipped["mount"] and a.cov_mount_xy_mm2 is None
    assert np.array_equal(a.rob_H_scn, ROB_H_SCN) and a.roll_deg is None


def test_compensations_beat_the_paper_on_the_simulated_robot():
    """paper+imu world, rendering-free: each seed meets the goals' bounds with every compensation on."""
    from fakes.accuracy import Case, run

    for seed in (100, 101):
        off = run(Case("paper+imu"), seed)
        on = run(Case("paper+imu", Compensation.parse("all")), seed)
        assert on["enclosing_mm"] <= 0.25 and on["pairwise_mm"] <= 0.07 and on["abs_rms_mm"] <= 0.10, on
        assert on["abs_rms_mm"] < off["abs_rms_mm"] and on["pairwise_mm"] < off["pairwise_mm"]


@pytest.mark.parametrize("roll, pitch", [(0.3, -0.2), (-0.5, 0.4)])
def test_a_backward_approach_gives_the_forward_result(roll, pitch):
    """MOVE < 0 onto the stop (``reverse``): the same robot pose as driving forward onto it."""
    heading, d = 30.0, 200.0
    H_at = pose(heading, roll, pitch, (1000.0, 500.0, 0.0))
    refl = np.array([0.0, 0.0, H_MM])  # the reflector above the robot's origin
    P_at = apply_H(H_at, refl)
    x = H_at[:3, 0] * [1, 1, 0] / np.linalg.norm(H_at[:3, 0][:2])
    tilt = (roll + 0.01, pitch - 0.01)  # the floor tilts a little differently where the approach began
    poses = []
    for reverse in (False, True):
        start = H_at[:3, 3] - (-d if reverse else d) * x  # behind the stop, or ahead of it driving backwards
        H_prev = pose(heading, *tilt, start)
        stop = Stop(apply_H(H_prev, refl), P_at, tilt, (roll, pitch), reverse=reverse)
        a = compensate(Compensation(tilt=True), stop, ROB_H_SCN, imu_offset=(0.0, 0.0))
        assert a.applied == ["tilt"]
        poses.append(robot_pose_at(a.abs_P_prev, P_at, roll_deg=a.roll_deg, pitch_deg=a.pitch_deg))
    assert np.allclose(poses[0], poses[1], atol=1e-9)
    assert np.allclose(poses[0][:3, :3], H_at[:3, :3], atol=2e-5)  # and it is the robot's true attitude
    mark = [300.0, -40.0, -H_MM]
    assert np.linalg.norm(apply_H(poses[0], mark) - apply_H(poses[1], mark)) < 0.010


def test_a_backward_approach_with_an_eccentric_mount_gives_the_true_pose():
    """MOVE < 0 with the mount's offset shown: the offset (fixed toward the tracker, whichever way the
    robot drove) comes off every point before the direction of travel is read, so backward = forward = truth."""
    from calibration.mount import MountOffset

    heading, d, roll, pitch = 120.0, 200.0, 0.4, -0.3
    trk = np.array([-1500.0, 3000.0, 1200.0])
    m = MountOffset(np.array([0.10, -0.04]), np.diag([1e-4, 1e-4]), True)
    H_at = pose(heading, roll, pitch, (1000.0, 500.0, 0.0))
    refl = np.array([0.0, 0.0, H_MM])
    seen = lambda P: P + m.offset_abs(P, trk)  # noqa: E731 (what the tracker measures of an eccentric reflector)
    x = H_at[:3, 0] * [1, 1, 0] / np.linalg.norm(H_at[:3, 0][:2])
    poses = []
    for reverse in (False, True):
        H_prev = pose(heading, roll + 0.01, pitch - 0.01, H_at[:3, 3] - (-d if reverse else d) * x)
        stop = Stop(seen(apply_H(H_prev, refl)), seen(apply_H(H_at, refl)), (roll + 0.01, pitch - 0.01), (roll, pitch),
                    reverse=reverse)
        a = compensate(Compensation(tilt=True, mount=True), stop, ROB_H_SCN, imu_offset=(0.0, 0.0), mount=m,
                       abs_t_trk=trk)
        assert a.applied == ["mount", "tilt"], a.skipped
        poses.append(robot_pose_at(a.abs_P_prev, a.abs_P_at, roll_deg=a.roll_deg, pitch_deg=a.pitch_deg))
    mark = [300.0, -40.0, -H_MM]  # in the pose robot_pose_at gives: the robot's axes at the reflector
    H_refl = H_at.copy()
    H_refl[:3, 3] = apply_H(H_at, refl)
    truth = apply_H(H_refl, mark)
    for P in poses:  # the offset turns by ~0.01° over the move: what is left is well under a micrometre
        assert np.linalg.norm(apply_H(P, mark) - truth) < 0.002, np.linalg.norm(apply_H(P, mark) - truth)
    # without the mount, each direction is off by the offset (and the two by the same amount)
    b = compensate(Compensation(tilt=True), stop, ROB_H_SCN, imu_offset=(0.0, 0.0))
    off = apply_H(robot_pose_at(b.abs_P_prev, b.abs_P_at, roll_deg=b.roll_deg, pitch_deg=b.pitch_deg), mark) - truth
    assert 0.09 < np.linalg.norm(off[:2]) < 0.12
