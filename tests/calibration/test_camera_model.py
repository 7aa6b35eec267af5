"""CameraModel: projection/undistortion round trip and file round trips."""
from __future__ import annotations

import json

import numpy as np
import pytest

from calibration.camera_model import CameraModel
from fakes.render import world_camera_model
from fakes.world import World


@pytest.fixture(scope="module")
def model() -> CameraModel:
    return world_camera_model(World(), World().params.reduced_size)


def _grid(size: tuple[int, int], n: int = 41) -> np.ndarray:
    u, v = np.meshgrid(np.linspace(-0.5, size[0] - 0.5, n), np.linspace(-0.5, size[1] - 0.5, n))
    return np.column_stack([u.ravel(), v.ravel()])


@pytest.mark.parametrize("size", [(1000, 750), (4024, 3036)])
def test_undistort_project_round_trip_over_whole_image(size: tuple[int, int]) -> None:
    m = world_camera_model(World(), size)
    uv = _grid(size)
    xy = m.undistort(uv)
    back = m.project(np.column_stack([xy, np.ones(len(xy))]))
    assert np.abs(back - uv).max() < 1e-6
    # the distortion is real: undistorted corners differ from the pinhole mapping
    pin = (uv - m.K[:2, 2]) / [m.K[0, 0], m.K[1, 1]]
    assert np.abs(xy - pin).max() * m.f > 10


def test_rays_are_unit_and_point_through_pixels(model: CameraModel) -> None:
    uv = _grid(model.size, 9)
    d = model.rays(uv)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    assert np.abs(model.project(d * 37.0) - uv).max() < 1e-6


def test_json_round_trip_exact(model: CameraModel, tmp_path) -> None:
    p = tmp_path / "cam.json"
    p.write_text(json.dumps(model.to_dict()))
    m2 = CameraModel.from_dict(json.loads(p.read_text()))
    assert np.array_equal(m2.K, model.K) and np.array_equal(m2.dist, model.dist) and m2.size == model.size


def test_bad_input_is_named() -> None:
    with pytest.raises(ValueError, match="dist"):
        CameraModel(np.eye(3), np.zeros(4), (10, 10))
    with pytest.raises(ValueError, match="fx"):
        CameraModel(np.diag([-1.0, 1.0, 1.0]), np.zeros(5), (10, 10))
    m = CameraModel(np.array([[100.0, 0, 50], [0, 100, 40], [0, 0, 1]]), np.zeros(5), (100, 80))
    with pytest.raises(ValueError, match="in front"):
        m.project(np.array([[0.0, 0.0, -1.0]]))
    with pytest.raises(ValueError, match="uv"):
        m.undistort(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="schema"):
        CameraModel.from_dict({"schema": 99, "K": np.eye(3).tolist(), "dist": [0] * 5, "size": [1, 1]})
