"""`make demo`'s figures against goals (fakes/demo.py, fakes/demo_floor.py) on synthetic figures: every goal
line says met or MISSED, a compensation that made a figure worse says so with its reason, reasons counted.
The demo itself is not run here (2–3 minutes): only the functions that word its figures."""
from __future__ import annotations

from fakes.demo import intrinsics_goals, referencing_goals, survey_goals
from fakes.demo_floor import summary_lines

HEADING = "the bend was fitted at 6 stops (the weight needs >= 8): the chord is used"


def _comp(heading_fit_applied: int = 0) -> dict:
    return {"requested": ["tilt", "heading_fit", "bias", "mount"], "stops": 40,
            "applied": {"tilt": 40, "heading_fit": heading_fit_applied, "bias": 40, "mount": 0},
            "skipped": {"heading_fit": [HEADING], "mount": ["not shown by the data"]},
            "skipped_stops": {"heading_fit": {HEADING: 40 - heading_fit_applied},
                              "mount": {"not shown by the data": 40}}}


def test_referencing_goals_mark_the_missed_rotation():
    lines = referencing_goals({"t_xy_mm": 0.0143, "t_z_mm": 0.0059, "rot_deg": 0.0162})
    assert lines == ["t_xy 14.3 µm (goal < 60 µm): met", "t_z 5.9 µm (goal < 45 µm): met",
                     "rotation 0.0162° (goal < 0.015°): MISSED"]
    assert all(ln.endswith(": met") for ln in referencing_goals({"t_xy_mm": 0.01, "t_z_mm": 0.01,
                                                                 "rot_deg": 0.01}))


def test_intrinsics_and_survey_goals_say_met_or_missed():
    assert [ln.rsplit(": ", 1)[1] for ln in intrinsics_goals({"df_rel": 0.0021, "pp_full_px": 0.35})] \
        == ["MISSED", "met"]
    assert [ln.rsplit(": ", 1)[1] for ln in intrinsics_goals({"df_rel": 0.0002, "pp_full_px": 1.6})] \
        == ["met", "MISSED"]
    ok, = survey_goals({"red": 0.017, "green": 0.020, "blue": 0.022})
    assert ok.endswith("the worst 22 µm (goal ≤ 50 µm): met") and "red 17 µm" in ok
    bad, = survey_goals({"red": 0.017, "green": 0.051})
    assert bad.endswith("the worst 51 µm (goal ≤ 50 µm): MISSED")


def test_the_floor_table_marks_every_goal_for_both_columns():
    without = {"enclosing": 0.30, "pairwise": 0.066, "abs_rms": 0.416, "grand_mean": 0.411}
    with_ = {"enclosing": 0.26, "pairwise": 0.023, "abs_rms": 0.059, "grand_mean": 0.028}
    lines = summary_lines(without, with_, _comp())
    assert "with tilt+bias |" in lines[0]
    rows = {ln.split(" | ")[0].lstrip("| "): ln for ln in lines[2:]}
    assert rows["enclosing diameter [mm]"].endswith("| ≤ 0.25 **MISSED** (without: MISSED) |")
    assert rows["mean pairwise distance of cluster means [mm]"].endswith("| ≤ 0.07 met (without: met) |")
    assert rows["absolute error RMS vs truth [mm]"].endswith("| ≤ 0.1 met (without: MISSED) |")
    assert not any("WORSE" in ln for ln in lines), "nothing got worse"


def test_a_figure_the_compensations_made_worse_says_so_with_its_reason():
    without = {"enclosing": 0.216, "pairwise": 0.066, "abs_rms": 0.416, "grand_mean": 0.411}
    with_ = {"enclosing": 0.237, "pairwise": 0.023, "abs_rms": 0.059, "grand_mean": 0.028}
    lines = summary_lines(without, with_, _comp())
    i = next(i for i, ln in enumerate(lines) if ln.startswith("WORSE"))
    assert lines[i] == "WORSE with the compensations: enclosing diameter 0.216 → 0.237 mm (+0.021 mm)"
    why = lines[i + 1:]
    assert why[0] == "  - possible reasons:" and any("only heading_fit corrects" in w for w in why)
    assert f"    - heading_fit applied at 0 of 40 stops: {HEADING} ×40" in why
    assert "    - mount applied at 0 of 40 stops: not shown by the data ×40" in why
    assert sum(ln.startswith("WORSE") for ln in lines) == 1


def test_worse_with_every_compensation_applied_says_the_run_does_not_show_why():
    comp = {"requested": ["tilt"], "stops": 8, "applied": {"tilt": 8}, "skipped": {}}
    same = {"enclosing": 0.2, "pairwise": 0.05, "abs_rms": 0.05, "grand_mean": 0.01}
    lines = summary_lines(same, {**same, "abs_rms": 0.06}, comp)
    assert lines[-3].startswith("WORSE with the compensations: absolute error RMS vs truth 0.050 → 0.060")
    assert "this run does not show why" in lines[-1]
    # a difference the table does not show (below its 0.001 mm) is not called worse
    assert not any("WORSE" in ln for ln in summary_lines(same, {**same, "abs_rms": 0.0502}, comp))


def test_a_worse_figure_names_the_compensation_that_made_it_worse():
    """With each compensation left out alone (the report's shifts), the one whose absence brings a figure back
    is named, and no guessed reasons follow."""
    without = {"enclosing": 0.216, "pairwise": 0.066, "abs_rms": 0.416, "grand_mean": 0.411}
    with_ = {"enclosing": 0.228, "pairwise": 0.022, "abs_rms": 0.060, "grand_mean": 0.028}
    left_out = {"tilt": {"enclosing": 0.213, "pairwise": 0.061, "abs_rms": 0.416, "grand_mean": 0.411},
                "bias": {"enclosing": 0.231, "pairwise": 0.021, "abs_rms": 0.060, "grand_mean": 0.028}}
    lines = summary_lines(without, with_, _comp(), left_out)
    worse = lines[lines.index(next(ln for ln in lines if ln.startswith("WORSE"))):]
    assert worse == ["WORSE with the compensations: enclosing diameter 0.216 → 0.228 mm (+0.012 mm); tilt made "
                     "it worse", "  - each left out alone: without tilt 0.213 mm, without bias 0.231 mm"]
