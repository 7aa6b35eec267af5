"""Floor marks rendered at known sub-pixel positions are located to < 0.1 px RMS."""
from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.errors import CalibrationError
from calibration.frames import apply_H, inv_H
from calibration.marks import locate_mark
from fakes.render import Renderer, world_camera_model
from fakes.world import FloorMark, World, WorldParams


@pytest.fixture(scope="module")
def renderer() -> Renderer:
    marks = (FloorMark("D", 2200.0, 1400.0, "dot", 0.4), FloorMark("X", 2600.0, 1100.0, "cross", 0.6))
    world = World(WorldParams(marks=marks))
    return Renderer(world, world.params.reduced_size)


def _observe(renderer: Renderer, mark: FloorMark, n: int, seed: int) -> tuple[np.ndarray, float]:
    """Render ``mark`` at n random robot poses (±3 mm, random heading); return errors (n, 2), px/mm."""
    world = renderer.world
    model = world_camera_model(world, renderer.size)
    rng = np.random.default_rng(seed)
    errs = []
    old = world.robot
    try:
        for _ in range(n):
            off = rng.uniform(-3, 3, 2)
            world.set_robot(world.pose_with_footprint_at(mark.x_mm + off[0], mark.y_mm + off[1],
                                                         rng.uniform(-180, 180)))
            cam_H_abs = inv_H(world.abs_H_cam())
            truth = model.project(apply_H(cam_H_abs, [mark.x_mm, mark.y_mm, 0.0]).reshape(1, 3))[0]
            # a 120x120 window around the mark (noise-free it equals the full render there)
            x0, y0 = (np.floor(truth) - 60).astype(int)
            img = renderer.render(rng=rng, roi=(x0, y0, 120, 120))
            guess = truth - [x0, y0] + rng.uniform(-3, 3, 2)
            px_per_mm = model.f / world.abs_H_cam()[2, 3]  # camera height over the floor
            obs = locate_mark(img, mark.kind, approx_uv=guess, size_px=mark.size_mm * px_per_mm)
            errs.append(obs.uv + [x0, y0] - truth)
            assert obs.score > 0.5
    finally:
        world.set_robot(old)
    return np.array(errs), px_per_mm


@pytest.mark.parametrize("name", ["D", "X"])
def test_marks_located_within_a_tenth_of_a_pixel(renderer: Renderer, name: str) -> None:
    mark = next(m for m in renderer.world.params.marks if m.name == name)
    errs, _ = _observe(renderer, mark, 20, seed=3 if name == "D" else 4)
    rms = math.sqrt(float(np.mean(np.sum(errs ** 2, axis=1))))
    print(f"{mark.kind}: rms {rms:.4f} px, bias {errs.mean(axis=0)}, max {np.abs(errs).max():.3f} px")
    assert rms < 0.1
    assert np.abs(errs).max() < 0.3


def test_dot_radius_is_estimated_when_not_given(renderer: Renderer) -> None:
    mark = next(m for m in renderer.world.params.marks if m.kind == "dot")
    world = renderer.world
    model = world_camera_model(world, renderer.size)
    old = world.robot
    try:
        world.set_robot(world.pose_with_footprint_at(mark.x_mm, mark.y_mm, 10.0))
        truth = model.project(apply_H(inv_H(world.abs_H_cam()), [mark.x_mm, mark.y_mm, 0.0]).reshape(1, 3))[0]
        img = renderer.render(rng=np.random.default_rng(9))
    finally:
        world.set_robot(old)
    obs = locate_mark(img, "dot", approx_uv=truth + [2.0, -2.0])
    assert np.linalg.norm(obs.uv - truth) < 0.2
    # no mark where we look: the plain floor has no dot and no saddle with contrast
    with pytest.raises(CalibrationError, match="no dot found|no dark blob"):
        locate_mark(img, "dot", approx_uv=truth + [150.0, 100.0], size_px=6.0)
    with pytest.raises(CalibrationError, match="no cross found"):
        locate_mark(img, "cross", approx_uv=truth + [150.0, 100.0], size_px=9.0)


def test_bad_arguments_are_named() -> None:
    img = np.full((100, 120), 128, np.uint8)
    with pytest.raises(ValueError, match="kind='star'"):
        locate_mark(img, "star")
    with pytest.raises(ValueError, match="approx_uv"):
        locate_mark(img, "dot", approx_uv=[500.0, 10.0], size_px=5)
    with pytest.raises(ValueError, match="size_px"):
        locate_mark(img, "dot", size_px=0.5)
    with pytest.raises(ValueError, match="dtype uint8"):
        locate_mark(img.astype(float), "dot", size_px=5)


@pytest.mark.parametrize("name", ["D", "X"])
def test_whole_image_search_without_approx(renderer: Renderer, name: str) -> None:
    mark = next(m for m in renderer.world.params.marks if m.name == name)
    world = renderer.world
    model = world_camera_model(world, renderer.size)
    old = world.robot
    try:
        world.set_robot(world.pose_with_footprint_at(mark.x_mm + 1.7, mark.y_mm - 2.2, 33.0))
        truth = model.project(apply_H(inv_H(world.abs_H_cam()), [mark.x_mm, mark.y_mm, 0.0]).reshape(1, 3))[0]
        img = renderer.render(rng=np.random.default_rng(17))
        size_px = mark.size_mm * model.f / world.abs_H_cam()[2, 3]
    finally:
        world.set_robot(old)
    obs = locate_mark(img, mark.kind, size_px=size_px)
    assert np.linalg.norm(obs.uv - truth) < 0.2
