"""The reflector mount's offset: measured by the reversal, applied only when shown, covered by the stated σ."""
from __future__ import annotations

import numpy as np
import pytest

from calibration.compensation import Compensation, Stop, compensate
from calibration.measure import measure_mark
from calibration.mount import MAX_OFFSET_MM, MountOffset, estimate, los_R
from calibration.referencing import reference
from calibration.scs import make_scs
from fakes import profiles
from fakes.accuracy import Case, referencing, run
from fakes.simulate import SimConfig, Simulation
from fakes.world import World, WorldParams

TRK = np.array([0.0, 5000.0, 1200.0])
COV = np.diag([1e-4, 1e-4])  # (10 µm)²


def test_the_line_of_sight_frame():
    R = los_R([1000.0, 1000.0, 350.0], TRK)
    assert np.linalg.det(R) == pytest.approx(1.0) and R[:, 2] == pytest.approx([0, 0, 1])
    toward = (TRK - [1000.0, 1000.0, 350.0])[:2]
    assert R[:2, 0] == pytest.approx(toward / np.linalg.norm(toward))
    m = MountOffset(np.array([0.1, 0.0]), COV, True)
    assert m.offset_abs([1000.0, 1000.0, 350.0], TRK)[:2] == pytest.approx(0.1 * toward / np.linalg.norm(toward))
    with pytest.raises(ValueError, match="not beside"):
        los_R([0.0, 5000.0, 0.0], TRK)


def _world(seed: int, ecc: float) -> Simulation:
    p = profiles.apply("paper+imu", WorldParams(seed=seed))
    world = World(p.with_(errors=p.errors.tweaked((("reflector", "mount_eccentricity_mm", ecc),))))
    return Simulation(world, SimConfig(seed=seed, pnp_sigma_px=0.05, report_tilt=True))


def _truth_los(sim: Simulation, abs_H_rob: np.ndarray) -> np.ndarray:
    w = sim.world
    m = w.effects.robot_reflector(abs_H_rob) - abs_H_rob[:3, 3]
    return los_R(abs_H_rob[:3, 3], w.abs_H_trk[:3, 3])[:, :2].T @ m


@pytest.mark.parametrize("seed", [100, 101, 102, 103])
def test_the_reversal_measures_a_0_1_mm_eccentricity_within_its_sigma(seed):
    sim = _world(seed, 0.1)
    cal = referencing(sim, reversal=True)
    assert cal.mount is not None and cal.mount.significant, cal.mount
    obs = sim.calibration(stream="calib")  # the same first visit again: its true pose
    e = cal.mount.los_mm - _truth_los(sim, obs.abs_H_rob_true)
    assert float(e @ np.linalg.solve(cal.mount.cov_los_mm2, e)) < 3.0 ** 2
    assert np.linalg.norm(e) < 0.035


def test_no_eccentricity_is_rarely_applied():
    applied = [referencing(_world(seed, 0.0), reversal=True).mount.significant for seed in range(100, 110)]
    assert sum(applied) <= 1


def test_the_absolute_error_of_an_eccentric_mount_is_removed():
    """The default compensation with the reversal: the 0.1 mm eccentricity no longer reaches the marks."""
    tweak = (("reflector", "mount_eccentricity_mm", 0.1),)
    with_mount = [run(Case("paper+imu", Compensation.parse("tilt,bias,mount"), tweak=tweak), s) for s in (100, 101, 102)]
    without = [run(Case("paper+imu", Compensation.parse("tilt,bias"), tweak=tweak), s) for s in (100, 101, 102)]
    assert max(r["abs_rms_mm"] for r in with_mount) < 0.085 < 0.10 < min(r["abs_rms_mm"] for r in without)
    ratio = np.concatenate([r["err_mm"] / r["std_mm"] for r in with_mount])
    assert np.percentile(ratio, 95) < 1.73  # the stated σ covers the error (χ², 2 dof)


#: an anisotropic covariance (mm²): a transposed rotation would show
COV_ANISO = np.array([[4e-4, 1e-4], [1e-4, 1e-4]])


def _stop() -> Stop:
    P_at = np.array([1000.0, 1000.0, 350.0])
    stream = np.linspace([800.0, 900.0, 350.0], P_at, 21)
    return Stop(np.array([800.0, 900.0, 350.0]), P_at, stream=stream)


def test_compensate_removes_a_shown_offset_from_every_tracker_point():
    """Each point loses the offset turned to its own line of sight (the tracker 2.3 m away: 5° over the move)."""
    trk = np.array([-1000.0, 2500.0, 1200.0])
    m = MountOffset(np.array([0.08, -0.03]), COV_ANISO, True)
    a = compensate(Compensation(mount=True), _stop(), np.eye(4), mount=m, abs_t_trk=trk)
    s = _stop()
    assert a.applied == ["mount"]
    assert a.abs_P_at == pytest.approx(s.abs_P_at - m.offset_abs(s.abs_P_at, trk))
    assert a.abs_P_prev == pytest.approx(s.abs_P_prev - m.offset_abs(s.abs_P_prev, trk))
    turn = np.linalg.norm(m.offset_abs(s.abs_P_prev, trk) - m.offset_abs(s.abs_P_at, trk))
    assert turn > 0.005  # µm-level: one offset for the whole move would be wrong by this much
    R = los_R(s.abs_P_at, trk)[:2, :2]
    assert a.cov_mount_xy_mm2 == pytest.approx(R @ COV_ANISO @ R.T)
    assert not np.allclose(a.cov_mount_xy_mm2, R.T @ COV_ANISO @ R)


def test_an_offset_not_shown_is_skipped_and_stated_in_sigma():
    m = MountOffset(np.array([0.02, 0.0]), COV_ANISO, False, "not shown by the data")
    a = compensate(Compensation(mount=True), _stop(), np.eye(4), mount=m, abs_t_trk=TRK)
    assert a.applied == [] and a.skipped["mount"] == "not shown by the data"
    assert a.abs_P_at == pytest.approx(_stop().abs_P_at)
    assert np.trace(a.cov_mount_xy_mm2) == pytest.approx(5e-4 + 0.02 ** 2)
    b = compensate(Compensation(mount=True), _stop(), np.eye(4), mount=m, abs_t_trk=None)
    assert "abs_H_trk" in b.skipped["mount"] and b.cov_mount_xy_mm2 is None


def test_measure_mark_states_the_mount_part():
    sim = Simulation(World(WorldParams(seed=31)), SimConfig(seed=31))
    obs = sim.calibration()
    res = reference(sim.model, sim.plate, obs.abs_P_nests, obs.abs_P_rob0, obs.abs_P_rob1, cam_ref=obs.cam_ref,
                    mc_samples=0)
    scs, o = make_scs(sim.model, res.cam_H_ref), sim.validation().observations[0]
    plain = measure_mark(o.uv, scs, res.rob_H_scn, o.abs_P_prev, o.abs_P_at)
    m = measure_mark(o.uv, scs, res.rob_H_scn, o.abs_P_prev, o.abs_P_at, cov_mount_xy_mm2=np.diag([9e-4, 16e-4]))
    assert m.std_parts_mm["mount"] == pytest.approx(0.05) and "mount" not in plain.std_parts_mm
    assert m.std_mm == pytest.approx(np.hypot(plain.std_mm, 0.05))
    with pytest.raises(ValueError, match="cov_mount_xy_mm2"):
        measure_mark(o.uv, scs, res.rob_H_scn, o.abs_P_prev, o.abs_P_at, cov_mount_xy_mm2=[1.0, 2.0])


def _estimate(half_t, headings=(0.0, 180.0)):
    H0 = np.eye(4)
    H0[:3, 3] = [1000.0, 1000.0, 350.0]
    scn = np.eye(4)
    scn[:3, 3] = [200.0, 0.0, -350.0]
    return estimate(half_t, [0.0, 0.0, 0.0], scn, H0, TRK, np.diag([1e-4] * 3 + [1e-9] * 3), list(headings))


def test_estimate_refuses_what_no_mount_can_give():
    assert _estimate([-0.1, 0.0, 0.0]).significant
    turned = _estimate([-0.1, 0.0, 0.0], headings=(0.0, 140.0))
    assert not turned.significant and "not 180°" in turned.why and not turned.warn
    big = _estimate([-1.5, 0.0, 0.0])
    assert not big.significant and f"{MAX_OFFSET_MM}" in big.why and big.warn
    small = _estimate([-0.015, 0.0, 0.0])
    assert not small.significant and "not shown" in small.why and not small.warn
    assert MountOffset.from_dict(big.to_dict()).los_mm == pytest.approx(big.los_mm)
    with pytest.raises(ValueError, match="reflector_mount"):
        MountOffset.from_dict({"los_mm": [0.1], "cov_los_mm2": COV.tolist(), "significant": True})
