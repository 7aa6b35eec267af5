"""Intrinsics from rendered views of the hand-held board, following the recipe; degenerate view sets."""
from __future__ import annotations

import numpy as np
import pytest

from calibration.board import DEFAULT_BOARD, Board
from calibration.errors import CalibrationError
from calibration.intrinsics import calibrate_intrinsics
from calibration.intrinsics_recipe import RECIPE, coverage_findings, same_as, tilt_findings
from fakes.board import recipe_images
from fakes.render import Renderer, world_camera_model
from fakes.world import World, WorldParams

SIZE = (800, 600)  # small for speed; the full-size figures are in bench/bench_intrinsics.py
#: a lens whose k3 is not 0: the k3 decision must come from the data (the default world's k3 is 0).
#: -0.01 is a test value of the order wide-angle calibrations report, not a measured lens
K3 = -0.01


@pytest.fixture(scope="module")
def k3_views():
    p = WorldParams()
    world = World(p.with_(distortion=p.distortion[:4] + (K3,)))
    images = recipe_images(world, Renderer(world, SIZE), np.random.default_rng(7), np.random.default_rng(8))
    return world, images


def test_k3_lens_from_the_recipe_without_a_guess(k3_views) -> None:
    world, images = k3_views
    board = Board.from_dict(DEFAULT_BOARD)
    model, report = calibrate_intrinsics(images, board, SIZE)
    true = world_camera_model(world, SIZE)  # scoring only
    assert report["k3"]["fitted"], report["k3"]
    assert not report["degenerate"] and report["warnings"] == []
    assert report["n_views_used"] == len(RECIPE) and report["rms_px"] < 0.15
    assert abs(model.f - true.f) / true.f < 0.001
    err = dict(zip(("fx", "fy", "cx", "cy"), (model.K - true.K)[[0, 1, 0, 1], [0, 1, 2, 2]]))
    err.update(zip(("k1", "k2", "p1", "p2", "k3"), model.dist - true.dist))
    for name, e in err.items():
        assert abs(e) <= 3 * report["std"][name], (name, e, report["std"][name])
    tilts = [v["tilt_deg"] for v in report["views"]]
    assert max(tilts) > 30 and min(tilts) < 10


def test_too_few_usable_views(k3_views) -> None:
    _, images = k3_views
    board = Board.from_dict(DEFAULT_BOARD)
    blank = np.full_like(images[0], 128)
    with pytest.raises(CalibrationError, match="only 2 of 4 views"):
        calibrate_intrinsics([images[0], images[1], blank, blank], board, SIZE, min_views=3)
    with pytest.raises(ValueError, match="expected 800x600"):
        calibrate_intrinsics([images[0][:10]], board, SIZE)


def _rvec(tilt_x: float, tilt_y: float) -> np.ndarray:
    return np.radians([tilt_x, tilt_y, 0.0])


@pytest.mark.parametrize("tilts, words", [
    ([(2, 1), (0, 3), (-4, 0), (1, -2), (3, 3), (0, 0)], ["near square-on", "about the image x axis and"]),
    ([(30, 0), (-30, 0), (35, 1), (0, 0), (-25, 2), (5, 0)], ["tilted about the image x axis", "tilt-y+35"]),
    ([(0, 30), (0, -35), (0, 0), (2, 1)], ["only 2 view(s)", "tilt-x+35"]),
])
def test_degenerate_view_sets_say_which_view_to_add(tilts, words) -> None:
    findings = tilt_findings([_rvec(*t) for t in tilts])
    assert len(findings) == 1 and all(w in findings[0] for w in words), findings


def test_a_good_set_has_no_findings() -> None:
    assert tilt_findings([_rvec(*t) for t in [(30, 0), (-30, 0), (0, 30), (0, -30), (0, 0)]]) == []


def test_corners_without_board_corners_are_named() -> None:
    centre = np.array([[400.0, 300.0], [100.0, 80.0]])  # only the middle and the top-left
    found = coverage_findings(centre, SIZE)
    assert len(found) == 3 and not any("top-left" in f for f in found) and "bottom-right" in found[-1]


def test_a_repeated_view_is_recognised() -> None:
    ids = np.arange(40)
    uv = np.random.default_rng(1).uniform(0, 800, (40, 2))
    assert same_as(ids, uv + 5.0, [(ids, uv)], 800) == 0  # 5 px < 3 % of 800
    assert same_as(ids, uv + 40.0, [(ids, uv)], 800) is None
