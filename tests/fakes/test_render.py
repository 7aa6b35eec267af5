"""Renderer validated against ground truth (corners), determinism and scene content."""
from __future__ import annotations

import numpy as np
import pytest

from calibration.target import detect_corners
from fakes.render import Renderer, true_corner_projections
from fakes.world import World, WorldParams


@pytest.fixture(scope="module")
def renderer() -> Renderer:
    world = World()
    return Renderer(world, world.params.reduced_size)


def test_detected_corners_match_true_projections(renderer: Renderer) -> None:
    world = renderer.world
    image = renderer.render(rng=np.random.default_rng(5))
    ids, uv = detect_corners(image, world.plate())
    tids, tuv = true_corner_projections(world, renderer.size)
    truth = dict(zip(tids.tolist(), tuv))
    common = [k for k, i in enumerate(ids) if int(i) in truth]
    d = uv[common] - np.array([truth[int(i)] for i in ids[common]])
    rms = float(np.sqrt(np.mean(np.sum(d ** 2, axis=1))))
    print(f"corners {len(common)}/{len(tids)}: rms {rms:.4f} px, bias {d.mean(axis=0)}")
    assert len(common) == len(ids) and len(ids) > 0.8 * len(tids)
    assert rms < 0.1
    assert np.abs(d.mean(axis=0)).max() < 0.01


def test_noise_free_corner_bias_is_tiny(renderer: Renderer) -> None:
    world = renderer.world
    ids, uv = detect_corners(renderer.render(noise=False), world.plate())
    tids, tuv = true_corner_projections(world, renderer.size)
    truth = dict(zip(tids.tolist(), tuv))
    d = uv - np.array([truth[int(i)] for i in ids])
    assert np.abs(d.mean(axis=0)).max() < 0.005


def test_deterministic_for_a_seed(renderer: Renderer) -> None:
    a = renderer.render(rng=np.random.default_rng(42))
    b = renderer.render(rng=np.random.default_rng(42))
    c = renderer.render(rng=np.random.default_rng(43))
    assert a.dtype == np.uint8 and a.shape == (750, 1000)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    assert np.array_equal(renderer.render(), renderer.render())  # default generator is fixed too


def test_levels_noise_and_vignetting(renderer: Renderer) -> None:
    p = renderer.world.params
    clean = renderer.render(noise=False).astype(float)
    noisy = renderer.render(rng=np.random.default_rng(0)).astype(float)
    resid = noisy - clean
    assert 1.0 < resid.std() < 4.0  # read noise 1.5 DN plus shot noise
    assert clean.min() >= p.black_dn - 1 and clean.max() <= p.white_dn + 1
    # white plate/board is darker in the corners than in the middle (vignetting)
    h, w = clean.shape
    centre = np.percentile(clean[h // 2 - 50:h // 2 + 50, w // 2 - 50:w // 2 + 50], 99)
    corner = np.percentile(clean[:60, :60], 99)
    assert corner < centre - 10


def test_floor_and_marks_appear(renderer: Renderer) -> None:
    world = renderer.world
    old = world.robot
    try:
        for mark in world.params.marks:
            world.set_robot(world.pose_with_footprint_at(mark.x_mm, mark.y_mm, 0.0))
            img = renderer.render(noise=False).astype(float)
            h, w = img.shape
            c = renderer.model.K[:2, 2].round().astype(int)
            centre = img[c[1] - 2:c[1] + 3, c[0] - 2:c[0] + 3]
            far = img[h // 2 - 60:h // 2 + 60, 50:150]
            # a dark mark (or the dark quadrants of the cross) under the footprint on a mid-grey floor
            assert img[c[1] - 20:c[1] + 21, c[0] - 20:c[0] + 21].min() < 45, mark.name
            assert 60 < np.median(far) < 130 and far.std() > 0.5, mark.name
            if mark.kind == "dot":
                assert centre.mean() < 45
    finally:
        world.set_robot(old)


def test_bad_arguments_are_named() -> None:
    world = World()
    with pytest.raises(ValueError, match="supersampling"):
        Renderer(world, (100, 80), supersampling=0)
    with pytest.raises(ValueError, match="too small"):
        Renderer(world, (4, 4))
    r = Renderer(world, (64, 48), supersampling=1)
    bad = np.eye(4)
    bad[0, 0] = -1
    with pytest.raises(ValueError, match="abs_H_cam"):
        r.render(bad)


def test_roi_equals_window_of_full_render(renderer: Renderer) -> None:
    full = renderer.render(noise=False).astype(int)
    for roi in [(0, 0, 1000, 750), (317, 211, 120, 90), (0, 700, 50, 50), (990, 0, 10, 750)]:
        x, y, w, h = roi
        part = renderer.render(noise=False, roi=roi).astype(int)
        assert part.shape == (h, w)
        diff = np.abs(part - full[y:y + h, x:x + w])
        assert diff.max() <= 1 and diff.mean() < 0.01, roi
    with pytest.raises(ValueError, match="roi"):
        renderer.render(roi=(990, 0, 20, 10))


def test_nest_rings_at_true_seats(renderer: Renderer) -> None:
    world = renderer.world
    seat_abs = world.nests_abs()["green"]
    old = world.robot
    try:
        world.set_robot(world.pose_with_footprint_at(seat_abs[0], seat_abs[1], 0.0))
        img = renderer.render(noise=False).astype(float)
        px_per_mm = renderer.model.f / (world.abs_H_cam()[2, 3] - world.params.plate_thickness_mm)
    finally:
        world.set_robot(old)
    c = np.rint(renderer.model.K[:2, 2]).astype(int)
    hole = img[c[1], c[0]]
    ring = img[c[1], c[0] + int(11.5 * px_per_mm)]
    plate = (img[c[1], c[0] + int(16.5 * px_per_mm)] if c[0] + int(16.5 * px_per_mm) < img.shape[1]
             else img[5, 5])
    assert hole < ring < plate - 20, (hole, ring, plate)


def test_ray_cache_shared_between_worlds_with_the_same_lens(renderer: Renderer) -> None:
    other = Renderer(World(renderer.world.params.with_(seed=99)), renderer.size)
    assert other._dx is renderer._dx
    assert not other._dx.flags.writeable
    wide = Renderer(World(renderer.world.params.with_(distortion=(-0.1, 0.0, 0.0, 0.0, 0.0))), (200, 150))
    assert wide._dx.shape != renderer._dx.shape


@pytest.mark.parametrize("exact", [True, False])
def test_cached_rays_match_undistort(monkeypatch, exact: bool) -> None:
    import fakes.render as render

    if not exact:  # force the pixel-centre cache with bilinear interpolation
        monkeypatch.setattr(render, "EXACT_CACHE_LIMIT", 0)
    monkeypatch.setattr(render, "_RAY_CACHE", {})
    r = Renderer(World(), (400, 300))
    ss = r.ss
    x, y = r._rays(0, 300 * ss, 0, 400 * ss)
    u = (np.arange(400 * ss) + 0.5) / ss - 0.5
    v = (np.arange(300 * ss) + 0.5) / ss - 0.5
    uu, vv = np.meshgrid(u[::7], v[::5])
    exact_xy = r.model.undistort(np.column_stack([uu.ravel(), vv.ravel()]))
    got = np.column_stack([x[::5, ::7].ravel(), y[::5, ::7].ravel()])
    err_px = np.abs(got - exact_xy).max() * r.model.f
    assert err_px < (1e-5 if exact else 1e-3), err_px


def test_ray_residuals_stored_on_disk_are_the_computed_bytes(monkeypatch, tmp_path) -> None:
    """fakes/ray_store.py: the first renderer computes and writes; a later process (here: the in-process
    cache emptied) reads the same bytes instead of computing; a damaged file is computed again; a
    folder that cannot be written is passed over."""
    import fakes.ray_store as ray_store
    import fakes.render as render

    monkeypatch.setenv("RITA_SIM_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(ray_store, "MIN_NODES", 0)
    monkeypatch.setattr(render, "_RAY_CACHE", {})
    first = Renderer(World(), (120, 90))
    files = list((tmp_path / "cache").glob("rays-*.npy"))
    assert len(files) == 1 and not list((tmp_path / "cache").glob(".*"))  # no temp file left
    computed = (first._dx.copy(), first._dy.copy())

    def not_again(*args, **kw):
        raise AssertionError("computed although stored")

    with monkeypatch.context() as m:
        m.setattr(render, "_RAY_CACHE", {})
        m.setattr(render.cv2, "undistortPoints", not_again)  # (the computation's source is in the key)
        loaded = Renderer(World(WorldParams(seed=4)), (120, 90))  # another world, the same camera
    assert np.array_equal(loaded._dx, computed[0]) and np.array_equal(loaded._dy, computed[1])
    assert loaded._dx.dtype == np.float32 and not loaded._dx.flags.writeable
    files[0].write_bytes(files[0].read_bytes()[:200])  # cut short: not a (2, h, w) float32 grid any more
    monkeypatch.setattr(render, "_RAY_CACHE", {})
    again = Renderer(World(), (120, 90))
    assert np.array_equal(again._dx, computed[0]) and files[0].stat().st_size > 200  # computed, rewritten
    monkeypatch.setattr(render, "_RAY_CACHE", {})
    Renderer(World(WorldParams(distortion=(-0.1, 0.0, 0.0, 0.0, 0.0))), (120, 90))
    assert len(list((tmp_path / "cache").glob("rays-*.npy"))) == 2  # another lens, another file
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv("RITA_SIM_CACHE", str(blocker / "cache"))  # cannot be created
    monkeypatch.setattr(render, "_RAY_CACHE", {})
    assert np.array_equal(Renderer(World(), (120, 90))._dx, computed[0])
