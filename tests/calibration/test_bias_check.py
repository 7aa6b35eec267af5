"""The stored robot-frame bias's covariance and its re-check (calibration/bias_check.py)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.bias_check import chord_bias, cov_in_acs, read_cov, recheck_bias
from calibration.metrics import experiment_metrics

HEADINGS = np.repeat(45.0 * np.arange(8), 5)
GROUPS = np.repeat(np.arange(8), 5)


def _experiment(rng: np.random.Generator, b: np.ndarray, per_stop: float = 0.03,
                per_direction: float = 0.01) -> np.ndarray:
    """Marks M + R(ψ)·b + a direction's shared error + each stop's own (mm)."""
    psi = np.radians(HEADINGS)
    R = np.stack([np.stack([np.cos(psi), -np.sin(psi)], -1), np.stack([np.sin(psi), np.cos(psi)], -1)], 1)
    shared = rng.normal(0.0, per_direction, (8, 2))[GROUPS]
    return np.array([1000.0, 500.0]) + R @ b + shared + rng.normal(0.0, per_stop, (len(psi), 2))


def test_the_bias_and_its_covariance_hold_over_repeated_experiments():
    """b is recovered, and (b̂ − b)ᵀ C⁻¹ (b̂ − b) averages 2 (χ² with 2 degrees of freedom) with a shared
    error per direction that the sandwich over stops alone would not see."""
    rng = np.random.default_rng(7)
    b = np.array([0.05, -0.02])
    z2 = []
    for _ in range(300):
        fitted = chord_bias(_experiment(rng, b), HEADINGS, GROUPS)
        assert fitted is not None
        est, C = fitted
        z2.append(float((est - b) @ np.linalg.inv(C) @ (est - b)))
    # the jackknife over 8 directions is a variance with 7 degrees of freedom: its χ² has a heavier tail than
    # χ²₂ (beyond the 1 % point in a few %), but not a smaller scale
    assert 1.6 < np.mean(z2) < 3.2, np.mean(z2)
    assert np.mean(np.array(z2) > 9.21) < 0.08


def test_a_bias_that_held_passes_and_one_that_moved_is_named():
    rng = np.random.default_rng(3)
    b = np.array([0.05, -0.02])
    alarms, caught = 0, 0
    for _ in range(200):
        stored = chord_bias(_experiment(rng, b), HEADINGS, GROUPS)
        assert stored is not None
        for moved, count in ((0.0, "alarms"), (0.06, "caught")):
            left = chord_bias(_experiment(rng, b - stored[0] + np.array([moved, 0.0])), HEADINGS, GROUPS)
            assert left is not None
            check = recheck_bias(stored[0], stored[1], left[0], left[1], "e1")
            if count == "alarms":
                alarms += not check.ok
            else:
                caught += not check.ok
    assert alarms / 200 < 0.05  # the level is 1 %; the jackknife's own noise adds some
    assert caught / 200 > 0.9
    bad = recheck_bias([0.05, -0.02], np.eye(2) * 1e-4, np.array([0.06, 0.0]), np.eye(2) * 1e-4, "e1")
    assert not bad.ok and bad.message is not None
    assert "(0.0500, -0.0200) mm" in bad.message and "(e1)" in bad.message
    assert "(0.0600, 0.0000)" in bad.message
    assert bad.p == pytest.approx(math.exp(-bad.chi2 / 2))


def test_a_bias_from_headings_that_cannot_separate_it_is_not_made():
    assert chord_bias(np.zeros((5, 2)), np.zeros(5), np.arange(5)) is None


def test_a_stored_covariance_that_is_not_one_is_named():
    with pytest.raises(ValueError, match=r"robot_bias.cov_mm2: \[\[1.0, 2.0\], \[0.0, 1.0\]\] is not"):
        read_cov([[1.0, 2.0], [0.0, 1.0]], "robot_bias.cov_mm2")
    with pytest.raises(ValueError, match="is not a finite symmetric"):
        read_cov([[-1.0, 0.0], [0.0, 1.0]], "x")
    with pytest.raises(ValueError, match="x: not a 2x2"):
        read_cov("nonsense", "x")
    assert read_cov([[1e-4, 0.0], [0.0, 4e-4]], "x").shape == (2, 2)


def test_a_bias_turned_into_acs_follows_the_heading():
    C = np.array([[4e-4, 0.0], [0.0, 1e-4]])
    assert cov_in_acs(C, 90.0) == pytest.approx(np.array([[1e-4, 0.0], [0.0, 4e-4]]))
    assert cov_in_acs(C, 0.0) == pytest.approx(C)


def test_the_bias_and_its_covariance_are_those_of_the_b_store_bias_stores():
    """Directions with unequal stop counts and headings that spread within a direction: chord_bias's b is
    metrics.fit.b (fit_bias on the directions' means), the b store_bias stores without a weight."""
    rng = np.random.default_rng(0)
    g = np.repeat(np.arange(8), [5, 1, 5, 2, 5, 5, 3, 5])
    psi = 45.0 * g + rng.normal(0.0, 2.0, len(g))
    c, s = np.cos(np.radians(psi)), np.sin(np.radians(psi))
    b = np.array([0.05, -0.02])
    xy = np.array([1000.0, 500.0]) + np.stack([c * b[0] - s * b[1], s * b[0] + c * b[1]], 1) \
        + rng.normal(0.0, 0.03, (len(g), 2))
    fitted = chord_bias(xy, psi, g)
    fit = experiment_metrics(xy, psi, g).fit
    assert fitted is not None and fit is not None
    assert fitted[0] == pytest.approx(np.array(fit.b), abs=1e-12)
