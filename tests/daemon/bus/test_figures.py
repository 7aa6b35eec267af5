"""daemon/bus/figures.py: every figure printed with a goal says met or MISSED; repeated reasons are counted."""
from __future__ import annotations

import math

import pytest

from daemon.bus.figures import Goal, counted, counted_from, goal_cell, goal_text, verdict


@pytest.mark.parametrize("value, goal, want", [
    (0.0162, Goal("<", 0.015, "°"), "MISSED"), (0.0148, Goal("<", 0.015, "°"), "met"),
    (0.015, Goal("<", 0.015, "°"), "MISSED"), (0.25, Goal("<=", 0.25, "mm"), "met"),
    (0.9, Goal(">=", 0.8), "met"), (0.7, Goal(">", 0.8), "MISSED"),
    (math.nan, Goal("<=", 1.0), "MISSED"), (math.inf, Goal(">=", 1.0), "MISSED")])
def test_goal_text_ends_in_its_verdict(value, goal, want):
    text = goal_text(value, goal, ".4f", "rotation")
    assert text.endswith(f": {want}") and text.startswith("rotation ")
    assert goal.met(value) == (want == "met")


def test_goal_text_spells_the_value_the_goal_and_the_unit():
    assert goal_text(0.0162, Goal("<", 0.015, "°"), ".4f", "rotation") \
        == "rotation 0.0162° (goal < 0.015°): MISSED"
    assert goal_text(14.3, Goal("<", 60, "µm"), ".1f", "t_xy") == "t_xy 14.3 µm (goal < 60 µm): met"
    assert goal_text(0.021, Goal("<=", 0.1, "%")) == "0.021% (goal ≤ 0.1%): met"
    assert goal_text(math.nan, Goal("<=", 1.5, "px")) == "nan px (goal ≤ 1.5 px): MISSED"


def test_goal_cell_marks_a_miss_in_bold():
    assert goal_cell(0.2, Goal("<=", 0.25, "mm")) == "≤ 0.25 met"
    assert goal_cell(0.3, Goal("<=", 0.25, "mm")) == "≤ 0.25 **MISSED**"
    assert verdict(True) == "met" and verdict(False) == "MISSED"


def test_a_goal_with_an_unknown_comparison_is_refused():
    with pytest.raises(ValueError, match="op"):
        Goal("=<", 1.0)


def test_repeated_reasons_are_counted_not_repeated():
    reasons = ["no stream"] * 7 + ["no offset", "no stream"]
    assert counted(reasons) == ["no stream ×8", "no offset"]
    assert counted_from({"no stream": 7, "no offset": 1}) == ["no stream ×7", "no offset"]
    assert counted([]) == []


def test_reasons_that_differ_only_in_numbers_are_one_reason_with_ranges():
    reasons = [f"its ends lie {a} and {b} mm beside the chord, allowed 0.050 mm"
               for a, b in (("0.002", "0.061"), ("0.012", "0.137"), ("0.007", "0.133"))]
    assert counted(reasons) == \
        ["its ends lie 0.002–0.012 and 0.061–0.137 mm beside the chord, allowed 0.050 mm ×3"]
    # another count of numbers is another reason
    two = ["fitted at 6 stops", "fitted at 6 of 8 stops"]
    assert counted(two) == two


def test_a_worse_figure_names_the_compensation_that_made_it_worse():
    from daemon.bus.figures import worse_lines

    comp = {"requested": ["tilt", "bias"], "stops": 8, "applied": {"tilt": 8, "bias": 8}, "skipped": {}}
    lines = worse_lines("enclosing diameter", 0.216, 0.237, comp, True, {"tilt": 0.250, "bias": 0.210})
    assert lines == ["WORSE with the compensations: enclosing diameter 0.216 → 0.237 mm (+0.021 mm); bias made "
                     "it worse", "  - each left out alone: without tilt 0.250 mm, without bias 0.210 mm"]
    none = worse_lines("enclosing diameter", 0.216, 0.237, comp, True, {"tilt": 0.240, "bias": 0.237})
    assert none[0].endswith("; no one compensation alone did") and "  - possible reasons:" in none
    assert worse_lines("enclosing diameter", 0.216, 0.2164, comp) == []  # not worse as printed
