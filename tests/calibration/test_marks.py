"""Floor marks rendered at known sub-pixel positions are located to < 0.1 px RMS."""
from __future__ import annotations

import math

import cv2
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


@pytest.fixture(scope="module")
def full_size_pair() -> tuple[Renderer, tuple[FloorMark, FloorMark]]:
    """A 4024×3036 renderer (SS=1 to keep it quick) of a world with a dot and a cross 8 mm apart."""
    marks = (FloorMark("D", 2200.0, 1400.0, "dot", 0.4), FloorMark("X", 2207.0, 1404.0, "cross", 0.6))
    world = World(WorldParams(marks=marks))
    return Renderer(world, world.params.full_size, supersampling=1), marks


def _place(world: World, model, floor_xy: np.ndarray, uv: tuple[float, float], heading: float) -> None:
    """Move the robot (flat floor, so a pure shift) until ``floor_xy`` is seen at pixel ``uv``."""
    world.set_robot(world.pose_with_footprint_at(floor_xy[0], floor_xy[1], heading))
    abs_H_cam = world.abs_H_cam()
    ray = abs_H_cam[:3, :3] @ model.rays(np.array([uv]))[0]
    hit = abs_H_cam[:3, 3] - abs_H_cam[2, 3] / ray[2] * ray
    pose = world.robot
    world.set_robot(type(pose)(pose.x_mm + floor_xy[0] - hit[0], pose.y_mm + floor_xy[1] - hit[1], heading))


# where the pair's middle is put (fractions of the image) and the robot heading: near
# three corners and in the centre, the pair turned differently each time
_PLACES = [(0.12, 0.15, 10.0), (0.88, 0.85, 40.0), (0.5, 0.5, 100.0), (0.85, 0.14, -60.0)]


def test_coarse_to_fine_equals_full_resolution_search(full_size_pair) -> None:
    renderer, marks = full_size_pair
    world = renderer.world
    model = world_camera_model(world, renderer.size)
    mid = np.mean([[m.x_mm, m.y_mm] for m in marks], axis=0)
    w, h = renderer.size
    rng = np.random.default_rng(31)
    seen = []
    old = world.robot
    try:
        for fu, fv, heading in _PLACES:
            _place(world, model, mid, (fu * w, fv * h), heading)
            cam_H_abs = inv_H(world.abs_H_cam())
            img = renderer.render(rng=rng)
            for mark in marks:
                truth = model.project(apply_H(cam_H_abs, [mark.x_mm, mark.y_mm, 0.0]).reshape(1, 3))[0]
                size_px = mark.size_mm * model.f / world.abs_H_cam()[2, 3]
                fast = locate_mark(img, mark.kind, size_px=size_px)
                full = locate_mark(img, mark.kind, size_px=size_px, coarse_to_fine=False)
                d = float(np.linalg.norm(fast.uv - full.uv))
                print(f"{mark.kind} at {truth.round(0)}: coarse-to-fine vs full {d:.4f} px, "
                      f"vs truth {np.linalg.norm(fast.uv - truth):.3f} px")
                assert d < 0.05
                # the mark, not something else (the dot's image is not symmetric under the
                # lens distortion: up to ~0.9 px off near the corners, both searches alike)
                assert np.linalg.norm(fast.uv - truth) < 2.0
                seen.append(truth)
    finally:
        world.set_robot(old)
    seen = np.array(seen)
    # the marks really were spread over the field: near both sides and both ends
    assert seen[:, 0].min() < 0.15 * w and seen[:, 0].max() > 0.85 * w
    assert seen[:, 1].min() < 0.15 * h and seen[:, 1].max() > 0.85 * h


def test_coarse_search_without_a_mark_says_so(renderer: Renderer) -> None:
    img = np.full((750, 1000), 120, np.uint8)
    img += np.random.default_rng(2).integers(0, 3, img.shape, dtype=np.uint8)
    with pytest.raises(CalibrationError, match="no dot found in the whole image; the best candidate near"):
        locate_mark(img, "dot", size_px=9.0)
    with pytest.raises(CalibrationError, match="no cross found in the whole image; .*no cross found: contrast"):
        locate_mark(img, "cross", size_px=12.0)


def _synthetic_dot(shape: tuple[int, int], centre: tuple[float, float], radius: float, seed: int) -> np.ndarray:
    """A supersampled dark disc on a grey, noisy background (no renderer needed)."""
    h, w = shape
    cx, cy = centre
    img = np.full((h, w), 170.0, np.float32)
    y0, x0 = int(cy) - 40, int(cx) - 40
    ys, xs = np.mgrid[y0:y0 + 81, x0:x0 + 81]
    sub = (np.arange(4) + 0.5) / 4 - 0.5
    cover = sum(((xs + a - cx) ** 2 + (ys + b - cy) ** 2 < radius ** 2) for a in sub for b in sub) / 16
    win = (slice(max(0, y0), y0 + 81), slice(max(0, x0), x0 + 81))
    img[win] -= 130 * cover[max(0, -y0):, max(0, -x0):][:img[win].shape[0], :img[win].shape[1]]
    img = cv2.GaussianBlur(img, (0, 0), 2.0) + np.random.default_rng(seed).normal(0, 2, (h, w)).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8)


@pytest.mark.parametrize("centre", [(46.3, 450.7), (60.2, 50.9), (1153.6, 853.4), (600.5, 850.2), (700.4, 44.8)])
def test_coarse_to_fine_finds_dots_next_to_the_border(centre: tuple[float, float]) -> None:
    # a 25 px dot 45–60 px from the border: the full-resolution search reaches it, so the
    # coarse one (8× shrink, a template as wide as 8 coarse pixels) must reach it too
    img = _synthetic_dot((900, 1200), centre, 25.2, seed=int(centre[0]))
    fast = locate_mark(img, "dot", size_px=25.2)
    full = locate_mark(img, "dot", size_px=25.2, coarse_to_fine=False)
    assert np.linalg.norm(fast.uv - full.uv) < 0.05
    assert np.linalg.norm(fast.uv - centre) < 0.1
