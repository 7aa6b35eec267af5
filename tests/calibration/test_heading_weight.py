"""calibration/heading_weight.py: the share of the stream's fitted bend an experiment shows to help.

Synthetic 8-direction experiments built here, not by the simulator: every move ends on the
mark's stop with a bend of its own (straight, arcs, S-curves of random size, a wiggle no
polynomial of the fit follows), a robot-frame bias, noisy anchors and streams. The weight is
learned on one experiment and applied to a second one on the same paths' family; the figure is
the heading's RMS error against truth, chord against weighted fit.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.compensation import Compensation, Stop, compensate
from calibration.heading_weight import (APPLY_Z, NOT_LEARNED, HeadingWeight, learn_from_stops,
                                        learn_heading_weight, stop_marks, weighted_slope)
from tests.calibration.weight_world import model_marks

L = 200.0
R_MARK = np.array([200.0, 50.0])  # the mark in the robot frame (the camera footprint), mm
B_TRUE = np.array([0.03, -0.02])  # a robot-frame bias, mm
M_TRUE = np.array([1000.0, 2000.0])
RAD = 250e-6  # the chord's heading error, 1σ, of the assumed path deviation (docs/accuracy.md)


def _shape(kind: str, rng: np.random.Generator):
    """The lateral offset e(s) of one move, zero at both ends."""
    if kind == "straight":
        return lambda s: 0.0 * s
    if kind in ("arc", "arc+"):  # end slope against the chord = κL/2; "arc+": 300 µrad on average (one way)
        k = rng.normal(2 * 300e-6 / L if kind == "arc+" else 0.0, 2 * RAD / L)
        return lambda s: k * s * (s - L) / 2
    if kind == "s-curve":
        a = rng.normal(0.0, RAD * L / (2 * np.pi))
        return lambda s: a * np.sin(2 * np.pi * s / L)
    a = rng.normal(0.0, RAD * L / (4 * np.pi))  # "wiggle": two periods
    return lambda s: a * np.sin(4 * np.pi * s / L)


def _rot(a: float) -> np.ndarray:
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def experiment(kind: str, seed: int, weight: HeadingWeight | None = NOT_LEARNED, n_stream: int = 150,
               sigma_stream: float = 0.015, sigma_anchor: float = 0.010, reverse: bool = False):
    """(stop marks for learning, headings, heading errors in rad of the chord and of what was applied);
    ``reverse``: the robot drives every final move backwards (its x axis against the travel)."""
    rng = np.random.default_rng(seed)
    stops, heads, chord_err, used_err = [], [], [], []
    for k in range(8):
        for _ in range(5):
            e = _shape(kind, rng)
            psi_c = math.radians(45.0 * k) + rng.normal(0.0, 0.01)
            h = 1e-3
            psi_true = psi_c + float(e(np.array([L]))[0] - e(np.array([L - h]))[0]) / h + (math.pi if reverse else 0)
            P_at = M_TRUE - _rot(psi_true) @ (R_MARK - B_TRUE)
            u, n = np.array([math.cos(psi_c), math.sin(psi_c)]), np.array([-math.sin(psi_c), math.cos(psi_c)])
            s = np.linspace(0.0, L, n_stream)
            xy = P_at - L * u + np.outer(s, u) + np.outer(e(s), n) + rng.normal(0.0, sigma_stream, (n_stream, 2))
            noisy = [P_at - L * u + rng.normal(0.0, sigma_anchor, 2), P_at + rng.normal(0.0, sigma_anchor, 2)]
            stop = Stop(*(np.append(p, 0.0) for p in noisy), stream=np.column_stack([xy, np.zeros(n_stream)]),
                        reverse=reverse)
            a = compensate(Compensation(heading_fit=True), stop, np.eye(4), heading_weight=weight)
            rob_P = np.append(_rot(psi_true).T @ (M_TRUE - P_at) + B_TRUE, 0.0)
            stops.append(stop_marks(a, rob_P))
            v, c = a.abs_P_at - a.abs_P_prev, noisy[1] - noisy[0]
            heads.append(math.degrees(math.atan2(v[1], v[0])))
            chord_err.append(math.atan2(c[1], c[0]) + (math.pi if reverse else 0) - psi_true)
            used_err.append(math.atan2(v[1], v[0]) - psi_true)
    return stops, np.array(heads), np.array(chord_err), np.array(used_err)


def rms(x: np.ndarray) -> float:
    """RMS of angle errors (rad), wrapped to (−π, π]."""
    return float(np.sqrt(np.mean(np.square(np.angle(np.exp(1j * np.asarray(x)))))))


def learned(kind: str, seed: int) -> HeadingWeight:
    stops, heads, _, _ = experiment(kind, seed)
    return learn_from_stops(stops, heads)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_straight_drives_never_lose_more_than_5_percent(seed):
    """On a straight drive the chord's error is its anchors' noise, which the stream can correct in part:
    the weight may be above 0, but it never costs more than 5 %."""
    w = learned("straight", seed)
    _, _, chord, used = experiment("straight", seed + 100, w)
    assert rms(used) <= 1.05 * rms(chord), (w, rms(chord), rms(used))


def test_when_the_stream_holds_nothing_the_chord_is_kept():
    """A stream too noisy to say anything about the end slope: no weight is shown."""
    stops, heads, _, _ = experiment("straight", 9, sigma_stream=0.5, n_stream=20, sigma_anchor=0.002)
    w = learn_from_stops(stops, heads)
    assert not w.applied and w.weight == 0.0 and "chord is used" in w.why, w


@pytest.mark.parametrize("kind", ["arc", "s-curve"])
def test_bent_drives_apply_a_weight_that_beats_the_chord(kind):
    for seed in (1, 2):
        w = learned(kind, seed)
        assert w.applied and 0.3 < w.weight <= 1.0, w
        _, _, chord, used = experiment(kind, seed + 100, w)
        assert rms(used) < 0.7 * rms(chord), (kind, w, rms(chord), rms(used))
        assert w.sigma_heading_rad > 0.5 * rms(used), w  # the stated σ is not far below the error left


def test_an_s_curve_takes_the_cubic_model():
    assert learned("s-curve", 4).model == "cubic"


def test_a_wiggle_the_fit_cannot_follow_never_costs_more_than_5_percent():
    for seed in (1, 2, 3):
        w = learned("wiggle", seed)
        _, _, chord, used = experiment("wiggle", seed + 100, w)
        assert rms(used) <= 1.05 * rms(chord), (w, rms(chord), rms(used))


def test_without_a_learned_weight_the_chord_is_used_and_the_reason_given():
    stops, _, chord, used = experiment("arc", 7)
    assert rms(used) == pytest.approx(rms(chord), rel=1e-9)
    a = compensate(Compensation(heading_fit=True), Stop(np.zeros(3), np.array([200.0, 0, 0]),
                                                        stream=np.column_stack([np.linspace(0, 200, 50),
                                                                                np.zeros((50, 2))])),
                   np.eye(4), heading_weight=NOT_LEARNED)
    assert "heading_fit" not in a.applied and "no learned weight" in a.skipped["heading_fit"]


def test_too_few_fitted_stops_and_unseparable_headings_are_refused_with_a_reason():
    w = learn_heading_weight(np.zeros((5, 2)), np.ones((5, 2)), np.zeros(5), np.ones(5))
    assert not w.applied and ">= 8" in w.why
    w = learn_heading_weight(np.zeros((10, 2)), np.zeros((10, 2)), np.zeros(10), np.ones(10))
    assert not w.applied and "separate" in w.why  # one heading, no bend moves any mark
    with pytest.raises(ValueError, match="3 headings"):
        learn_heading_weight(np.zeros((4, 2)), np.zeros((4, 2)), np.zeros(3), np.zeros(4))


def test_the_chords_reason_is_kept_apart_from_its_consequence():
    """``reason`` is why the chord is kept, ``why`` adds what follows (the chord is used): a message that
    states its own consequence quotes ``reason`` and parses nothing; the field round-trips, and a record
    stored before it reads as ""."""
    w = learn_heading_weight(np.zeros((5, 2)), np.ones((5, 2)), np.zeros(5), np.ones(5))
    assert w.reason == "the bend was fitted at 5 stops (the weight needs >= 8)"
    assert w.why == w.reason + ": the chord is used"
    assert NOT_LEARNED.why == NOT_LEARNED.reason + ": the chord is used"
    assert HeadingWeight.from_dict(w.to_dict()) == w
    old = {k: v for k, v in w.to_dict().items() if k != "reason"}
    assert HeadingWeight.from_dict(old).reason == ""
    shown = learned("arc", 1)
    assert shown.applied and shown.reason == "" and shown.why == ""


def test_a_stored_record_round_trips_and_a_bad_one_names_its_field():
    w = learned("arc", 1)
    assert HeadingWeight.from_dict({**w.to_dict(), "job": "x"}) == w
    # b's covariance (calibration/bias_check.py) round-trips; a record stored before it has none
    assert w.b_cov_mm2 is not None and np.all(np.linalg.eigvalsh(np.array(w.b_cov_mm2)) > 0)
    assert HeadingWeight.from_dict({**w.to_dict(), "b_cov_mm2": None}).b_cov_mm2 is None
    with pytest.raises(ValueError, match="heading_weight: b_cov_mm2"):
        HeadingWeight.from_dict({**w.to_dict(), "b_cov_mm2": [[1.0]]})
    with pytest.raises(ValueError, match="weight=1.5"):
        HeadingWeight.from_dict({**w.to_dict(), "weight": 1.5}, "calibration: heading_weight")
    with pytest.raises(ValueError, match="model='quartic'"):
        HeadingWeight.from_dict({**w.to_dict(), "model": "quartic"})
    with pytest.raises(ValueError, match="calibration: heading_weight: not a heading weight record"):
        HeadingWeight.from_dict({"weight": 0.5}, "calibration: heading_weight")


def test_a_slope_unlike_the_learned_ones_keeps_the_chord_and_says_why():
    """A fitted slope far beyond the learning experiment's (the fit read a lean or a jolt) is not turned by
    the weight: one such stop on a short-correlation floor moved its mark by 0.28 mm before."""
    w = HeadingWeight(0.7, 0.7, 0.08, 40, 350e-6, 160e-6, True, "", slope_limit_rad=1400e-6)
    assert weighted_slope(w, 1000e-6) == pytest.approx((700e-6, 160e-6, ""))
    slope, sigma, why = weighted_slope(w, -1906e-6)
    assert (slope, sigma) == (0.0, 0.0) and "-1906 µrad is beyond the 1400 µrad" in why


@pytest.mark.parametrize("n_dirs, reps", [(8, 5), (8, 1)])
def test_learning_leaves_out_the_slopes_use_would_refuse_also_in_a_short_experiment(n_dirs, reps):
    """One wild slope cannot raise its own limit (a robust scale, not the rms: with 8 stops max|s|/rms ≤ √8
    would keep any outlier), and the limit learning used is the one later jobs apply."""
    stops, heads, _, _ = experiment("arc", 1)
    keep = [k * 5 + r for k in range(n_dirs) for r in range(reps)]
    stops, heads = [stops[i] for i in keep], heads[keep]
    chord, fits = stops[0]
    wild = [(chord, {m: (xy + [0.5, 0.5], 50e-3, s) for m, (xy, _, s) in fits.items()})] + stops[1:]
    w = learn_from_stops(wild, heads)
    assert w.n_stops <= len(stops) - 1 and w.slope_limit_rad < 5e-3, w
    assert weighted_slope(w, 50e-3)[2] and not weighted_slope(w, 0.5 * w.slope_limit_rad)[2]


def test_the_bias_stored_with_the_weight_is_fitted_with_it():
    """Bends that lean one way (a mean end slope of 300 µrad) move every chord mark along the lever arm
    turned 90°, which a bias fitted on the chord's marks absorbs; the bias fitted jointly with the weight
    is the robot's own (the writer's 30, −20 µm), so applying both later does not count the mean bend twice."""
    from calibration.metrics import fit_bias
    stops, heads, _, _ = experiment("arc+", 1)
    w = learn_from_stops(stops, heads)
    assert w.applied and w.b_mm is not None
    chord_b = fit_bias(np.array([c for c, _ in stops]), heads).b
    assert np.hypot(*(np.array(w.b_mm) - B_TRUE)) < 0.012, w.b_mm
    assert np.hypot(*(np.array(chord_b) - B_TRUE)) > 0.04, chord_b  # the chord's b carries the mean bend


def test_driving_backwards_learns_and_applies_the_same_weight():
    """The same bends and noise driven backwards onto the stops (the robot's x axis against the travel, so
    the mark lies on the other side and the experiment's marks differ): the weight agrees within its σ and
    the heading error left is the forward one's, well under the chord's."""
    fw, rv = learned("arc", 1), learn_from_stops(*experiment("arc", 1, reverse=True)[:2])
    assert rv.applied and abs(rv.weight - fw.weight) < 2 * math.hypot(fw.sigma, rv.sigma), (fw, rv)
    _, _, chord_f, used_f = experiment("arc", 101, fw)
    _, _, chord_r, used_r = experiment("arc", 101, rv, reverse=True)
    assert rms(chord_r) == pytest.approx(rms(chord_f), rel=1e-6)
    assert rms(used_r) == pytest.approx(rms(used_f), rel=0.15) and rms(used_r) < 0.7 * rms(chord_r)


def _known_weight(w_true: float, noise_mm: float, seed: int) -> HeadingWeight:
    """The weight learned from marks built exactly by the model (weight_world.py ``model_marks``)."""
    return learn_heading_weight(*model_marks(w_true, noise_mm, seed), None, "lowest", np.repeat(np.arange(8), 5))


def test_a_weight_expected_to_err_less_than_the_chord_is_applied_though_not_shown_at_3_sigma():
    """Between √2σ and 3σ applying the estimate is expected to err less than the chord (w_fit² − σ² > σ²):
    it is applied (the old significance gate at 3σ kept the chord here)."""
    w = _known_weight(0.2, 0.03, 2)
    assert APPLY_Z == pytest.approx(math.sqrt(2.0))
    assert math.sqrt(2.0) < w.weight_fit / w.sigma < 3.0, w
    assert w.applied and w.weight == pytest.approx(w.weight_fit) and w.why == "", w


def test_a_weight_below_root_2_sigma_keeps_the_chord_and_says_why():
    w = _known_weight(0.0, 0.03, 1)
    assert 0.0 < w.weight_fit < math.sqrt(2.0) * w.sigma, w
    assert not w.applied and w.weight == 0.0 and "not above √2σ" in w.why and "chord is used" in w.why, w
