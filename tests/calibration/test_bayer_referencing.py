"""Referencing from a BayerRG8 rendering meets the acceptance thresholds like Mono8
(docs/accuracy.md).

The Mono8 case is tests/calibration/test_calibration_sim.py's rendered fixture: the same
world, seed, pose and noise stream, so the only difference here is the sensor, the RGGB
colour filter (fakes.colour) and the demosaicing to grey (calibration.image.to_grey) before
corner detection; the thresholds asserted are the same. Like that test (whose helpers this
reuses), the referencing is given the world's camera model and plate definition: replacing
them by estimated ones is tested elsewhere (test_worker_e2e.py, test_plate_survey.py), not here.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from calibration.image import to_grey
from calibration.referencing import rob_H_cam_error
from calibration.scs import make_scs
from calibration.target import estimate_cam_H_ref
from fakes.simulate import SimConfig, Simulation
from fakes.world import World, WorldParams
from tests.calibration.test_calibration_sim import SIGMA_T, run_reference, true_footprint_error


@pytest.fixture(scope="module", params=["BayerRG8", "BayerRG12p"])
def visit(request):
    world = World(WorldParams(seed=61))
    sim = Simulation(world, SimConfig(seed=61, render=True, sigma_t_mm=0.0, pixel_format=request.param))
    obs = sim.calibration()
    assert obs.pixel_format == request.param and obs.image.ndim == 2
    grey = to_grey(obs.image, obs.pixel_format)
    return world, sim, replace(obs, image=grey), estimate_cam_H_ref(grey, sim.model, sim.plate)


def test_without_tracker_noise(visit):
    world, sim, obs, _ = visit
    res = run_reference(sim, obs, sigma_t=0.0)
    err = rob_H_cam_error(res.rob_H_cam, world.rob_H_cam)
    foot = true_footprint_error(sim, res)
    bias = np.linalg.norm(sim.true_bias(res.rob_H_scn, make_scs(sim.model, res.cam_H_ref)))
    print(f"{sim.cfg.pixel_format}: footprint {foot * 1e3:.2f} µm, bias {bias * 1e3:.2f} µm, "
          f"t {np.hypot(err['t_xy_mm'], err['t_z_mm']) * 1e3:.2f} µm, rot {err['rot_deg']:.5f}°, "
          f"{res.n_corners} corners")
    assert foot < 0.005 and bias < 0.005
    assert err["rot_deg"] < 0.01 and np.hypot(err["t_xy_mm"], err["t_z_mm"]) < 0.020, err
    assert res.verdict == "ok" and res.n_corners > 300 and res.ambiguity_ratio > 5


def test_nominal_tracker_noise(visit):
    world, sim, obs, cam_ref = visit
    rng = np.random.default_rng(7)
    for _ in range(3):  # three tracker-noise draws on the same image, as for Mono8
        noisy = replace(obs, image=None, cam_ref=cam_ref)
        noisy.abs_P_nests = obs.abs_P_nests + rng.normal(0, SIGMA_T, (3, 3))
        noisy.abs_P_rob0 = obs.abs_P_rob0 + rng.normal(0, SIGMA_T, 3)
        noisy.abs_P_rob1 = obs.abs_P_rob1 + rng.normal(0, SIGMA_T, 3)
        err = rob_H_cam_error(run_reference(sim, noisy).rob_H_cam, world.rob_H_cam)
        print(f"{sim.cfg.pixel_format}: t_xy {err['t_xy_mm'] * 1e3:.1f} µm, t_z {err['t_z_mm'] * 1e3:.1f} µm, "
              f"rot {err['rot_deg']:.4f}°")
        assert err["t_xy_mm"] < 0.06 and err["t_z_mm"] < 0.045 and err["rot_deg"] < 0.015, err
