"""The accuracy harness's stated σ (as the product states it, issue #20) and its restatement
(bench/accuracy_envelope.py's coverage columns), and a seeded coverage check of that σ."""
from __future__ import annotations

import numpy as np
import pytest

from bench.accuracy_envelope import CASES, DEFAULT, HONEST_RATIO, coverage, restated
from calibration.measure import CHORD_HEADING_SIGMA_RAD, measure_mark, tracker_sigma_mm
from calibration.referencing import reference
from calibration.scs import make_scs
from fakes import profiles
from fakes.accuracy import measure_all, run
from fakes.simulate import SimConfig, Simulation
from fakes.world import World, WorldParams


def test_stated_sigma_is_the_products_and_the_old_one_restates_to_it():
    world = World(profiles.apply("paper", WorldParams(seed=3)))
    sim = Simulation(world, SimConfig(seed=3, pnp_sigma_px=0.05, directions=2, repetitions=1))
    obs = sim.calibration()
    res = reference(sim.model, sim.plate, obs.abs_P_nests, obs.abs_P_rob0, obs.abs_P_rob1,
                    cam_ref=obs.cam_ref, mc_samples=50)
    scs, cov = make_scs(sim.model, res.cam_H_ref), res.uncertainty.cov_rob_H_scn
    val = sim.validation()
    trk = world.abs_H_trk[:3, 3]
    pts, _, sig = measure_all(val, DEFAULT, scs, res.rob_H_scn, None, None, cov, abs_t_trk=trk)
    row = {"std_mm": sig[:, 0], "t_unit_mm2": sig[:, 1], "lever_mm": sig[:, 2], "std_old_mm": sig[:, 3],
           "sigma_t_mm": sig[:, 5]}
    for o, s_t in zip(val.observations, row["sigma_t_mm"]):
        d = max(np.linalg.norm(o.abs_P_prev - trk), np.linalg.norm(o.abs_P_at - trk))
        assert s_t == pytest.approx(tracker_sigma_mm(d)) and 0.018 < s_t < 0.026  # the marks are ~4-5 m away
    old = np.array([measure_mark(o.uv, scs, res.rob_H_scn, o.abs_P_prev, o.abs_P_at, cov_rob_H_scn=cov).std_mm
                    for o in val.observations])
    new = np.array([measure_mark(o.uv, scs, res.rob_H_scn, o.abs_P_prev, o.abs_P_at, cov_rob_H_scn=cov,
                                 sigma_t_mm=s, sigma_heading_rad=CHORD_HEADING_SIGMA_RAD).std_mm
                    for o, s in zip(val.observations, row["sigma_t_mm"])])
    np.testing.assert_allclose(row["std_old_mm"], old, rtol=1e-9)
    np.testing.assert_allclose(row["std_mm"], new, rtol=1e-9)
    np.testing.assert_allclose(restated(row), old, rtol=1e-9)
    # the old σ restated with the new tracker σ and the chord's heading term is the new one (the lever arm
    # from the robot frame's xy: the robot stands upright in this world's stops without a tilt compensation)
    np.testing.assert_allclose(restated(row, sigma_t_mm=row["sigma_t_mm"],
                                        heading_rad=CHORD_HEADING_SIGMA_RAD),
                               row["std_mm"], rtol=1e-6)
    assert row["lever_mm"] == pytest.approx(np.hypot(200.0, 50.0), abs=10.0)  # the camera footprint's offset
    assert np.all(row["std_mm"] > 2 * row["std_old_mm"]) and len(pts) == 2
    assert np.all(sig[:, 4] == pytest.approx(CHORD_HEADING_SIGMA_RAD * row["lever_mm"], rel=1e-3))


#: the coverage check's seeds (8 × 40 stops = 320 marks) and its bound: an honest Gaussian σ gives p95 1.73;
#: 1.25× that leaves room for the p95's sampling scatter over 320 correlated stops
COVERAGE_SEEDS = tuple(range(200, 208))
P95_BOUND = 1.25 * HONEST_RATIO[1]


@pytest.fixture(scope="module")
def baseline_rows():
    """The envelope's baseline (paper+imu, the default compensation) over the check's seeds."""
    return [run(CASES[0], s) for s in COVERAGE_SEEDS]


def test_the_stated_sigma_covers_the_error_on_a_seeded_harness_run(baseline_rows):
    """p95 of |error| / std_mm within 1.25 × 1.73 with the σ the product states; the σ it stated before
    issue #20 (10 µm, no heading term) fails the same bound (about 3.5 on the envelope's 40 seeds)."""
    p50, p95 = coverage(baseline_rows, "std_mm")
    old50, old95 = coverage(baseline_rows, "std_old_mm")
    assert p95 <= P95_BOUND, (p50, p95)
    assert old95 > P95_BOUND, (old50, old95)  # the check can fail: it does on the old σ
    assert p50 > 0.4, p50  # and σ is not inflated beyond use (an honest σ: 0.83)
