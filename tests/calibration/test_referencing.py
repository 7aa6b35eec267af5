"""The referencing chain against the simulated world's ground truth (no rendering)."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from calibration.errors import CalibrationError
from calibration.frames import apply_H, inv_H, make_H, rot_x, rot_y, rot_z
from calibration.referencing import (Gates, board_corners_ref, chain, plate_normal, reference, reference_pose,
                                     rob_H_cam_error, robot_pose, seat_tilt_deg)
from fakes.simulate import SimConfig, Simulation
from fakes.world import World, WorldParams

FLIP = make_H(rot_x(np.pi), np.zeros(3))  # scn_H_ref of a simple SCS: PCS z down -> SCS z up


def run(sim: Simulation, obs, scn_H_cam=None, **kw):
    """Referencing of a rendering-free observation with a simple SCS on the plate plane."""
    cam_H_ref = obs.cam_ref if isinstance(obs.cam_ref, np.ndarray) else obs.cam_ref.cam_H_ref
    if scn_H_cam is None:
        scn_H_cam = FLIP @ inv_H(cam_H_ref)
    kw.setdefault("mc_samples", 0)
    return reference_pose(cam_H_ref, scn_H_cam, sim.plate.ref_P_smr(), obs.abs_P_nests, obs.abs_P_rob0,
                          obs.abs_P_rob1, sigma_t_mm=sim.cfg.sigma_t_mm, **kw)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_no_noise_algebraic_path_is_exact(seed):
    world = World(WorldParams(seed=seed))
    sim = Simulation(world, SimConfig(sigma_t_mm=0.0, seed=seed))
    res = run(sim, sim.calibration())
    assert np.abs(res.rob_H_cam - world.rob_H_cam).max() < 1e-9
    err = rob_H_cam_error(res.rob_H_cam, world.rob_H_cam)
    assert err["t_xy_mm"] < 1e-9 and err["t_z_mm"] < 1e-9 and np.radians(err["rot_deg"]) < 1e-9
    for H in (res.rob_H_cam, res.rob_H_scn, res.abs_H_scn, res.abs_H_rob, res.scn_H_cam):
        assert abs(np.linalg.det(H[:3, :3]) - 1) < 1e-12
    # the robot frame is the true one: origin at the reflector, z along the plate normal
    assert np.abs(res.abs_H_rob - sim.calibration().abs_H_rob_true).max() < 1e-9
    assert res.verdict == "ok", res.messages


def test_result_does_not_depend_on_the_scs_choice():
    world = World(WorldParams(seed=4))
    sim = Simulation(world, SimConfig(seed=4))
    obs = sim.calibration()
    a = run(sim, obs)
    shift = make_H(rot_z(0.7), [12.0, -3.0, 0.0])  # another in-plane SCS
    b = run(sim, obs, scn_H_cam=shift @ FLIP @ inv_H(obs.cam_ref))
    assert np.abs(a.rob_H_cam - b.rob_H_cam).max() < 1e-9
    assert np.abs(b.rob_H_scn - a.rob_H_scn @ inv_H(shift)).max() < 1e-9


def test_rigid_transform_of_all_acs_data_leaves_rob_H_cam_unchanged():
    world = World(WorldParams(seed=5))
    sim = Simulation(world, SimConfig(seed=5))
    obs = sim.calibration()
    a = run(sim, obs)
    G = make_H(rot_z(2.1) @ rot_y(0.3) @ rot_x(-0.4), [5000.0, -2000.0, 300.0])
    obs.abs_P_nests = apply_H(G, obs.abs_P_nests)
    obs.abs_P_rob0, obs.abs_P_rob1 = apply_H(G, obs.abs_P_rob0), apply_H(G, obs.abs_P_rob1)
    b = run(sim, obs)
    assert np.abs(a.rob_H_cam - b.rob_H_cam).max() < 1e-9
    assert np.abs(G @ a.abs_H_rob - b.abs_H_rob).max() < 1e-8


def test_plate_normal_points_toward_the_robot():
    world = World(WorldParams(seed=6))
    nests = np.array(list(world.nests_abs().values()))
    P0 = world.abs_H_rob()[:3, 3]
    n = plate_normal(nests, P0)
    assert n @ (P0 - nests.mean(axis=0)) > 0 and abs(np.linalg.norm(n) - 1) < 1e-12
    assert n[2] > 0.999  # the plate lies flat in this world
    # reversed nest order flips the raw cross product; the orientation rule flips it back
    assert np.allclose(plate_normal(nests[::-1], P0), n)
    # a reflector below the plate gets the opposite normal
    below = nests.mean(axis=0) - 300 * n
    assert np.allclose(plate_normal(nests, below), -n)


def test_robot_pose_is_the_papers_basis():
    n = np.array([0.0, 0.0, 1.0])
    H = robot_pose([1.0, 2.0, 3.0], [10.0, 10.0, 0.5], n)  # the climb is projected out
    assert np.allclose(H[:3, 0], [np.sqrt(0.5), np.sqrt(0.5), 0])
    assert np.allclose(H[:3, 1], np.cross(n, H[:3, 0]))
    assert np.allclose(H[:3, 2], n) and np.allclose(H[:3, 3], [1, 2, 3])
    assert abs(np.linalg.det(H[:3, :3]) - 1) < 1e-12
    with pytest.raises(CalibrationError, match="heading undefined"):
        robot_pose([0, 0, 0], [0, 0, 5.0], n)
    with pytest.raises(ValueError, match="unit vector"):
        robot_pose([0, 0, 0], [1, 0, 0], [0, 0, 2.0])


@pytest.mark.parametrize("seed", range(10, 16))
def test_nominal_tracker_noise_within_thresholds(seed):
    world = World(WorldParams(seed=seed))
    sim = Simulation(world, SimConfig(seed=seed, pnp_sigma_px=0.05))
    res = run(sim, sim.calibration())
    err = rob_H_cam_error(res.rob_H_cam, world.rob_H_cam)
    assert err["t_xy_mm"] < 0.06 and err["t_z_mm"] < 0.045 and err["rot_deg"] < 0.015, err
    assert res.verdict in ("ok", "warn")


def test_swapped_nest_labels_detected_in_referencing():
    world = World(WorldParams(seed=7))
    sim = Simulation(world, SimConfig(seed=7))
    obs = sim.calibration()
    obs.abs_P_nests = obs.abs_P_nests[[1, 0, 2]]
    with pytest.raises(CalibrationError, match="swapped"):
        run(sim, obs)


def test_gates_fail_and_warn_with_clear_messages():
    world = World(WorldParams(seed=8))
    sim = Simulation(world, SimConfig(seed=8))
    obs = sim.calibration()
    bad = run(sim, obs, n_corners=12, rms_px=0.8, ambiguity_ratio=1.3)
    assert bad.verdict == "fail"
    text = " ".join(bad.messages)
    assert "12 target corners" in text and "ambiguity ratio 1.30" in text and "0.800 px" in text
    short = Simulation(world, SimConfig(seed=8, move_mm=100.0)).calibration()
    warn = run(sim, short, n_corners=500, rms_px=0.05, ambiguity_ratio=50.0)
    assert warn.verdict == "warn" and "100.0 mm" in " ".join(warn.messages)
    strict = run(sim, obs, gates=Gates(min_move_mm=250.0))
    assert strict.verdict == "fail"


def test_to_dict_is_json_and_carries_uncertainty():
    world = World(WorldParams(seed=9))
    sim = Simulation(world, SimConfig(seed=9))
    res = run(sim, sim.calibration(), mc_samples=50)
    d = json.loads(json.dumps(res.to_dict()))
    assert np.allclose(d["rob_H_cam"], res.rob_H_cam)
    assert len(d["uncertainty"]["std_t_mm"]) == 3 and d["uncertainty"]["footprint_std_mm"] > 0
    assert d["verdict"] == res.verdict and set(d["nest_residuals_mm"]) == {"red", "green", "blue"}


def test_bad_inputs_are_named():
    world = World(WorldParams(seed=9))
    sim = Simulation(world, SimConfig(seed=9))
    obs = sim.calibration()
    obs.abs_P_rob1 = np.array([np.nan, 0, 0])
    with pytest.raises(ValueError, match="abs_P_rob1"):
        run(sim, obs)
    with pytest.raises(ValueError, match="sigma_plate_mm"):
        run(sim, sim.calibration(), sigma_plate_mm=-1.0)


def test_reference_entry_point_checks_its_arguments():
    world = World(WorldParams(seed=9))
    sim = Simulation(world, SimConfig(seed=9))
    obs = sim.calibration()
    args = (sim.model, sim.plate, obs.abs_P_nests, obs.abs_P_rob0, obs.abs_P_rob1)
    with pytest.raises(ValueError, match="exactly one"):
        reference(*args)
    with pytest.raises(ValueError, match="cam_ref"):
        reference(*args, cam_ref=np.eye(3))
    res = reference(*args, cam_ref=obs.cam_ref, mc_samples=0)  # a bare 4x4 cam_H_ref is accepted
    assert np.abs(res.rob_H_cam - world.rob_H_cam).max() < 0.2 and res.n_corners is None


def test_board_corner_ids_match_opencv():
    world = World(WorldParams(seed=1))
    plate = world.plate()
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_1000)
    board = cv2.aruco.CharucoBoard((plate.board_cols, plate.board_rows), plate.square_mm, plate.marker_mm, d)
    ref = np.asarray(board.getChessboardCorners(), float)
    ids = np.array([0, 1, 38, 39, 500, len(ref) - 1])
    assert np.allclose(board_corners_ref(plate, ids), ref[ids])
    with pytest.raises(ValueError, match="out of range"):
        board_corners_ref(plate, [len(ref)])


def _unequal_seats_observation(seat_dz_mm=(0.0, -0.6, 0.4), seed=21):
    """Truth and observations for a plate whose nest seats sit at unequal heights.

    The seat heights are stated correctly in the plate definition; the tracker
    measures the SMRs where they really are. No noise: the only error source is how
    the robot z axis is chosen.
    """
    world = World(WorldParams(seed=seed))
    sim = Simulation(world, SimConfig(sigma_t_mm=0.0, seed=seed))
    obs = sim.calibration()
    ref_P = sim.plate.ref_P_smr() + np.column_stack([np.zeros((3, 2)), seat_dz_mm])
    obs.abs_P_nests = apply_H(world.abs_H_ref, ref_P)
    return world, sim, obs, ref_P


def test_unequal_seat_heights_do_not_tilt_the_robot_frame():
    world, sim, obs, ref_P = _unequal_seats_observation()
    cam_H_ref = obs.cam_ref if isinstance(obs.cam_ref, np.ndarray) else obs.cam_ref.cam_H_ref
    res = reference_pose(cam_H_ref, FLIP @ inv_H(cam_H_ref), ref_P, obs.abs_P_nests, obs.abs_P_rob0,
                         obs.abs_P_rob1, sigma_t_mm=0.0, mc_samples=0)
    err = rob_H_cam_error(res.rob_H_cam, world.rob_H_cam)
    print(err)
    assert err["rot_deg"] < 0.01 and err["t_xy_mm"] < 0.001 and err["t_z_mm"] < 0.001
    # the robot z axis is the plate surface normal, not the nest triangle's (0.16° off here)
    up = world.abs_H_ref[:3, :3] @ [0.0, 0.0, -1.0]
    assert np.degrees(np.arccos(min(1.0, res.abs_n @ up))) < 1e-6
    tri = plate_normal(obs.abs_P_nests, obs.abs_P_rob0)
    assert np.degrees(np.arccos(tri @ up)) > 0.1
    assert res.verdict == "ok", res.messages


def test_unequal_seat_heights_uncertainty_follows_the_surface_normal():
    # the Monte Carlo chain uses the same normal: its mean stays on the true pose
    world, sim, obs, ref_P = _unequal_seats_observation(seed=22)
    cam_H_ref = obs.cam_ref if isinstance(obs.cam_ref, np.ndarray) else obs.cam_ref.cam_H_ref
    scn_H_cam = FLIP @ inv_H(cam_H_ref)
    run_chain = chain(ref_P, scn_H_cam)
    rob_H_cam, _ = run_chain(obs.abs_P_nests, obs.abs_P_rob0, obs.abs_P_rob1, cam_H_ref)
    assert rob_H_cam_error(rob_H_cam, world.rob_H_cam)["rot_deg"] < 1e-6


def test_implausible_seat_tilt_in_the_plate_file_warns():
    world, sim, obs, ref_P = _unequal_seats_observation((0.0, -3.0, 3.0), seed=23)
    cam_H_ref = obs.cam_ref if isinstance(obs.cam_ref, np.ndarray) else obs.cam_ref.cam_H_ref
    assert seat_tilt_deg(ref_P) > 0.5
    res = reference_pose(cam_H_ref, FLIP @ inv_H(cam_H_ref), ref_P, obs.abs_P_nests, obs.abs_P_rob0,
                         obs.abs_P_rob1, sigma_t_mm=0.0, mc_samples=0)
    assert res.verdict == "warn"
    assert any("tilted" in m and "seat z" in m for m in res.messages), res.messages
    assert rob_H_cam_error(res.rob_H_cam, world.rob_H_cam)["rot_deg"] < 0.01  # still handled
