"""bench/accuracy_shapes.py's premises and one small case through the product's own experiment code."""
from __future__ import annotations

import math

import numpy as np

from bench.accuracy_shapes import COMPS, run_seed
from bench.shapes_data import dot_image
from bench.shapes_tables import tables
from calibration.marks import locate_mark


def test_the_synthetic_dot_is_located_where_the_simulation_put_it():
    rng = np.random.default_rng(7)
    for _ in range(5):
        uv = np.array([500.0, 375.0]) + rng.uniform(-30.0, 30.0, 2)
        found = np.asarray(locate_mark(dot_image(uv, 6.3, (1000, 750)), kind="dot", size_px=6.3).uv).ravel()
        assert np.linalg.norm(found - uv) < 0.02  # px: far below the simulation's 0.05 px


def test_one_changed_shape_case_is_scored_against_truth_with_the_products_verdict():
    rows = run_seed(101, (("arc", "kink-end"),), repetitions=2)
    assert [r["comp"] for r in rows] == list(COMPS)
    for r in rows:
        assert (r["learned_on"], r["shape"]) == ("arc", "kink-end") and r["verdict"] in ("ok", "warn")
        assert all(math.isfinite(r[k]) and r[k] > 0 for k in ("p95_ratio", "enclosing_mm", "abs_rms_mm"))
        assert r["max_ratio"] >= r["p95_ratio"]
    # the default applies the weight its learning experiment stored; the chord stores none
    assert rows[0]["weight"] is not None and rows[1]["weight"] is None
    text = tables(rows)
    assert "arc → kink-end" in text and "Shape changed after learning" in text


def test_the_joint_fit_comparator_keeps_the_in_sample_weight_where_the_product_keeps_the_chord():
    """bench's b/w comparator: a kink near the stop whose weight passes in-sample but the held-out directions
    prefer the chord: the product stores the chord, the comparator the weight with its joint b."""
    from bench.accuracy_shapes import joint_from_stops
    from calibration.heading_weight import learn_from_stops
    from tests.calibration.weight_world import experiment

    ex = experiment("kink", 3, n_stream=40)
    product, joint = (f(ex["stops"], ex["heads"], ex["groups"]) for f in (learn_from_stops, joint_from_stops))
    assert not product.applied and product.cv["chosen"] == "chord"
    assert joint.applied and joint.weight > 0.0 and joint.b_mm != product.b_mm
