"""compute_referencing (live run and ``ritactl recompute``) hands camera_model.json to the camera-model check."""
from __future__ import annotations

import pytest

from calibration.plate import NEST_NAMES
from daemon.compute.procedures import compute_referencing
from fakes.simulate import SimConfig, Simulation
from fakes.world import World, WorldParams


def test_result_carries_the_check_and_reads_the_model_std():
    # a small rendering keeps this wiring test cheap; the check's figures are tested in tests/calibration
    sim = Simulation(World(WorldParams(seed=2)), SimConfig(seed=2, render=True, size=(500, 375)))
    obs = sim.calibration()
    f = sim.model.K[0, 0]
    state = {"camera_model": {**sim.model.to_dict(), "std": {"fx": 0.005 * f, "fy": 0.005 * f}},
             "plate": sim.plate.to_dict(),
             "nests": {n: {"abs_xyz": p.tolist()} for n, p in zip(NEST_NAMES, obs.abs_P_nests)},
             "runs": [{"P0": {"abs_xyz": obs.abs_P_rob0.tolist()}, "P1": {"abs_xyz": obs.abs_P_rob1.tolist()},
                       "image": "run0.png"}], "sigma_t_mm": sim.cfg.sigma_t_mm}
    out = compute_referencing(state, lambda name: obs.image)
    check = out["runs"][0]["model_check"]
    assert check["model_sigma_f_rel"] == pytest.approx(0.005) and check["verdict"] == "warn"
    assert out["verdict"] == "warn"
    assert any(m.startswith("camera model: its calibration gives the focal length") for m in out["messages"])
    without = compute_referencing({**state, "camera_model": sim.model.to_dict()}, lambda name: obs.image)
    assert without["runs"][0]["model_check"]["model_sigma_f_rel"] is None
