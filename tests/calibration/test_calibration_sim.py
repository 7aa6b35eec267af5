"""End-to-end simulation protocol (docs/accuracy.md, "Reference figures") scored against the world's truth.

Rendered: one referencing image at 1000×750 (with and without tracker noise on the
same image) and, when the mark locator is available, one rendered 8×5 validation
run. Rendering-free: several seeds with PnP on noisy projected corners and marks at
projected truth + 0.05 px.
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from calibration.measure import measure_image, measure_mark
from calibration.metrics import experiment_metrics
from calibration.referencing import reference, rob_H_cam_error
from calibration.reversal import combine
from calibration.scs import make_scs
from fakes.simulate import SimConfig, Simulation
from calibration.target import estimate_cam_H_ref
from calibration.uncertainty import footprint
from fakes.world import World, WorldParams

SIGMA_T = 0.010
BIAS = ((0.1, 0.0, 0.0), (0.0, -0.07, 0.07), (-0.05, 0.05, -0.07))


def run_reference(sim: Simulation, obs, sigma_t=SIGMA_T, **kw):
    kw.setdefault("mc_samples", 50)
    if obs.image is not None:
        return reference(sim.model, sim.plate, obs.abs_P_nests, obs.abs_P_rob0, obs.abs_P_rob1, image=obs.image,
                         sigma_t_mm=max(sigma_t, 1e-3), **kw)
    return reference(sim.model, sim.plate, obs.abs_P_nests, obs.abs_P_rob0, obs.abs_P_rob1, cam_ref=obs.cam_ref,
                     sigma_t_mm=max(sigma_t, 1e-3), **kw)


def validate(sim: Simulation, res, scs, val=None):
    """Measure every validation stop; return the metrics and the measured points."""
    val = val or sim.validation()
    pts = np.array([measure_mark(o.uv, scs, res.rob_H_scn, o.abs_P_prev, o.abs_P_at, roll_deg=o.roll_deg,
                                 pitch_deg=o.pitch_deg).abs_P for o in val.observations])
    v = np.array([o.abs_P_at - o.abs_P_prev for o in val.observations])
    hs = np.degrees(np.arctan2(v[:, 1], v[:, 0]))  # measured approach headings
    return experiment_metrics(pts, hs), pts, val


def true_footprint_error(sim: Simulation, res) -> float:
    p = sim.world.params
    true = np.array([*p.cam_footprint_mm, -p.reflector_height_mm])
    return float(np.linalg.norm((footprint(res.rob_H_cam, res.rob_H_scn) - true)[:2]))


def assert_nominal_metrics(m, mark_abs):
    assert m.enclosing_diameter_mm < 0.22, m.enclosing_diameter_mm
    assert m.pairwise_mean_mm < 0.09, m.pairwise_mean_mm
    assert max(c.max_from_mean_mm for c in m.clusters) < 0.08
    assert np.linalg.norm(np.array(m.all.mean) - mark_abs[:2]) < 0.07


# ---------------------------------------------------------------------------- rendered


@pytest.fixture(scope="module")
def rendered():
    world = World(WorldParams(seed=61))
    sim = Simulation(world, SimConfig(seed=61, render=True, sigma_t_mm=0.0))
    obs = sim.calibration()
    return world, sim, obs, estimate_cam_H_ref(obs.image, sim.model, sim.plate)


def test_rendered_referencing_without_tracker_noise(rendered):
    world, sim, obs, _ = rendered
    res = run_reference(sim, obs, sigma_t=0.0)  # the whole path from the image
    err = rob_H_cam_error(res.rob_H_cam, world.rob_H_cam)
    assert true_footprint_error(sim, res) < 0.005
    assert np.linalg.norm(sim.true_bias(res.rob_H_scn, make_scs(sim.model, res.cam_H_ref))) < 0.005
    assert err["rot_deg"] < 0.01 and np.hypot(err["t_xy_mm"], err["t_z_mm"]) < 0.020, err
    assert res.verdict == "ok" and res.n_corners > 300 and res.ambiguity_ratio > 5


def test_rendered_referencing_nominal_tracker_noise(rendered):
    world, sim, obs, cam_ref = rendered
    rng = np.random.default_rng(7)
    for _ in range(3):  # three tracker-noise draws on the same image
        noisy = replace(obs, image=None, cam_ref=cam_ref)
        noisy.abs_P_nests = obs.abs_P_nests + rng.normal(0, SIGMA_T, (3, 3))
        noisy.abs_P_rob0 = obs.abs_P_rob0 + rng.normal(0, SIGMA_T, 3)
        noisy.abs_P_rob1 = obs.abs_P_rob1 + rng.normal(0, SIGMA_T, 3)
        res = run_reference(sim, noisy)
        err = rob_H_cam_error(res.rob_H_cam, world.rob_H_cam)
        assert err["t_xy_mm"] < 0.06 and err["t_z_mm"] < 0.045 and err["rot_deg"] < 0.015, err
        assert 0.003 < res.uncertainty.footprint_std_mm < 0.05


@pytest.fixture(scope="module")
def rendered_validation(rendered):
    """40 rendered validation images (1000×750), located once; tracker noise is added per test."""
    world, sim, _, _ = rendered
    return sim.validation()


def test_rendered_validation_without_tracker_noise(rendered, rendered_validation):
    world, sim, obs, cam_ref = rendered
    res = run_reference(sim, replace(obs, image=None, cam_ref=cam_ref), sigma_t=0.0, mc_samples=0)
    m, _, val = validate(sim, res, make_scs(sim.model, res.cam_H_ref), rendered_validation)
    # the acceptance thresholds: all 8-direction metrics < 10 µm without tracker noise
    assert m.enclosing_diameter_mm < 0.010, m.enclosing_diameter_mm
    assert m.pairwise_mean_mm < 0.010 and max(c.max_from_mean_mm for c in m.clusters) < 0.010
    assert np.linalg.norm(np.array(m.all.mean) - val.mark_abs[:2]) < 0.010
    assert np.linalg.norm(np.array(m.fit.M) - val.mark_abs[:2]) < 0.010


def test_rendered_validation_nominal(rendered, rendered_validation):
    world, sim, obs, cam_ref = rendered
    rng = np.random.default_rng(11)
    noisy_cal = replace(obs, image=None, cam_ref=cam_ref, abs_P_nests=obs.abs_P_nests + rng.normal(0, SIGMA_T, (3, 3)),
                        abs_P_rob0=obs.abs_P_rob0 + rng.normal(0, SIGMA_T, 3),
                        abs_P_rob1=obs.abs_P_rob1 + rng.normal(0, SIGMA_T, 3))
    res = run_reference(sim, noisy_cal, mc_samples=0)
    val = replace(rendered_validation, observations=[
        replace(o, abs_P_prev=o.abs_P_prev + rng.normal(0, SIGMA_T, 3), abs_P_at=o.abs_P_at + rng.normal(0, SIGMA_T, 3))
        for o in rendered_validation.observations])
    m, _, _ = validate(sim, res, make_scs(sim.model, res.cam_H_ref), val)
    assert_nominal_metrics(m, val.mark_abs)
    table = m.to_markdown()
    assert table.count("\n| ") >= 9  # 8 directions + All


def test_measure_image_on_a_rendered_stop(rendered, rendered_validation):
    world, sim, obs, cam_ref = rendered
    res = run_reference(sim, replace(obs, image=None, cam_ref=cam_ref), sigma_t=0.0, mc_samples=0)
    scs = make_scs(sim.model, res.cam_H_ref)
    o = rendered_validation.observations[7]
    image = sim.renderer.render(o.abs_H_rob_true @ world.rob_H_cam, rng=np.random.default_rng(3))
    m = measure_image(image, scs, res.rob_H_scn, o.abs_P_prev, o.abs_P_at, kind=sim.mark.kind,
                      mark_size_mm=sim.mark.size_mm)
    assert np.linalg.norm(m.uv - o.uv_true) < 0.3
    assert np.linalg.norm(m.abs_P[:2] - rendered_validation.mark_abs[:2]) < 0.010


# ---------------------------------------------------------------------------- rendering-free


@pytest.mark.parametrize("seed", [71, 72, 73, 74, 75])
def test_nominal_pipeline_rendering_free(seed):
    world = World(WorldParams(seed=seed))
    sim = Simulation(world, SimConfig(seed=seed, pnp_sigma_px=0.05))
    res = run_reference(sim, sim.calibration())
    err = rob_H_cam_error(res.rob_H_cam, world.rob_H_cam)
    assert err["t_xy_mm"] < 0.06 and err["t_z_mm"] < 0.045 and err["rot_deg"] < 0.015, err
    scs = make_scs(sim.model, res.cam_H_ref)
    m, _, val = validate(sim, res, scs)
    assert len(m.clusters) == 8 and all(c.n == 5 for c in m.clusters)
    assert_nominal_metrics(m, val.mark_abs)


def test_no_noise_rendering_free_metrics_vanish():
    world = World(WorldParams(seed=76))
    sim = Simulation(world, SimConfig(seed=76, sigma_t_mm=0.0, mark_sigma_px=0.0))
    res = run_reference(sim, sim.calibration(), sigma_t=0.0, mc_samples=0)
    m, _, val = validate(sim, res, make_scs(sim.model, res.cam_H_ref))
    assert m.enclosing_diameter_mm < 1e-6 and m.pairwise_mean_mm < 1e-6 and m.fit.b_norm_mm < 1e-6
    assert np.linalg.norm(np.array(m.fit.M) - val.mark_abs[:2]) < 1e-6


@pytest.mark.parametrize("seed", [81, 82, 83])
def test_circle_fit_recovers_bias_and_mark(seed):
    """Injected 0.1 mm nest bias + tracker noise: the 8-direction fit finds M and the true b."""
    world = World(WorldParams(seed=seed, nest_definition_bias_mm=BIAS))
    sim = Simulation(world, SimConfig(seed=seed))
    res = run_reference(sim, sim.calibration(), sigma_plate_mm=0.1, mc_samples=0)
    scs = make_scs(sim.model, res.cam_H_ref)
    m, _, val = validate(sim, res, scs)
    b_true = sim.true_bias(res.rob_H_scn, scs)
    assert np.linalg.norm(b_true) > 0.01  # the bias is there to be found
    assert np.linalg.norm(np.array(m.fit.b) - b_true) < 0.010, (m.fit.b, b_true)
    assert np.linalg.norm(np.array(m.fit.M) - val.mark_abs[:2]) < 0.010


def test_reversal_then_validation_removes_plate_bias():
    world = World(WorldParams(seed=84, nest_definition_bias_mm=BIAS))
    sim = Simulation(world, SimConfig(seed=84, sigma_t_mm=0.0, mark_sigma_px=0.0))
    a = run_reference(sim, sim.calibration(heading_deg=20.0, stream="a"), sigma_plate_mm=0.1, mc_samples=0)
    b = run_reference(sim, sim.calibration(heading_deg=200.0, stream="b"), sigma_plate_mm=0.1, mc_samples=0)
    scs = make_scs(sim.model, a.cam_H_ref)
    single, _, _ = validate(sim, a, scs)
    rev = combine([a, b])
    both, _, _ = validate(sim, rev, scs)
    assert single.fit.b_norm_mm > 0.01
    assert both.fit.b_norm_mm < 0.001 and both.enclosing_diameter_mm < 0.002


def test_sim_config_and_world_checks():
    with pytest.raises(ValueError, match="sigma_t_mm"):
        SimConfig(sigma_t_mm=-0.01)
    with pytest.raises(ValueError, match="move_mm"):
        SimConfig(move_mm=0.0)
    world = World(WorldParams(seed=90))
    with pytest.raises(ValueError, match="M9"):
        Simulation(world, SimConfig(mark="M9"))
    # a mark on the plate cannot be approached from the floor
    from fakes.world import FloorMark

    on_plate = World(WorldParams(seed=90, marks=(FloorMark("P", *WorldParams().plate_xy_mm),)))
    with pytest.raises(ValueError, match="on the plate"):
        Simulation(on_plate, SimConfig(mark="P")).validation()
    # same seed, same observations; another seed, other noise
    a = Simulation(world, SimConfig(seed=1)).calibration()
    b = Simulation(world, SimConfig(seed=1)).calibration()
    c = Simulation(world, SimConfig(seed=2)).calibration()
    assert np.array_equal(a.abs_P_nests, b.abs_P_nests) and not np.array_equal(a.abs_P_nests, c.abs_P_nests)
