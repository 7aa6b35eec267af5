"""An experiment's report files read as a metrologist's tools read them: the header says job, date, mark,
calibration, compensations, verdict and each goal met or MISSED; every CSV is one tidy table (Python's csv
module, one header row, the same number of cells in every row, numbers that parse); the plot is a PNG."""
from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import numpy as np
import pytest

from calibration.metrics import experiment_metrics
from daemon.bus.datasets import check_file
from daemon.compute.files import REPORT_FILES, write_result_files
from daemon.compute.report_tables import METRICS_COLUMNS, SIGMA_PARTS, stops_columns

HEADING = "the bend was fitted at 6 stops (the weight needs >= 8): the chord is used"


def _result(spread_mm: float, bias_applied: bool = True, seed: int = 3) -> dict:
    """A synthetic experiment result shaped as daemon/compute/procedures.py writes one: 8 directions × 3."""
    rng = np.random.default_rng(seed)
    headings = np.repeat(np.arange(8) * 45.0 - 180.0, 3) + rng.normal(0, 0.3, 24)
    xy = np.array([2200.0, 1400.0]) + rng.normal(0, spread_mm, (24, 2))
    ks = np.repeat(np.arange(8), 3)
    metrics = experiment_metrics(xy, headings, ks.tolist())
    comp_rec = {"requested": ["tilt", "heading_fit", "bias"], "applied": ["tilt", "bias"] if bias_applied
                else ["tilt"], "skipped": {"heading_fit": HEADING}}
    marks = [{"abs_xyz": [*p, 3.0], "uv": [500.0, 375.0], "std_mm": 0.03, "heading_deg": float(h), "k": int(k),
              "sigma": {"tracker_mm": 0.02, "tracker_source": "distance", "tracker_distance_mm": 4000.0,
                        "heading_rad": 2.5e-4, "heading_source": "chord", "pixel_px": 0.05, "calibration": True,
                        "parts_mm": {"tracker": 0.02, "pixel": 0.001, "calibration": 0.01, "tilt": 0.002,
                                     "heading": 0.015}},
              "compensation": comp_rec} for p, h, k in zip(xy, headings, ks)]
    return {"schema": 1, "procedure": "experiment", "software": "1.0", "job": "20261128T050000-experiment-ab12",
            "calibration_job": "20261128T040000-referencing-cd34", "marks": marks, "metrics": metrics.to_dict(),
            "params": {"mark_xy": [2200.0, 1400.0], "kind": "dot", "mark_size_mm": 1.0},
            "compensation": {"requested": ["tilt", "heading_fit", "bias"], "stops": 24,
                             "applied": {"tilt": 24, "heading_fit": 0, "bias": 24 if bias_applied else 0},
                             "skipped": {"heading_fit": [HEADING]}, "skipped_stops": {"heading_fit": {HEADING: 24}},
                             "imu_offset_deg": [0.01, -0.02], "robot_bias_mm": [-0.002, 0.0063],
                             "reflector_mount_los_mm": None, "heading_weight": None},
            "table_markdown": metrics.to_markdown(), "table_csv": metrics.to_csv(),
            "checks": {"bias_model": {"ok": True, "message": ""}}, "verdict": "ok", "messages": []}


def _table(text: str) -> list[dict[str, str]]:
    rows = list(csv.reader(io.StringIO(text)))
    assert rows and all(len(r) == len(rows[0]) for r in rows), "one table: every row as wide as the header"
    assert not any(r == [] for r in rows), "no blank line: a second table would follow one"
    return [dict(zip(rows[0], r)) for r in rows[1:]]


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    out = {}
    for name, spread in (("met", 0.02), ("missed", 0.12)):
        root = tmp_path_factory.mktemp(name)
        out[name] = (root, write_result_files(root, _result(spread), dataset=f"/data/procedures/{name}-job"))
    return out


def test_the_report_files_are_listed_and_written(written):
    root, result = written["met"]
    assert result["files"] == REPORT_FILES
    assert all((root / f).stat().st_size > 0 for f in REPORT_FILES)
    assert (root / "clusters.png").read_bytes().startswith(b"\x89PNG")
    assert check_file(json.loads((root / "result.json").read_text()), "result", "result.json") == []


def test_the_header_says_what_a_metrologist_files(written):
    md = (written["met"][0] / "report.md").read_text()
    head = md.split("## The paper's table")[0]
    for field in ("job", "date", "dataset", "mark", "calibration", "compensations", "robot-frame bias", "verdict",
                  "goals", "angles"):
        assert f"- **{field}**" in head, field
    assert "20261128T050000-experiment-ab12" in head and "20261128T040000-referencing-cd34" in head
    assert "met-job (/data/procedures/met-job)" in head
    assert "robot-frame bias b = (-0.0020, +0.0063) mm, the calibration's" in head
    assert f"heading_fit: applied at 0 of 24 stops; skipped: {HEADING} ×24" in head
    assert head.count(HEADING) == 1, "a repeated reason is counted, not repeated"
    assert "| **All** |" in md  # the paper's table follows the header


def test_every_goal_line_of_the_report_says_met_or_missed(written):
    for name, expect in (("met", "met"), ("missed", "**MISSED**")):
        md = (written[name][0] / "report.md").read_text()
        goals = [ln for ln in md.splitlines() if "(goal " in ln]
        assert len(goals) == 2, goals
        assert all(ln.endswith((": met", ": **MISSED**")) for ln in goals), goals
        assert goals[0].startswith("  - enclosing diameter") and goals[0].endswith(expect)
        rows = {r["metric"]: r for r in _table((written[name][0] / "report_metrics.csv").read_text())}
        assert rows["enclosing_diameter"]["goal_verdict"] == expect.strip("*")
        assert float(rows["enclosing_diameter"]["goal_limit"]) == 0.25 and rows["centroid_mean"]["goal_verdict"] == ""


def test_the_csvs_are_tidy_tables_with_documented_columns(written):
    root, result = written["met"]
    table = _table((root / "report.csv").read_text())
    assert [r["direction"] for r in table][-1] == "All" and len(table) == 9
    assert float(table[0]["mean_x_mm"]) == pytest.approx(result["metrics"]["clusters"][0]["mean"][0], abs=1e-12)
    assert table[-1]["heading_min_deg"] == ""
    metrics = _table((root / "report_metrics.csv").read_text())
    assert list(metrics[0]) == METRICS_COLUMNS
    assert all(float(r["value"]) == float(r["value"]) for r in metrics)  # one number a cell, never a pair
    stops = _table((root / "report_stops.csv").read_text())
    assert list(stops[0]) == stops_columns() and len(stops) == 24
    numeric = [c for c in stops_columns() if c.endswith(("_mm", "_deg", "_px", "_rad")) or c in ("stop", "k")]
    assert all(float(r[c]) == float(r[c]) for r in stops for c in numeric if r[c] != ""), "numbers parse"
    assert float(stops[5]["x_mm"]) == result["marks"][5]["abs_xyz"][0]  # in full, as stored
    s0 = stops[0]
    assert (s0["stop"], s0["direction"], s0["tilt"], s0["heading_fit"], s0["mount"]) == \
        ("0", "down", "applied", "skipped", "not requested")
    assert s0["heading_fit_skipped_because"] == HEADING and float(s0["std_heading_mm"]) == 0.015
    assert s0["std_mount_mm"] == ""  # no mount term at this stop: empty, not 0


def test_the_bias_shown_is_named_for_what_it_is(written, tmp_path):
    rows = {r["metric"]: r for r in _table((written["met"][0] / "report_metrics.csv").read_text())}
    assert float(rows["bias_applied_x"]["value"]) == -0.002 and "bias_left_fitted_x" in rows
    assert "bias_fitted_x" not in rows
    write_result_files(tmp_path, _result(0.02, bias_applied=False))
    rows = {r["metric"]: r for r in _table((tmp_path / "report_metrics.csv").read_text())}
    assert "bias_fitted_x" in rows and "bias_applied_x" not in rows and "bias_left_fitted_x" not in rows


def test_the_plot_header_and_angle_labels(written):
    from daemon.compute.report import _direction_label, _header_text

    text = _header_text(written["missed"][1])
    assert "MISSED" in text and "job:" in text and "angles:" in text and "ACS +x towards +y" in text
    assert _direction_label("up", -0.04, 5) == "up: ψ = 0.0°, 5 stops"  # never "-0°"


def test_ritactl_marks_the_experiments_goals(written, capsys):
    from daemon.ctl.calib import show_result

    for name, verdict in (("met", "met"), ("missed", "MISSED")):
        result = written[name][1]
        show_result({k: result[k] for k in ("procedure", "verdict", "messages", "dataset", "table_markdown",
                                            "files", "compensation", "metrics")})
        goals = [ln for ln in capsys.readouterr().out.splitlines() if "(goal " in ln]
        assert len(goals) == 2 and goals[0].strip().startswith("enclosing diameter"), goals
        assert goals[0].endswith(f": {verdict}") and all(ln.endswith((": met", ": MISSED")) for ln in goals)


def test_no_goal_is_printed_without_its_verdict_anywhere():
    """Every goal the product and the demo print goes through daemon/bus/figures.py (goal_text, goal_cell,
    experiment_goal_lines), which ends it in met or MISSED: no other source spells a goal out itself."""
    import re
    from pathlib import Path

    root = Path(__file__).resolve().parents[3]
    spelled = re.compile(r"""["'][^"'\n]*\(?goal\s*(<=|>=|<|>|≤|≥)\s*[\d{]""")
    sources = [p for d in ("daemon", "fakes", "calibration") for p in (root / d).rglob("*.py")]
    sources += list((root / "daemon" / "console").rglob("*.js"))
    found = [f"{p.relative_to(root)}:{i}" for p in sources if p.name != "figures.py"
             for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1) if spelled.search(line)]
    assert found == [], f"a goal spelled out without figures.py's verdict: {found}"


def test_a_long_header_makes_the_plot_taller_rather_than_cover_the_legend(written):
    import struct

    from daemon.compute.report import plot_clusters

    def height(png: bytes) -> int:
        return struct.unpack(">II", png[16:24])[1]  # the IHDR's width, height

    result = written["met"][1]
    short = height(plot_clusters(result))
    long = height(plot_clusters({**result, "messages": [f"reason {i}: " + "x " * 100 for i in range(12)]}))
    assert short == 800 and long > short + 200, (short, long)


def test_every_sigma_part_is_a_documented_column_and_a_schema_part():
    """report_stops.csv's std_<part>_mm columns, docs/datasets.md's table and the result schema's
    ``sigma.parts_mm`` name the same parts (a part added to one and not the others fails here)."""
    root = Path(__file__).resolve().parents[3]
    doc = (root / "docs" / "datasets.md").read_text()
    schema = json.loads((root / "daemon" / "bus" / "schemas" / "result.schema.json").read_text())
    assert set(schema["$defs"]["mark_sigma"]["properties"]["parts_mm"]["properties"]) == set(SIGMA_PARTS)
    assert [p for p in SIGMA_PARTS if f"`std_{p}_mm`" not in doc] == []
