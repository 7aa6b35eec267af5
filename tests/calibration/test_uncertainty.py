"""Monte Carlo covariance of rob_H_cam against the empirical scatter of simulated runs."""
from __future__ import annotations

import numpy as np
import pytest

from calibration.frames import inv_H, make_H, rot_x
from calibration.referencing import chain, reference_pose
from fakes.simulate import SimConfig, Simulation
from calibration.target import pose_from_corners
from calibration.uncertainty import footprint, monte_carlo, perturb_pose, pnp_covariance, pose_delta
from fakes.render import true_corner_projections
from fakes.world import World, WorldParams

FLIP = make_H(rot_x(np.pi), np.zeros(3))


def test_pose_delta_round_trip():
    rng = np.random.default_rng(0)
    H = make_H(rot_x(0.3), [1.0, 2.0, 3.0])
    for _ in range(10):
        d = rng.normal(0, 0.01, 6)
        assert np.allclose(pose_delta(perturb_pose(H, d), H), d, atol=1e-12)


def test_footprint_on_a_simple_geometry():
    rob_H_cam = make_H(rot_x(np.pi), [200.0, 50.0, -320.0])  # looking straight down
    plane = make_H(np.eye(3), [0.0, 0.0, -350.0])
    assert np.allclose(footprint(rob_H_cam, plane), [200.0, 50.0, -350.0])
    with pytest.raises(ValueError, match="parallel"):
        footprint(make_H(np.eye(3), [0, 0, 0]) @ make_H(rot_x(np.pi / 2), [0, 0, 0]), plane)


def test_monte_carlo_matches_empirical_scatter():
    world = World(WorldParams(seed=21))
    heading = 40.0
    errs, foot = [], []
    for s in range(60):
        sim = Simulation(world, SimConfig(seed=100 + s))
        obs = sim.calibration(heading_deg=heading)
        r = reference_pose(obs.cam_ref, FLIP @ inv_H(obs.cam_ref), sim.plate.ref_P_smr(), obs.abs_P_nests,
                           obs.abs_P_rob0, obs.abs_P_rob1, mc_samples=0)
        errs.append(pose_delta(r.rob_H_cam, world.rob_H_cam))
        foot.append(r.footprint_rob[:2])
    emp_t = np.std(np.array(errs)[:, :3], axis=0)
    emp_r = np.std(np.array(errs)[:, 3:], axis=0)
    sim = Simulation(world, SimConfig(seed=99))
    obs = sim.calibration(heading_deg=heading)
    unc = reference_pose(obs.cam_ref, FLIP @ inv_H(obs.cam_ref), sim.plate.ref_P_smr(), obs.abs_P_nests,
                         obs.abs_P_rob0, obs.abs_P_rob1, mc_samples=400, seed=3).uncertainty
    # 60 empirical runs: the std is known to ~±20 %; allow a factor 1.6 either way
    ratio_t = unc.std_t_mm / emp_t
    ratio_r = np.radians(unc.std_rot_deg) / emp_r
    assert np.all((ratio_t > 1 / 1.6) & (ratio_t < 1.6)), (unc.std_t_mm, emp_t)
    assert np.all((ratio_r > 1 / 1.6) & (ratio_r < 1.6)), (unc.std_rot_deg, np.degrees(emp_r))
    emp_f = np.std(np.array(foot), axis=0)
    assert 1 / 1.6 < unc.footprint_std_mm / np.hypot(*emp_f) < 1.6
    # docs/accuracy.md, "Error magnitudes": tens of µm at σ_t = 10 µm
    assert 0.005 < unc.footprint_std_mm < 0.05


def test_monte_carlo_is_seeded_and_validates():
    world = World(WorldParams(seed=22))
    sim = Simulation(world, SimConfig(seed=1))
    obs = sim.calibration()
    ch = chain(sim.plate.ref_P_smr(), FLIP @ inv_H(obs.cam_ref))
    a = monte_carlo(ch, obs.abs_P_nests, obs.abs_P_rob0, obs.abs_P_rob1, obs.cam_ref, 0.01, n_samples=30, seed=5)
    b = monte_carlo(ch, obs.abs_P_nests, obs.abs_P_rob0, obs.abs_P_rob1, obs.cam_ref, 0.01, n_samples=30, seed=5)
    assert np.array_equal(a.cov_rob_H_cam, b.cov_rob_H_cam)
    zero = monte_carlo(ch, obs.abs_P_nests, obs.abs_P_rob0, obs.abs_P_rob1, obs.cam_ref, 0.0, n_samples=10)
    assert np.abs(zero.cov_rob_H_cam).max() < 1e-20
    with pytest.raises(ValueError, match="n_samples"):
        monte_carlo(ch, obs.abs_P_nests, obs.abs_P_rob0, obs.abs_P_rob1, obs.cam_ref, 0.01, n_samples=2)
    with pytest.raises(ValueError, match="6x6"):
        monte_carlo(ch, obs.abs_P_nests, obs.abs_P_rob0, obs.abs_P_rob1, obs.cam_ref, 0.01, np.eye(3))


def test_pnp_covariance_matches_repeated_pnp():
    world = World(WorldParams(seed=23))
    sim = Simulation(world, SimConfig(seed=1))
    abs_H_cam = world.abs_H_rob() @ world.rob_H_cam
    ids, uv = true_corner_projections(world, sim.cfg.size, abs_H_cam)
    truth = inv_H(abs_H_cam) @ world.abs_H_ref
    rng = np.random.default_rng(7)
    sigma = 0.2
    deltas = [pose_delta(pose_from_corners(ids, uv + rng.normal(0, sigma, uv.shape), sim.model,
                                           sim.plate).cam_H_ref, truth) for _ in range(60)]
    emp = np.std(deltas, axis=0)
    board = np.asarray(__import__("calibration.target", fromlist=["make_board"]).make_board(sim.plate)
                       .getChessboardCorners(), float)[ids]
    cov = pnp_covariance(sim.model.K, sim.model.dist, truth, board, sigma)
    ratio = np.sqrt(np.diag(cov)) / emp
    assert np.all((ratio > 1 / 1.6) & (ratio < 1.6)), ratio
    with pytest.raises(ValueError, match="sigma_px"):
        pnp_covariance(sim.model.K, sim.model.dist, truth, board, 0.0)


def test_rotvec_handles_tiny_and_large_angles():
    from calibration.uncertainty import rotmat, rotvec

    for r in ([5e-6, 0, 0], [1e-9, -2e-9, 3e-9], [0.5, -2.0, 1.0], [0, 0, np.pi - 1e-9]):
        R = rotmat(r)
        assert abs(np.linalg.det(R) - 1) < 1e-12
        assert np.abs(rotmat(rotvec(R)) - R).max() < 1e-12
    assert np.allclose(rotvec(rotmat([5e-6, 0, 0])), [5e-6, 0, 0], rtol=1e-9, atol=0)


def _loop_monte_carlo(ch, abs_P, P0, P1, cam_H_ref, sigma, L, n, seed):
    """The per-sample loop the batched Monte Carlo replaces: same draws, same chain, one sample at a time."""
    rng = np.random.default_rng(seed)
    c0, s0 = ch(abs_P, P0, P1, cam_H_ref)
    d = []
    for _ in range(n):
        e = rng.normal(0.0, sigma, size=(5, 3))
        H = cam_H_ref if L is None else perturb_pose(cam_H_ref, L @ rng.normal(size=6))
        rc, rs = ch(abs_P + e[:3], P0 + e[3], P1 + e[4], H)
        d.append(np.concatenate([pose_delta(rc, c0), pose_delta(rs, s0), footprint(rc, rs) - footprint(c0, s0)]))
    return np.array(d)


@pytest.mark.parametrize("with_pnp", [False, True])
def test_batched_monte_carlo_equals_the_per_sample_loop(with_pnp):
    world = World(WorldParams(seed=22))
    sim = Simulation(world, SimConfig(seed=1))
    obs = sim.calibration()
    ch = chain(sim.plate.ref_P_smr(), FLIP @ inv_H(obs.cam_ref))
    cov = np.diag([0.02, 0.02, 0.05, 1e-5, 1e-5, 2e-5]) ** 2 if with_pnp else None
    L = None if cov is None else np.linalg.eigh(cov)[1] * np.sqrt(np.linalg.eigh(cov)[0])
    d = _loop_monte_carlo(ch, obs.abs_P_nests, obs.abs_P_rob0, obs.abs_P_rob1, obs.cam_ref, 0.01, L, 40, 3)
    unc = monte_carlo(ch, obs.abs_P_nests, obs.abs_P_rob0, obs.abs_P_rob1, obs.cam_ref, 0.01, cov, 40, 3)
    assert np.allclose(unc.cov_rob_H_cam, np.cov(d[:, :6].T), rtol=1e-9, atol=1e-20)
    assert np.allclose(unc.cov_rob_H_scn, np.cov(d[:, 6:12].T), rtol=1e-9, atol=1e-20)
    assert np.allclose(unc.std_footprint_mm, d[:, 12:14].std(axis=0, ddof=1), rtol=1e-9)


def test_batched_rotations_match_the_single_ones_in_every_case():
    from calibration.uncertainty import rotmats, rotvec, rotvecs, rotmat

    rng = np.random.default_rng(4)
    r = np.vstack([rng.normal(0, 0.3, (20, 3)), rng.normal(0, 1e-10, (3, 3)),  # ordinary, below 1e-8 rad
                   [[np.pi, 0, 0], [0, np.pi - 1e-8, 0], [0, 0, 0]]])  # at and near π, identity
    R = np.array([rotmat(x) for x in r])
    assert np.allclose(rotmats(r), R, atol=1e-15)
    assert np.allclose(rotvecs(R), [rotvec(x) for x in R], atol=1e-12)
