"""Plate survey: nest seats in PCS by multi-view triangulation."""
from __future__ import annotations

import numpy as np
import pytest

from calibration.camera_model import CameraModel
from calibration.errors import CalibrationError
from calibration.frames import apply_H, inv_H, make_H
from calibration.plate import NEST_NAMES
from calibration.survey import intersect_rays, survey_nests, triangulate
from fakes.world import World, WorldParams


def look_at(C: np.ndarray, X: np.ndarray, up=(1.0, 0.0, 0.0)) -> np.ndarray:
    """ref_H_cam of a camera at C whose optical axis points at X."""
    z = (X - C) / np.linalg.norm(X - C)
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    return make_H(np.column_stack([x, np.cross(z, x), z]), C)


def setup(seed=0):
    world = World(WorldParams(seed=1))
    model = CameraModel(world.camera_matrix((1000, 750)), world.dist_coeffs(), (1000, 750))
    seats = {n: P + [0, 0, world.params.smr_offset_mm] for n, P in world.nests_ref_true().items()}
    return world, model, seats


def views_of(X, model, offsets, noise=0.0, rng=None):
    Hs, uvs = [], []
    for off in offsets:
        H = look_at(X + np.asarray(off, float), X)
        uv = model.project(apply_H(inv_H(H), X)[None, :])[0]
        if noise:
            uv = uv + rng.normal(0, noise, 2)
        Hs.append(H)
        uvs.append(uv)
    return Hs, np.array(uvs)


OFFSETS = [(-150.0, 0.0, -400.0), (150.0, 20.0, -400.0), (0.0, 150.0, -380.0)]


def test_exact_triangulation_and_plate_update():
    world, model, seats = setup()
    views = {n: views_of(seats[n], model, OFFSETS[:2]) for n in NEST_NAMES}
    s = survey_nests(views, model)
    for n in NEST_NAMES:
        assert np.allclose(s.nests_ref_nst[n], seats[n], atol=1e-7)
        assert max(s.triangulations[n].reproj_px) < 1e-6
        assert s.triangulations[n].max_angle_deg > 20
    plate = s.apply_to(world.plate())
    assert np.allclose(plate.ref_P_smr(), [world.nests_ref_true()[n] for n in NEST_NAMES], atol=1e-7)
    assert "survey" in plate.notes


def test_noisy_views_give_consistent_residuals():
    world, model, seats = setup()
    rng = np.random.default_rng(3)
    X = seats["red"]
    errs = []
    for _ in range(30):
        Hs, uvs = views_of(X, model, OFFSETS, noise=0.1, rng=rng)
        t = triangulate(Hs, uvs, model)
        errs.append(np.linalg.norm(t.ref_P - X))
        assert 0 < t.rms_mm < 0.4 and max(t.reproj_px) < 0.6
    # 0.1 px at ~0.85 mm/px (f = 470 px, 400 mm away) is ~85 µm across each ray
    assert 0.02 < np.median(errs) < 0.3


def test_parallel_rays_and_bad_input_rejected():
    _, model, seats = setup()
    X = seats["green"]
    Hs, uvs = views_of(X, model, [(0, 0, -400.0), (1.0, 0, -400.0)])
    with pytest.raises(CalibrationError, match="parallel"):
        triangulate(Hs, uvs, model)
    with pytest.raises(ValueError, match="poses"):
        triangulate(Hs[:1], uvs, model)
    with pytest.raises(ValueError, match=">= 2 rays"):
        intersect_rays(np.zeros((1, 3)), np.ones((1, 3)))
    with pytest.raises(ValueError, match="no views"):
        survey_nests({"red": (Hs, uvs)}, model)


def test_mismatched_view_is_caught():
    world, model, seats = setup()
    views = {n: views_of(seats[n], model, OFFSETS) for n in NEST_NAMES}
    Hs, uvs = views["blue"]
    uvs = uvs.copy()
    uvs[2] += [15.0, 0.0]  # one view matched the wrong ring edge
    views["blue"] = (Hs, uvs)
    with pytest.raises(CalibrationError, match="blue"):
        survey_nests(views, model)
