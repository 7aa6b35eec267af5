"""SCS: convention, analytic image <-> plane mapping, and agreement with the truth."""
from __future__ import annotations

import numpy as np
import pytest

from calibration.errors import CalibrationError
from calibration.frames import apply_H, inv_H
from calibration.scs import Scs, make_scs
from calibration.target import estimate_cam_H_ref, make_board
from fakes.render import Renderer, true_corner_projections, world_camera_model
from fakes.world import World


@pytest.fixture(scope="module")
def truth():
    world = World()
    size = world.params.reduced_size
    model = world_camera_model(world, size)
    cam_H_ref = inv_H(world.abs_H_cam()) @ world.abs_H_ref
    return world, model, cam_H_ref, make_scs(model, cam_H_ref)


def _pixels(size: tuple[int, int], n: int = 25) -> np.ndarray:
    u, v = np.meshgrid(np.linspace(-0.5, size[0] - 0.5, n), np.linspace(-0.5, size[1] - 0.5, n))
    return np.column_stack([u.ravel(), v.ravel()])


def test_convention_right_handed_positive_quadrant(truth) -> None:
    _, model, _, scs = truth
    assert abs(np.linalg.det(scs.scn_H_cam[:3, :3]) - 1) < 1e-12
    xy = scs.image_to_scn(_pixels(model.size))
    assert xy.min() >= -1e-9
    assert xy[:, 0].min() < 0.05 and xy[:, 1].min() < 0.05  # the footprint touches both axes
    assert xy[:, 0].max() <= scs.extent_mm[0] + 1e-9 and xy[:, 1].max() <= scs.extent_mm[1] + 1e-9
    # x follows +column, y follows −row, z points up toward the camera
    c = model.K[:2, 2]
    p = scs.image_to_scn(np.array([c, c + [10, 0], c + [0, 10]]))
    assert p[1, 0] - p[0, 0] > 0.5 and abs(p[1, 1] - p[0, 1]) < 0.05
    assert p[2, 1] - p[0, 1] < -0.5 and abs(p[2, 0] - p[0, 0]) < 0.05
    assert scs.scn_H_cam[2, 3] > 20
    assert 0.05 < scs.gsd_mm < 0.08


def scn_to_image(scs: Scs, xy: np.ndarray) -> np.ndarray:
    """SCS xy points on z = 0 to distorted pixel coordinates: image_to_scn's inverse, by projection."""
    return scs.model.project(apply_H(inv_H(scs.scn_H_cam), np.column_stack([xy, np.zeros(len(xy))])))


def test_round_trip(truth) -> None:
    _, model, _, scs = truth
    uv = _pixels(model.size)
    assert np.abs(scn_to_image(scs, scs.image_to_scn(uv)) - uv).max() < 1e-6
    xy = np.random.default_rng(3).uniform([5, 5], np.array(scs.extent_mm) - 5, (200, 2))
    assert np.abs(scs.image_to_scn(scn_to_image(scs, xy)) - xy).max() < 1e-9


def test_true_corners_map_to_board_positions_exactly(truth) -> None:
    world, model, cam_H_ref, scs = truth
    ids, uv = true_corner_projections(world, model.size)
    ref_P = np.asarray(make_board(world.plate()).getChessboardCorners(), float)[ids]
    scn_P = apply_H(scs.scn_H_cam @ cam_H_ref, ref_P)
    assert np.abs(scn_P[:, 2]).max() < 1e-9  # the SCS plane is the board plane
    assert np.abs(scs.image_to_scn(uv) - scn_P[:, :2]).max() < 1e-7


def test_rendered_corners_map_within_few_um(truth) -> None:
    world, model, _, _ = truth
    image = Renderer(world, model.size).render(rng=np.random.default_rng(11))
    pose = estimate_cam_H_ref(image, model, world.plate())
    scs = make_scs(model, pose.cam_H_ref)
    # truth: the true board corner positions carried into this SCS with the true pose
    true_cam_H_ref = inv_H(world.abs_H_cam()) @ world.abs_H_ref
    ref_P = np.asarray(make_board(world.plate()).getChessboardCorners(), float)[pose.ids]
    scn_P = apply_H(scs.scn_H_cam @ true_cam_H_ref, ref_P)
    err = np.linalg.norm(scs.image_to_scn(pose.uv) - scn_P[:, :2], axis=1) * 1000
    print(f"rendered corners in SCS: rms {np.sqrt(np.mean(err ** 2)):.2f} um, max {err.max():.2f} um")
    assert np.sqrt(np.mean(err ** 2)) < 8.0
    assert np.abs(scn_P[:, 2]).max() < 0.005  # estimated plane agrees with the true one


def test_files_round_trip(truth) -> None:
    scs = truth[3]
    scs2 = Scs.from_dict(scs.to_dict())
    assert np.array_equal(scs2.scn_H_cam, scs.scn_H_cam) and scs2.extent_mm == scs.extent_mm


def test_camera_below_plate_is_rejected(truth) -> None:
    _, model, cam_H_ref, _ = truth
    flipped = cam_H_ref.copy()
    flipped[:3, :3] = cam_H_ref[:3, :3] @ np.diag([1.0, -1.0, -1.0])
    flipped[:3, 3] = -cam_H_ref[:3, 3] * [1, 1, -1] + [0, 0, 2 * cam_H_ref[2, 3]]
    with pytest.raises(CalibrationError, match="not above the plate"):
        make_scs(model, flipped)
