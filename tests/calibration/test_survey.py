"""Rays' least-squares intersection: the plate survey's first estimate of a nest seat."""
from __future__ import annotations

import numpy as np
import pytest

from calibration.errors import CalibrationError
from calibration.survey import intersect_rays

X = np.array([12.0, -40.0, 3.0])
CENTRES = np.array([(-150.0, 0.0, -400.0), (150.0, 20.0, -400.0), (0.0, 150.0, -380.0)]) + X


def test_rays_through_a_point_meet_there_exactly():
    P, dist, angle = intersect_rays(CENTRES, X - CENTRES)
    assert np.allclose(P, X, atol=1e-9) and np.allclose(dist, 0.0, atol=1e-9)
    assert angle > 20


def test_noisy_rays_give_distances_of_their_size():
    rng = np.random.default_rng(3)
    d = (X - CENTRES) / np.linalg.norm(X - CENTRES, axis=1, keepdims=True) + rng.normal(0, 2e-4, (3, 3))
    P, dist, _ = intersect_rays(CENTRES, d)
    # 2e-4 of a 430 mm ray is ~0.09 mm across it
    assert 0.005 < np.linalg.norm(P - X) < 0.3 and 0 < max(dist) < 0.3


def test_parallel_rays_and_bad_input_rejected():
    with pytest.raises(CalibrationError, match="parallel"):
        intersect_rays(CENTRES[:2], [X - CENTRES[0], X - CENTRES[0] + [1.0, 0, 0]])
    with pytest.raises(ValueError, match=">= 2 rays"):
        intersect_rays(np.zeros((1, 3)), np.ones((1, 3)))
    with pytest.raises(ValueError, match="non-finite"):
        intersect_rays(CENTRES, [[np.nan, 0, 1]] * 3)
