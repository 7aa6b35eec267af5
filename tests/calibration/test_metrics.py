"""Experiment metrics: exact enclosing circle, table figures, bias fit, renderers."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from calibration.metrics import (_circle2, _circle3, direction_name, experiment_metrics, fit_bias,
                                 min_enclosing_circle)


def min_enclosing_circle_brute(points) -> tuple[np.ndarray, float]:
    """Reference O(N⁴) solution over all pair and triple circles (small sets only)."""
    P = np.asarray(points, dtype=float)
    best = (P[0], 0.0) if len(P) == 1 else (P[0], np.inf)
    cands = [_circle2(P[i], P[j]) for i, j in itertools.combinations(range(len(P)), 2)]
    cands += [_circle3(P[i], P[j], P[k]) for i, j, k in itertools.combinations(range(len(P)), 3)]
    for c, r in cands:
        if r < best[1] and np.all(np.linalg.norm(P - c, axis=1) <= r * (1 + 1e-9) + 1e-12):
            best = (c, r)
    return best


def test_enclosing_circle_matches_brute_force_on_random_small_sets():
    rng = np.random.default_rng(0)
    for trial in range(150):
        n = int(rng.integers(1, 10))
        P = rng.normal(size=(n, 2)) * rng.uniform(0.01, 100)
        if trial % 5 == 0:  # points on a line and repeated points are legal input
            P[:, 1] = 2 * P[:, 0]
        if trial % 7 == 0 and n > 2:
            P[1] = P[0]
        c, r = min_enclosing_circle(P, seed=trial)
        cb, rb = min_enclosing_circle_brute(P)
        assert r == pytest.approx(rb, rel=1e-9, abs=1e-12)
        assert np.all(np.linalg.norm(P - c, axis=1) <= r * (1 + 1e-9) + 1e-12)


def test_enclosing_circle_far_from_origin_in_mm_keeps_micrometres():
    """The paper's coordinates: 130 m from the origin, tens-of-µm spreads."""
    rng = np.random.default_rng(1)
    P = np.array([130825.9, 8525.3]) + rng.normal(0, 0.05, size=(40, 2))
    c, r = min_enclosing_circle(P)
    _, rb = min_enclosing_circle_brute(P[:12])
    assert np.all(np.linalg.norm(P - c, axis=1) <= r + 1e-9)
    # at least two points on the circle (else it could shrink)
    on = np.abs(np.linalg.norm(P - c, axis=1) - r) < 1e-9
    assert on.sum() >= 2
    assert min_enclosing_circle(P[:12])[1] == pytest.approx(rb, abs=1e-9)


def test_known_circles():
    sq = np.array([[0, 0], [2, 0], [2, 2], [0, 2], [1, 1]], float)
    c, r = min_enclosing_circle(sq)
    assert np.allclose(c, [1, 1]) and r == pytest.approx(np.sqrt(2))
    c, r = min_enclosing_circle([[3.0, 4.0]])
    assert np.allclose(c, [3, 4]) and r == 0.0
    with pytest.raises(ValueError, match="N, 2"):
        min_enclosing_circle(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="non-finite"):
        min_enclosing_circle([[0.0, np.nan]])


def test_direction_names_follow_the_paper():
    assert [direction_name(a) for a in (0, 45, 90, 135, 180, -180, -135, -90, -45, 30)] == [
        "up", "upleft", "left", "downleft", "down", "down", "downright", "right", "upright", "30deg"]


def _experiment(b=(0.03, -0.02), M=(2200.0, 1400.0), noise=0.0, seed=0, reps=5):
    rng = np.random.default_rng(seed)
    pts, hs = [], []
    for k in range(8):
        for _ in range(reps):
            psi = 45.0 * k + rng.normal(0, 0.5)
            a = np.radians(psi)
            R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
            pts.append(np.array(M) + R @ np.array(b) + rng.normal(0, noise, 2))
            hs.append(psi)
    return np.array(pts), np.array(hs)


def test_bias_fit_recovers_M_and_b_exactly():
    pts, hs = _experiment()
    m = experiment_metrics(pts, hs)
    assert np.allclose(m.fit.M, [2200.0, 1400.0], atol=2e-4)  # cluster-mean heading vs per-point jitter
    assert np.allclose(m.fit.b, [0.03, -0.02], atol=2e-4)
    # the means lie on a circle of radius |b|: centroid distance = |b|, pairwise mean known for 8 points
    assert m.centroid_mean_mm == pytest.approx(np.hypot(0.03, 0.02), rel=1e-2)
    chords = [2 * np.sin(np.pi * abs(i - j) / 8) for i, j in itertools.combinations(range(8), 2)]
    assert m.pairwise_mean_mm == pytest.approx(np.hypot(0.03, 0.02) * np.mean(chords), rel=1e-2)


def test_fit_bias_exact_without_jitter_and_rejects_degenerate():
    psi = np.arange(8) * 45.0
    a = np.radians(psi)
    b = np.array([0.1, 0.05])
    means = np.array([[5 + np.cos(t) * b[0] - np.sin(t) * b[1], 7 + np.sin(t) * b[0] + np.cos(t) * b[1]] for t in a])
    f = fit_bias(means, psi)
    assert np.allclose(f.M, [5, 7], atol=1e-12) and np.allclose(f.b, b, atol=1e-12) and f.rms_mm < 1e-12
    with pytest.raises(ValueError, match="separate"):
        fit_bias(means[[0, 0, 0]], [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="at least 3"):
        fit_bias(means[:2], psi[:2])


def test_table_figures_and_renderers():
    pts, hs = _experiment(noise=0.02, seed=3)
    m = experiment_metrics(pts, hs)
    assert [c.name for c in m.clusters] == ["up", "upleft", "left", "downleft", "down", "downright", "right",
                                          "upright"]
    up = pts[:5]
    c0 = m.clusters[0]
    d = np.linalg.norm(up - up.mean(axis=0), axis=1)
    assert c0.n == 5 and np.allclose(c0.mean, up.mean(axis=0))
    assert c0.max_from_mean_mm == pytest.approx(d.max()) and c0.mean_from_mean_mm == pytest.approx(d.mean())
    assert c0.radius_mm == pytest.approx(min_enclosing_circle_brute(up)[1], rel=1e-9)
    assert c0.angle_range_deg[0] == pytest.approx(hs[:5].min()) and c0.angle_range_deg[1] == pytest.approx(hs[:5].max())
    down = m.clusters[4]  # headings around 180° wrap: the range must stay contiguous
    assert down.angle_range_deg[1] - down.angle_range_deg[0] < 5
    assert m.enclosing_diameter_mm == pytest.approx(2 * min_enclosing_circle(pts)[1])
    md = m.to_markdown()
    assert "| **All** |" in md and "| downleft |" in md and "cluster means, over pairs" in md
    assert f"{m.pairwise_mean_mm:.3f}" in md
    csv = m.to_csv()
    assert csv.splitlines()[0] == ",".join(m.CSV_COLUMNS)
    assert len([ln for ln in csv.splitlines() if ln.startswith(("up,", "All,"))]) == 2
    assert len(csv.splitlines()) == 1 + len(m.clusters) + 1  # one table: no blank line, no metric rows under it
    up = next(ln for ln in csv.splitlines() if ln.startswith("up,")).split(",")
    assert float(up[2]) == m.clusters[0].mean[0]  # in full precision, not the table's 3 decimals
    assert m.to_dict()["enclosing_diameter_mm"] == m.enclosing_diameter_mm


def test_metrics_bad_input_and_custom_groups():
    pts, hs = _experiment(reps=2)
    with pytest.raises(ValueError, match="headings"):
        experiment_metrics(pts, hs[:-1])
    m = experiment_metrics(pts, hs, groups=[f"g{i // 4}" for i in range(len(pts))])
    assert [c.name for c in m.clusters] == ["g0", "g1", "g2", "g3"]  # mixed headings: labels kept
    by_k = experiment_metrics(pts, hs, groups=[i // 2 for i in range(len(pts))])
    assert [c.name for c in by_k.clusters] == [c.name for c in experiment_metrics(pts, hs).clusters]


def test_a_fit_after_an_applied_bias_is_labelled_what_is_left():
    """The table's b is the fit of these marks: after the calibration's b was applied, only what is left."""
    m = experiment_metrics([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]], [0.0, 90.0, 180.0, -90.0])
    assert "*Robot-frame bias b, fitted to these marks (x, y) [mm]*" in m.to_markdown()
    m.applied_b = [-0.002, 0.0063]
    md = m.to_markdown()
    assert "*Robot-frame bias b applied at every stop, the calibration's (x, y) [mm]*: -0.0020, 0.0063" in md
    assert "*Robot-frame bias b left after the applied b, fitted to these marks (x, y) [mm]*" in md
    assert "applied_b" not in str(m.to_dict()), "recompute compares metrics key by key: no new key"
    m.applied_b, m.partly_applied = None, "3 of 8 stops only: the fitted b mixes both"
    assert "*Robot-frame bias b applied at*: 3 of 8 stops only" in m.to_markdown()
    assert "partly" not in str(m.to_dict()) and "3 of 8" not in str(m.to_dict())
