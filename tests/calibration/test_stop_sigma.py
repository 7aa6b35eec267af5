"""The heading σ each stop states (calibration/compensation.py, calibration/bend_fit.py): from its own data.

A stop that keeps the chord although its stream was fitted states how far its own fitted bend says the
chord may be off (never less than the a-priori path deviation); a stop that applies the weight adds
what its fitted path misses at the end of the move (a late turn a polynomial over the whole move
overshoots). Paths built here: a straight move of L = 200 mm along x with a lateral offset e(s).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from calibration.bend_fit import bend_fit
from calibration.compensation import Compensation, Stop, compensate
from calibration.heading_weight import NOT_LEARNED, HeadingWeight
from calibration.measure import CHORD_HEADING_SIGMA_RAD
from tests.calibration.weight_world import L, _ramp


def _stop(e, seed: int, sigma_stream: float = 0.005, n: int = 150) -> tuple[Stop, float]:
    """(the stop, the chord's true heading error: the path's end slope against the chord, rad)."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, L, n)
    stream = np.column_stack([s, e(s) + rng.normal(0.0, sigma_stream, n), np.zeros(n)])
    end = float(e(np.array([L]))[0] - e(np.array([L - 1e-3]))[0]) / 1e-3
    return Stop(np.zeros(3), np.array([L, 0.0, 0.0]), stream=stream), end


def turn(lo: float, hi: float, rad: float):
    """A turn of ``rad`` between lo·L and hi·L, straight elsewhere, zero at both ends."""
    return lambda s: rad * (_ramp(s, lo, hi) - s * float(_ramp(np.array([L]), lo, hi)[0]) / L)


def test_a_stop_that_keeps_the_chord_states_its_own_large_bend_not_the_a_priori_250_urad():
    """An arc whose end is 800 µrad off the chord, and no learned weight: the chord stays, and its σ says how
    far off it is (today's a-priori 250 µrad would put the error at 3.2σ)."""
    for seed in (1, 2, 3):
        k = 2 * 800e-6 / L
        stop, end = _stop(lambda s: k * s * (s - L) / 2, seed)
        a = compensate(Compensation(heading_fit=True), stop, np.eye(4), heading_weight=NOT_LEARNED)
        assert "heading_fit" not in a.applied and a.heading_sigma_basis == "stop_fit"
        assert a.sigma_heading_rad > 2.0 * CHORD_HEADING_SIGMA_RAD and abs(end) < 1.3 * a.sigma_heading_rad, (
            a.sigma_heading_rad, end)


def test_a_straight_stop_that_keeps_the_chord_never_states_less_than_the_a_priori_sigma():
    """A stream cannot see a turn whose trace across it is below its noise: the data raise the σ, never lower
    it."""
    stop, _ = _stop(lambda s: 0.0 * s, 4)
    a = compensate(Compensation(heading_fit=True), stop, np.eye(4), heading_weight=NOT_LEARNED)
    assert a.sigma_heading_rad == CHORD_HEADING_SIGMA_RAD and a.heading_sigma_basis == "a_priori"


def test_a_late_turn_the_fit_overshoots_is_in_the_stops_sigma_with_the_weight_applied():
    """A 2 mrad turn at 80–85 % of the move: a polynomial over the whole move ends far off the straight end
    that follows; the end's own line shows it, and the stated σ carries it (the weight's population σ alone
    does not)."""
    stop, end = _stop(turn(0.8, 0.85, 2000e-6), 0)
    fit = bend_fit(stop.stream, stop.abs_P_prev, stop.abs_P_at, 0.010)
    assert fit.shape not in ("other", "arc") and fit.end_lack_of_fit_rad > 0.5 * abs(fit.slope_rad - end)
    w = HeadingWeight(0.9, 0.9, 0.05, 40, 300e-6, 100e-6, True, "", model="lowest")
    a = compensate(Compensation(heading_fit=True), stop, np.eye(4), heading_weight=w)
    applied_error = 0.9 * fit.slope_rad - end
    assert "heading_fit" in a.applied and a.heading_sigma_basis == "weight"
    assert a.sigma_heading_rad == pytest.approx(math.hypot(100e-6, fit.end_lack_of_fit_rad))
    assert abs(applied_error) < 1.3 * a.sigma_heading_rad, (applied_error, a.sigma_heading_rad)


def test_a_clean_arc_misses_nothing_at_its_end():
    lofs = [bend_fit(_stop(lambda s: 2 * 300e-6 / L * s * (s - L) / 2, seed)[0].stream, np.zeros(3),
                     np.array([L, 0.0, 0.0]), 0.010).end_lack_of_fit_rad for seed in range(10)]
    assert np.median(lofs) < 30e-6 and max(lofs) < 150e-6, lofs
