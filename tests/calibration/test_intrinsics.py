"""Intrinsics recovered from rendered ChArUco views at different tilts."""
from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.errors import CalibrationError
from calibration.frames import apply_H, make_H, rot_x, rot_y, rot_z
from calibration.intrinsics import calibrate_intrinsics
from fakes.render import Renderer, world_camera_model
from fakes.world import World


def view_pose(world: World, tilt_x: float, tilt_y: float, yaw: float, height: float) -> np.ndarray:
    """abs_H_cam looking at the board centre from ``height`` mm, tilted by the given degrees."""
    R = (rot_z(math.radians(yaw)) @ rot_x(math.pi) @ rot_x(math.radians(tilt_x))
         @ rot_y(math.radians(tilt_y)))
    target = apply_H(world.abs_H_ref, world.board_centre_ref())
    axis = R[:, 2]
    return make_H(R, target - axis * (height / -axis[2]), "abs_H_cam")


@pytest.fixture(scope="module")
def views():
    world = World()
    size = world.params.reduced_size
    r = Renderer(world, size)
    rng = np.random.default_rng(21)
    poses = [(0, 0, 10, 32), (15, 0, 40, 30), (-15, 0, 100, 30), (0, 15, 160, 30),
             (0, -15, 220, 30), (10, 10, 280, 36), (-10, 8, 330, 28)]
    return world, size, [r.render(view_pose(world, *p), rng=rng) for p in poses]


def test_recovers_focal_length_and_centre(views) -> None:
    world, size, images = views
    true = world_camera_model(world, size)
    model, report = calibrate_intrinsics(images, world.plate(), size)
    dk = model.K - true.K
    print(f"fx {dk[0, 0]:+.3f} fy {dk[1, 1]:+.3f} cx {dk[0, 2]:+.3f} cy {dk[1, 2]:+.3f} px; "
          f"rms {report['rms_px']:.4f} px (all {report['rms_px_all']:.4f}), rejected {report['n_rejected']}/{report['n_corners']}; dist {np.round(model.dist - true.dist, 5)}; "
          f"views {[round(v.get('rms_px', -1), 3) for v in report['views']]}")
    assert report["n_views_used"] == len(images)
    assert report["n_rejected"] < 0.08 * report["n_corners"] and report["rms_px_all"] < 0.2
    assert abs(dk[0, 0]) < 0.5 and abs(dk[1, 1]) < 0.5
    assert abs(dk[0, 2]) < 0.5 and abs(dk[1, 2]) < 0.5
    assert report["rms_px"] < 0.1
    assert all(v["rms_px"] < 0.15 for v in report["views"])
    # the recovered lens maps the image edges like the true one (< 0.5 px)
    uv = np.array([[0.0, 0.0], [size[0] - 1.0, 0.0], [0.0, size[1] - 1.0], [size[0] - 1.0, size[1] - 1.0]])
    xy = model.undistort(uv)
    back = true.project(np.column_stack([xy, np.ones(4)]))
    assert np.abs(back - uv).max() < 0.5


def test_too_few_usable_views(views) -> None:
    world, size, images = views
    blank = np.full_like(images[0], 128)
    with pytest.raises(CalibrationError, match="only 2 of 4 views"):
        calibrate_intrinsics([images[0], images[1], blank, blank], world.plate(), size)
    with pytest.raises(ValueError, match="expected 1000x750"):
        calibrate_intrinsics([images[0][:10]], world.plate(), size)
