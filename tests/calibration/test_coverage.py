"""calibration/coverage.py: an experiment's stated σ against its own scatter (the Birge ratio).

Synthetic 8 × 5 experiments built here: each stop's mark is M + R(ψ)·b plus an isotropic Gaussian
error of a known σ per stop; the stated σ is that σ, or a fraction of it.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.coverage import (ALPHA, P95_RADIUS, binomial_tail, check_sigma, chi2_quantile, scatter_sigma,
                                  stored_scale)

M = np.array([1500.0, 200.0])
B = np.array([0.03, -0.02])


def marks(seed: int, sigma_true: float = 0.03, n_dirs: int = 8, reps: int = 5):
    """(xy, headings, the true radial σ per stop): σ/√2 per coordinate, as a mark's std_mm is radial."""
    rng = np.random.default_rng(seed)
    psi = np.repeat(45.0 * np.arange(n_dirs), reps) + rng.normal(0.0, 0.5, n_dirs * reps)
    a = np.radians(psi)
    Rb = np.column_stack([np.cos(a) * B[0] - np.sin(a) * B[1], np.sin(a) * B[0] + np.cos(a) * B[1]])
    s = sigma_true * rng.uniform(0.7, 1.3, len(psi))  # each stop its own σ (the tracker's distance varies)
    return M + Rb + rng.normal(0.0, 1.0, (len(psi), 2)) * (s / math.sqrt(2.0))[:, None], psi, s


def test_the_chi2_quantile_matches_the_tables():
    """Wilson–Hilferty against tabulated χ² quantiles at 99 % (NIST/SEMATECH e-Handbook, table 1.3.6.7.4)."""
    for dof, exact in ((4, 13.277), (12, 26.217), (76, 107.583), (30, 50.892)):
        assert chi2_quantile(dof) == pytest.approx(exact, rel=0.01)


def test_a_sigma_that_holds_is_called_consistent_about_as_often_as_alpha_says():
    warns = [not check_sigma(*marks(seed)).ok for seed in range(200)]
    assert sum(warns) <= 8, sum(warns)  # α = 1 %: 2 expected of 200, P(> 8) < 1e-3


def test_a_sigma_half_the_scatter_warns_naming_the_ratio_and_scales_by_it():
    xy, psi, s = marks(3)
    c = check_sigma(xy, psi, s / 2.0)
    assert c is not None and not c.ok
    assert c.birge_ratio == pytest.approx(2.0, rel=0.2) and c.scale == max(c.birge_ratio, c.coverage_factor)
    assert f"Birge ratio {c.birge_ratio:.2f}" in c.message and f"scaled by {c.scale:.2f}" in c.message
    assert c.dof == 2 * 40 - 4 and c.alpha == ALPHA
    # the scaled σ covers: the same check with it is consistent
    assert check_sigma(xy, psi, s / 2.0 * c.scale).ok


def test_a_bias_is_the_model_not_scatter_and_a_large_sigma_is_never_shrunk():
    xy, psi, s = marks(4, sigma_true=0.001)
    c = check_sigma(xy + 0.0, psi, np.full(len(psi), 0.03))
    assert c.ok and c.birge_ratio < 0.2 and c.scale == 1.0  # b = 36 µm is fitted, not counted as scatter


def test_a_heading_dependent_error_the_model_lacks_is_caught():
    """A floor that moves the mark by 0.1 mm at one direction only: no M + R(ψ)·b holds it."""
    xy, psi, s = marks(5)
    xy[np.abs(psi - 90.0) < 5.0] += [0.1, 0.0]
    c = check_sigma(xy, psi, s)
    assert not c.ok and c.birge_ratio > 1.5


def test_common_parts_are_left_out_and_a_check_that_cannot_be_made_says_none():
    assert scatter_sigma(0.05, {"calibration": 0.03, "mount": 0.0, "tracker": 0.04}) == pytest.approx(0.04)
    assert scatter_sigma(0.01, {"mount": 0.02}) == 0.0
    assert check_sigma(np.zeros((3, 2)), [0, 90, 180], [0.01] * 3) is None  # 2 degrees of freedom
    # one heading: M and b not separated
    assert check_sigma(np.zeros((8, 2)), np.zeros(8), [0.01] * 8) is None
    assert check_sigma(np.zeros((8, 2)), 45.0 * np.arange(8), [0.0] * 8) is None


def test_a_stored_scale_is_read_or_refused_with_the_reason():
    assert stored_scale(None) == (1.0, "")
    assert stored_scale({"scale": 1.8, "job": "e1"}) == (1.8, "")
    scale, why = stored_scale({"scale": 0.5})
    assert scale == 1.0 and "scale=0.5 must be >= 1" in why
    assert "not a σ check record" in stored_scale({"ratio": 2})[1]


def test_the_binomial_tail_matches_the_tables():
    """P(X ≥ k) for Binomial(40, 0.05): 1 at k = 0, and the tabulated 0.0034 at 7 (1 − CDF(6) = 0.99658)."""
    assert binomial_tail(0, 40, 0.05) == pytest.approx(1.0)
    assert binomial_tail(7, 40, 0.05) == pytest.approx(0.0034, abs=1e-4)
    assert binomial_tail(41, 40, 0.05) == 0.0


def one_line_heavy_tailed(seed: int, sigma: float = 0.03):
    """Marks whose error lies along one line per stop (perpendicular to the heading, as a heading error moves
    a mark) and is concentrated in a few stops (as a kink that falls near the end of some moves only): 30 %
    of the stops are 1.8 σ off, the rest 0.1 σ. Its variance is the stated σ's (radial σ²), so the Birge
    ratio is about 1; a fifth of the stops lie beyond 1.73 σ, not 5 %."""
    xy, psi, s = marks(seed, sigma_true=1e-6)
    rng = np.random.default_rng(seed + 1000)
    big = rng.uniform(size=len(psi)) < 0.3
    amp = np.where(big, rng.normal(1.8, 0.2, len(psi)) * rng.choice([-1.0, 1.0], len(psi)),
                   rng.normal(0.0, 0.1, len(psi))) * sigma
    a = np.radians(psi)
    return xy + amp[:, None] * np.column_stack([-np.sin(a), np.cos(a)]), psi, np.full(len(psi), sigma)


def test_an_error_the_variance_covers_but_the_95_percent_radius_does_not_warns_by_the_coverage():
    """The Birge ratio alone passes such errors; the count of stops beyond 1.73 σ does not, and the σ
    scaled by the coverage factor covers the experiment's own residuals at 95 %."""
    checks = [check_sigma(*one_line_heavy_tailed(seed)) for seed in range(40)]
    birge_only = sum(c.birge_ratio > c.limit_ratio for c in checks)
    by_coverage = [c for c in checks if c.p_beyond < ALPHA]
    assert len(by_coverage) >= 15 and birge_only < len(by_coverage), (birge_only, len(by_coverage))
    c = by_coverage[0]
    assert not c.ok and c.scale >= c.coverage_factor > 1.0
    assert f"{c.n_beyond} of 40 stops beyond {P95_RADIUS:.2f} σ" in c.message
    assert f"coverage factor {c.coverage_factor:.2f}" in c.message
    xy, psi, s = one_line_heavy_tailed(checks.index(c))
    assert check_sigma(xy, psi, s * c.scale).p_beyond >= ALPHA


def test_a_factor_above_1_within_the_checks_is_applied_without_a_warn():
    """As the PDG's S: a σ that holds still gets its experiment's factor when it exceeds 1; the verdict stays
    ok, and the message says the factor is within the checks."""
    checks = [check_sigma(*marks(seed)) for seed in range(40)]
    scaled = [c for c in checks if c.ok and c.scale > 1.0]
    assert scaled, "an honest σ's own factor exceeds 1 in about half the experiments"
    for c in checks:
        assert c.scale == max(1.0, c.birge_ratio, c.coverage_factor)
    assert "within the checks at 1 %" in scaled[0].message and "does not cover" not in scaled[0].message
    assert all(c.message is None for c in checks if c.scale == 1.0)
