"""calibration/weight_cv.py: the chord or the weight, chosen by what predicts a direction left out.

Experiments from tests/calibration/weight_world.py. The stored choice is never an in-sample fit alone:
its record carries the leave-one-direction-out figures it was chosen by.
"""
from __future__ import annotations

import numpy as np

from calibration.heading_weight import learn_from_stops
from calibration.metrics import fit_bias
from tests.calibration.weight_world import B_TRUE, experiment


def test_on_arcs_the_weight_predicts_the_directions_left_out_better_and_is_stored_with_its_figures():
    ex = experiment("arc", 1)
    w = learn_from_stops(ex["stops"], ex["heads"], ex["groups"])
    assert w.applied and w.cv is not None and w.cv["chosen"] == "weight" and w.cv["folds"] == 8
    assert w.cv["weight_rms_mm"] < 0.7 * w.cv["chord_rms_mm"], w.cv
    assert len(w.cv["weight_folds"]) == 8 and all(abs(x - w.weight) < 0.2 for x in w.cv["weight_folds"])
    assert np.hypot(*(np.array(w.b_mm) - B_TRUE)) < 0.012, w.b_mm


def test_where_the_chord_with_its_own_b_predicts_better_it_is_stored_with_that_b_and_both_figures():
    """A kink near the stop that the stream (60 points) does not resolve: in-sample the weight passes its
    test, held out the chord predicts better; the record keeps the chord, its own b, and says why with both
    figures."""
    ex = experiment("kink", 2, n_stream=60)
    w = learn_from_stops(ex["stops"], ex["heads"], ex["groups"])
    assert w.cv is not None and w.cv["chosen"] == "chord" and w.cv["chord_rms_mm"] <= w.cv["weight_rms_mm"]
    assert not w.applied and w.weight == 0.0 and w.weight_fit > 0.0
    assert f"({w.cv['chord_rms_mm']:.4f} mm RMS)" in w.why and f"({w.cv['weight_rms_mm']:.4f} mm)" in w.why
    chord_b = fit_bias(np.array([c for c, _ in ex["stops"]]), ex["heads"]).b  # equal repetitions: the same b
    assert np.allclose(w.b_mm, chord_b, atol=1e-9), (w.b_mm, chord_b)


def test_fewer_than_five_directions_cannot_be_cross_validated_and_keep_the_chord():
    ex = experiment("arc", 1, n_dirs=4, reps=5)
    w = learn_from_stops(ex["stops"], ex["heads"], ex["groups"])
    assert not w.applied and w.cv is None and "fewer than 5 directions" in w.why and w.b_mm is not None
