"""The accuracy harness's stated σ and its restatement (bench/accuracy_envelope.py's coverage columns)."""
from __future__ import annotations

import numpy as np
import pytest

from bench.accuracy_envelope import DEFAULT, restated
from calibration.measure import measure_mark
from calibration.referencing import reference
from calibration.scs import make_scs
from fakes import profiles
from fakes.accuracy import measure_all
from fakes.simulate import SimConfig, Simulation
from fakes.world import World, WorldParams


def test_restated_sigma_equals_measuring_with_that_tracker_sigma_plus_the_heading_term():
    world = World(profiles.apply("paper", WorldParams(seed=3)))
    sim = Simulation(world, SimConfig(seed=3, pnp_sigma_px=0.05, directions=2, repetitions=1))
    obs = sim.calibration()
    res = reference(sim.model, sim.plate, obs.abs_P_nests, obs.abs_P_rob0, obs.abs_P_rob1, cam_ref=obs.cam_ref,
                    mc_samples=50)
    scs, cov = make_scs(sim.model, res.cam_H_ref), res.uncertainty.cov_rob_H_scn
    val = sim.validation()
    pts, _, sig = measure_all(val, DEFAULT, scs, res.rob_H_scn, None, None, cov)
    row = {"std_mm": sig[:, 0], "t_unit_mm2": sig[:, 1], "lever_mm": sig[:, 2]}
    direct = np.array([measure_mark(o.uv, scs, res.rob_H_scn, o.abs_P_prev, o.abs_P_at, sigma_t_mm=0.022,
                                    cov_rob_H_scn=cov).std_mm for o in val.observations])
    np.testing.assert_allclose(restated(row, sigma_t_mm=0.022), direct, rtol=1e-9)
    np.testing.assert_allclose(restated(row), row["std_mm"], rtol=1e-12)
    with_heading = restated(row, heading_rad=2.5e-4)
    np.testing.assert_allclose(with_heading ** 2 - row["std_mm"] ** 2, (2.5e-4 * row["lever_mm"]) ** 2, rtol=1e-9)
    assert row["lever_mm"] == pytest.approx(np.hypot(200.0, 50.0), abs=10.0)  # the camera footprint's offset
    assert np.all(row["std_mm"] > 0) and len(pts) == 2
