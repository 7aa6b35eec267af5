"""The recompute comparison is strict: a dropped mark, a changed verdict or string is a mismatch, never 0.0."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from daemon.ctl import main as ctl
from daemon.compute.recompute import Difference, compare, recompute
from tests.dataset_writer import write_experiment


def test_compare_names_every_structural_difference():
    stored = {"verdict": "ok", "marks": [{"abs_xyz": [1.0, 2.0], "k": 0}, {"abs_xyz": [3.0, 4.0], "k": 1}],
              "metrics": {"name": "N", "r": 0.5}}
    same = json.loads(json.dumps(stored))
    assert compare(same, stored) == (0.0, [])
    d, bad = compare({**same, "marks": same["marks"][:1]}, stored)
    assert bad == ["result.marks: 1 entries recomputed, 2 stored"]
    assert compare({**same, "verdict": "warn"}, stored)[1] == ["result.verdict: 'warn' recomputed, 'ok' stored"]
    assert compare({**same, "metrics": {"name": "NE", "r": 0.5}}, stored)[1] == [
        "result.metrics.name: 'NE' recomputed, 'N' stored"]
    assert compare({"verdict": "ok"}, {"verdict": "ok", "marks": []})[1] == [
        "result.marks: missing from the recomputed result"]
    assert compare({"x": None}, {"x": 1.0})[1] and compare({"x": True}, {"x": 1})[1]
    d, bad = compare({**same, "metrics": {"name": "N", "r": 0.5 + 1e-7}}, stored)
    assert bad == [] and d == pytest.approx(1e-7)
    assert math.isinf(Difference(0.0, ["x"])) and Difference(1e-9, []) < 1e-8


@pytest.fixture(scope="module")
def experiment_folder(tmp_path_factory):
    """An independent writer's experiment (tests/dataset_writer.py) with its own result stored beside it."""
    from tests.dataset_writer import write_referencing

    tmp = tmp_path_factory.mktemp("cmp")
    rob_H_cam = write_referencing(tmp / "ref")
    folder = tmp / "exp"
    write_experiment(folder, recompute(tmp / "ref")[0], rob_H_cam, np.array([1500.0, 200.0, 3.0]))
    (folder / "result.json").write_text(json.dumps(recompute(folder)[0]))
    return folder


def test_a_dropped_mark_fails_the_recompute_check(experiment_folder, capsys):
    result, diff = recompute(experiment_folder)
    assert diff == 0.0 and diff.mismatches == []
    stored = json.loads((experiment_folder / "result.json").read_text())
    stored["marks"] = stored["marks"][:-1]
    (experiment_folder / "result.json").write_text(json.dumps(stored))
    _, diff = recompute(experiment_folder)
    assert math.isinf(diff) and diff.mismatches[0].startswith("result.marks: ")
    assert ctl.main(["recompute", str(experiment_folder)]) in (0, 1)
    assert "the stored result differs (1):" in capsys.readouterr().out


def test_a_computation_failure_on_a_valid_dataset_exits_2_in_operator_words(experiment_folder, tmp_path, capsys):
    """A folder that meets its contract but whose inclinometer read 45° (no robot stands like that): exit 2,
    not 5 (5 is for a missing or invalid dataset), naming what failed."""
    import shutil

    folder = tmp_path / "exp"
    shutil.copytree(experiment_folder, folder)
    state = json.loads((folder / "state.json").read_text())
    state["obs"]["calibration"]["imu_offset_deg"] = [0.0, 0.0]
    for stop in state["obs"]["stops"]:
        stop["imu_prev"] = stop["imu_at"] = {"roll_deg": 45.0, "pitch_deg": 0.0, "n": 10}
    (folder / "state.json").write_text(json.dumps(state))
    from daemon.bus.datasets import validate_folder

    assert validate_folder(folder) == []
    code = ctl.main(["recompute", str(folder)])
    err = capsys.readouterr().err
    assert code == 2 and "computation failed on the stored data" in err and "45" in err, (code, err)
    assert "Traceback" not in err


def _edited(folder, tmp_path, fn):
    import shutil

    out = tmp_path / "edited"
    shutil.copytree(folder, out)
    state = json.loads((out / "state.json").read_text())
    fn(state)
    (out / "state.json").write_text(json.dumps(state))
    from daemon.bus.datasets import validate_folder

    return [str(p) for p in validate_folder(out)]


def test_validate_checks_the_streams_rows(experiment_folder, tmp_path):
    def stream(state):
        stop = state["obs"]["stops"][0]
        stop["stream"] = {"n": 3, "abs_xyz": [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], "tilt_deg": [[0.0, 0.0]],
                          "t_sigma_ns": [5, 6, 7]}

    problems = _edited(experiment_folder, tmp_path, stream)
    assert any("$.obs.stops[0].stream.n" in p and "3 but abs_xyz has 2 rows" in p for p in problems), problems
    assert any("$.obs.stops[0].stream.tilt_deg" in p and "1 rows" in p for p in problems), problems
    assert any("$.obs.stops[0].stream.t_sigma_ns" in p and "3 rows" in p for p in problems), problems


def test_compensation_names_are_an_enum_in_the_schema(experiment_folder, tmp_path):
    assert any("compensation" in p for p in _edited(experiment_folder, tmp_path,
                                                    lambda s: s["obs"].update(compensation="tilt,foo")))
    assert _edited(experiment_folder, tmp_path / "ok", lambda s: s["obs"].update(compensation="tilt, bias")) == []


def test_a_long_value_never_cuts_the_reason_off(experiment_folder, tmp_path):
    problems = _edited(experiment_folder, tmp_path, lambda s: s["obs"].update(sigma_t_mm=[0.001] * 500))
    hit = [p for p in problems if "sigma_t_mm" in p]
    assert hit and all(p.rstrip().endswith(("'number'", "'null'", "number", "null")) or "is not" in p for p in hit)
    assert all("..." not in p.split("is not", 1)[-1] for p in hit), hit
