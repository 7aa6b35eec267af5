"""cam_H_ref from a rendered image of the plate against the world's ground truth."""
from __future__ import annotations

import numpy as np
import pytest

from calibration import target
from calibration.errors import CalibrationError
from calibration.frames import apply_H, inv_H, make_H, rot_x, rot_z, rotation_angle
from calibration.target import (_consistent, _detect_markers, _marker_codes, detect_corners, estimate_cam_H_ref,
                                make_board, pose_from_corners)
from fakes.render import Renderer, world_camera_model
from fakes.world import World, WorldParams


def rotation_error_deg(R_est: np.ndarray, R_true: np.ndarray) -> float:
    """Angle of ``R_estᵀ R_true`` in degrees."""
    return float(np.degrees(rotation_angle(R_est.T @ R_true)))


def footprint_ref(cam_H_ref: np.ndarray) -> np.ndarray:
    """Where the optical axis meets the plate surface (PCS xy)."""
    ref_H_cam = inv_H(cam_H_ref)
    C, d = ref_H_cam[:3, 3], ref_H_cam[:3, 2]
    return (C - C[2] / d[2] * d)[:2]


@pytest.fixture(scope="module")
def scene():
    world = World()
    size = world.params.reduced_size
    renderer = Renderer(world, size)
    image = renderer.render(rng=np.random.default_rng(7))
    return world, renderer, image, world_camera_model(world, size)


def test_pose_matches_truth(scene) -> None:
    world, _, image, model = scene
    pose = estimate_cam_H_ref(image, model, world.plate())
    true = inv_H(world.abs_H_cam()) @ world.abs_H_ref
    rot = rotation_error_deg(pose.cam_H_ref[:3, :3], true[:3, :3])
    foot = np.linalg.norm(footprint_ref(pose.cam_H_ref) - footprint_ref(true)) * 1000
    print(f"rotation error {rot:.5f} deg, footprint error {foot:.2f} um, corners {pose.n_corners}, "
          f"rms {pose.rms_px:.3f} px, ambiguity {pose.ambiguity_ratio:.1f}")
    assert rot < 0.01
    assert foot < 5.0
    assert np.abs(pose.cam_H_ref[:3, 3] - true[:3, 3]).max() < 0.02
    assert pose.ambiguity_ratio > 5
    assert pose.n_corners > 200 and pose.rms_px < 0.3
    assert abs(np.linalg.det(pose.cam_H_ref[:3, :3]) - 1) < 1e-9


def test_bare_floor_raises_clear_error(scene) -> None:
    world, renderer, _, model = scene
    mark = world.params.marks[0]
    world.set_robot(world.pose_with_footprint_at(mark.x_mm + 3.0, mark.y_mm, 20.0))
    try:
        image = renderer.render(rng=np.random.default_rng(1))
    finally:
        world.set_robot(world.pose_with_target_in_view(world.plate_yaw_deg + 60.0))
    with pytest.raises(CalibrationError, match=r"only 0 ChArUco corner"):
        estimate_cam_H_ref(image, model, world.plate())


def test_ambiguity_threshold_is_enforced(scene) -> None:
    world, _, image, model = scene
    ids, uv = detect_corners(image, world.plate())
    with pytest.raises(CalibrationError, match="ambiguous target pose"):
        pose_from_corners(ids, uv, model, world.plate(), min_ambiguity_ratio=1e12)
    with pytest.raises(CalibrationError, match="need at least 50"):
        pose_from_corners(ids[:20], uv[:20], model, world.plate(), min_corners=50)


def test_bad_inputs_are_named(scene) -> None:
    world, _, image, model = scene
    with pytest.raises(ValueError, match="dtype uint8"):
        detect_corners(image.astype(np.float32), world.plate())
    with pytest.raises(ValueError, match="camera model is for"):
        detect_corners(image[:100], world.plate(), model)
    plate = world.plate()
    plate.aruco_dict = "DICT_NOPE"
    with pytest.raises(ValueError, match="DICT_NOPE"):
        make_board(plate)


def test_fast_marker_path_agrees_with_opencv(scene) -> None:
    world, _, image, _ = scene
    ids_f, uv_f = detect_corners(image, world.plate(), fast=True)
    ids_o, uv_o = detect_corners(image, world.plate(), fast=False)
    common, i_f, i_o = np.intersect1d(ids_f, ids_o, return_indices=True)
    print(f"fast {len(ids_f)} corners, OpenCV {len(ids_o)}, common {len(common)}")
    assert len(common) > 0.97 * max(len(ids_f), len(ids_o))
    # the corners are refined from slightly different marker-corner starts: they agree
    # closely, and neither path is closer to the truth (test_render checks that)
    d = np.linalg.norm(uv_f[i_f] - uv_o[i_o], axis=1)
    print(f"difference rms {np.sqrt(np.mean(d ** 2)):.4f} px, max {d.max():.4f} px")
    assert np.sqrt(np.mean(d ** 2)) < 0.03 and d.max() < 0.2


# --------------------------------------------------------------------------- dense dictionaries

@pytest.fixture(scope="module")
def oblique_4x4():
    """A DICT_4X4_1000 board seen 35° off its normal from 40 mm (a hand-held board, close and tilted)."""
    world = World(WorldParams(aruco_dict="DICT_4X4_1000", seed=3))
    size = world.params.reduced_size
    centre = apply_H(world.abs_H_ref, world.board_centre_ref())
    R = rot_z(0.3) @ rot_x(np.pi) @ rot_x(np.radians(35.0))  # nadir, then tilted 35°
    abs_H_cam = make_H(R, centre - 40.0 * R[:, 2])
    image = Renderer(world, size).render(abs_H_cam, rng=np.random.default_rng(5))
    model = world_camera_model(world, size)
    return world, image, model, inv_H(abs_H_cam) @ world.abs_H_ref


def _true_marker_centres(board, model, cam_H_ref) -> dict[int, np.ndarray]:
    return {int(i): model.project(apply_H(cam_H_ref, np.asarray(o).reshape(4, 3))).mean(axis=0)
            for i, o in zip(board.getIds().ravel(), board.getObjPoints())}


def test_correction_limit_is_the_dictionarys_own() -> None:
    # OpenCV accepts int(maxCorrectionBits × errorCorrectionRate) wrong bits: 0 for 4X4_1000
    for name, bits in (("DICT_4X4_1000", 0), ("DICT_5X5_1000", 1), ("DICT_6X6_1000", 2)):
        plate = World(WorldParams(aruco_dict=name)).plate()
        assert _marker_codes(make_board(plate))[2] == bits, name


def test_dense_dictionary_oblique_view_decodes(oblique_4x4) -> None:
    world, image, model, cam_H_ref = oblique_4x4
    plate = world.plate()
    board = make_board(plate)
    corners, ids = _detect_markers(image, board)
    truth = _true_marker_centres(board, model, cam_H_ref)
    off = [float(np.linalg.norm(c.reshape(4, 2).mean(axis=0) - truth[int(i)])) for c, i in zip(corners, ids.ravel())]
    print(f"{len(ids)} markers, largest offset from the true centre {max(off):.2f} px")
    assert len(ids) > 200 and max(off) < 2.0  # every id is the marker actually there
    pose = estimate_cam_H_ref(image, model, plate)
    rot = rotation_error_deg(pose.cam_H_ref[:3, :3], cam_H_ref[:3, :3])
    print(f"{pose.n_corners} corners, rotation error {rot:.5f}°")
    assert pose.n_corners > 300 and rot < 0.01
    assert np.abs(pose.cam_H_ref[:3, 3] - cam_H_ref[:3, 3]).max() < 0.01


def test_misread_marker_is_dropped(oblique_4x4) -> None:
    world, image, model, cam_H_ref = oblique_4x4
    board = make_board(world.plate())
    corners, ids = _detect_markers(image, board)
    wrong = ids.copy()
    far = next(int(i) for i in board.getIds().ravel() if int(i) not in set(ids.ravel().tolist()))
    wrong[len(wrong) // 2, 0] = far  # a marker read as an id that is elsewhere on the board
    kept_corners, kept = _consistent(corners, wrong, board)
    assert far not in kept.ravel().tolist()
    assert len(kept) >= len(ids) - 3  # the good markers stay


def test_rejected_marker_set_falls_back_to_opencv(oblique_4x4, monkeypatch) -> None:
    world, image, _, _ = oblique_4x4
    plate = world.plate()
    corners, ids = _detect_markers(image, make_board(plate))
    shuffled = np.random.default_rng(0).permutation(ids.ravel()).reshape(-1, 1)  # nonsense the board check rejects
    monkeypatch.setattr(target, "_detect_markers", lambda img, board: (corners, shuffled))
    got_ids, got_uv = detect_corners(image, plate)
    ocv_ids, ocv_uv = detect_corners(image, plate, fast=False)
    assert len(got_ids) == len(ocv_ids) > 300
    assert np.array_equal(got_ids, ocv_ids) and np.allclose(got_uv, ocv_uv)
