"""calibration/checks.py: the self-checks pass on data that follow the model and name what fails otherwise."""
from __future__ import annotations

import numpy as np
import pytest

from calibration.checks import bias_model_check, stream_tilt_check
from calibration.metrics import fit_bias


def experiment(extra_mm: float, reps: int, seed: int = 4, sigma: float = 0.010):
    """Cluster positions of 8 directions: M + R(ψ)·b, plus an error ∝ cos 2ψ that is no robot-frame bias."""
    rng = np.random.default_rng(seed)
    psi = np.radians(np.arange(8) * 45.0)
    b = np.array([0.05, -0.03])
    xy, labels = [], []
    for k, p in enumerate(psi):
        R = np.array([[np.cos(p), -np.sin(p)], [np.sin(p), np.cos(p)]])
        mean = np.array([100.0, 50.0]) + R @ b + extra_mm * np.cos(2 * p) * np.array([1.0, 0.0])
        xy += list(mean + rng.normal(0, sigma, (reps, 2)))
        labels += [k] * reps
    xy = np.array(xy)
    means = np.array([xy[np.array(labels) == k].mean(axis=0) for k in range(8)])
    return xy, labels, fit_bias(means, np.degrees(psi)).rms_mm


@pytest.mark.parametrize("reps", [5, 1])
def test_a_robot_frame_bias_passes(reps):
    xy, labels, rms = experiment(0.0, reps)
    out = bias_model_check(xy, labels, rms, [0.010] * len(xy))
    assert out["ok"] and out["message"] is None and out["expected_rms_mm"] > 0


@pytest.mark.parametrize("reps", [5, 1])
def test_a_heading_dependent_error_that_is_no_bias_warns(reps):
    xy, labels, rms = experiment(0.08, reps)
    out = bias_model_check(xy, labels, rms, [0.010] * len(xy))
    assert not out["ok"] and "do not follow M + R(ψ)·b" in out["message"], out


def test_stream_tilt_against_the_standstill_readings():
    t = np.column_stack([np.linspace(0.10, 0.14, 50), np.linspace(-0.2, -0.21, 50)])
    assert stream_tilt_check(t, (0.10, -0.2), (0.14, -0.21), 0.0) is None
    bad = stream_tilt_check(t + [0.05, 0.0], (0.10, -0.2), (0.14, -0.21), 0.0)
    assert bad is not None and "not used" in bad
