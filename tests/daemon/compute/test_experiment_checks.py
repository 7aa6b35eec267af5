"""An experiment's own data against the figures it states, and the calibration it stores (issue: accuracy that
knows when it does not know).

Datasets from the independent writer (tests/dataset_writer.py): a referencing and an 8-direction
experiment, one stop per direction, to which the tests add what they need (tracker noise beyond the
stated σ, a stream along each final move, another calibration).
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from daemon.bus.datasets import check_file
from daemon.compute.procedures import compute_measure_mark, no_mount_why
from daemon.compute.recompute import BiasNotStored, recompute, store_bias_offline
from daemon.ctl import main as ctl
from daemon.worker.compensations import store_bias
from tests.dataset_writer import point, write_experiment, write_referencing

SPEED = 100.0  # mm/s along the streams added here
RATE = 20.0  # Hz


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    """(referencing result, experiment folder) with a straight stream of 40 points along every final move."""
    tmp = tmp_path_factory.mktemp("checks")
    rob_H_cam = write_referencing(tmp / "ref")
    ref = recompute(tmp / "ref")[0]
    folder = tmp / "exp"
    write_experiment(folder, ref, rob_H_cam, np.array([1500.0, 200.0, 3.0]),
                     headings=tuple(45.0 * k for k in range(8)), reps=1)
    state = json.loads((folder / "state.json").read_text())
    for i, stop in enumerate(state["obs"]["stops"]):
        a, b = (np.array(stop[k]["abs_xyz"]) for k in ("P_prev", "P_at"))
        f = np.linspace(0.0, 1.0, 40)
        t = (f * np.linalg.norm(b - a) / SPEED * 1e9).astype(np.int64) + 10 ** 12 * (i + 1)
        stop["stream"] = {"n": 40, "abs_xyz": (a + np.outer(f, b - a)).tolist(), "host_time_ns": t.tolist(),
                          "rate_hz": RATE, "tilt_samples": 0}
    (folder / "state.json").write_text(json.dumps(state))
    return ref, folder


def _copy(folder: Path, tmp: Path, edit=None) -> Path:
    out = tmp / "copy"
    shutil.copytree(folder, out)
    if edit is not None:
        state = json.loads((out / "state.json").read_text())
        edit(state)
        (out / "state.json").write_text(json.dumps(state))
    return out


def test_a_scatter_the_stated_sigma_does_not_cover_warns_with_the_ratio_and_scales_every_sigma(base,
                                                                                             tmp_path):
    """0.15 mm of tracker error per stop where the dataset states 10 µm: the Birge ratio names it, the verdict
    is warn, and every mark's std_mm is the stated one times the ratio."""
    rng = np.random.default_rng(1)

    def shift(state):
        for stop in state["obs"]["stops"]:
            d = np.append(rng.normal(0.0, 0.15, 2), 0.0)
            for k in ("P_prev", "P_at"):  # both points: the heading stays, the mark moves
                stop[k] = point(np.array(stop[k]["abs_xyz"]) + d)
            stop.pop("stream")

    result, _ = recompute(_copy(base[1], tmp_path, shift), compensation="none")
    check = result["checks"]["sigma"]
    assert result["verdict"] == "warn" and not check["ok"] and check["birge_ratio"] > 1.5
    assert check["scale"] == max(check["birge_ratio"], check["coverage_factor"])
    assert any(f"Birge ratio {check['birge_ratio']:.2f}" in m and f"scaled by {check['scale']:.2f}" in m
               for m in result["messages"])
    for m in result["marks"]:
        assert m["std_mm"] == pytest.approx(m["sigma"]["stated_mm"] * check["scale"])
        assert m["sigma"]["scale"] > 1.5


def test_recompute_store_bias_writes_what_the_live_store_bias_stores(base, tmp_path, capsys):
    """The same experiment stored live (active.json = the calibration it used) and offline: equal records."""
    ref, folder = base
    result, _ = recompute(folder)
    data = tmp_path / "data"
    (data / "calibration").mkdir(parents=True)
    (data / "calibration" / "active.json").write_text(json.dumps(ref))
    assert "stored in the active calibration" in store_bias(data, result)
    live = json.loads((data / "calibration" / "active.json").read_text())
    offline = store_bias_offline(folder, result, tmp_path / "out.json", stored=live["robot_bias"]["stored"])
    assert json.loads((tmp_path / "out.json").read_text()) == live == offline
    assert live["sigma_check"]["job"] == result["job"] and "heading_weight" in live
    # the verb: the file, the same record but its time stamp, and the exit of the verdict
    assert ctl.main(["recompute", str(folder), "--store-bias", str(tmp_path / "cli.json")]) == 0
    cli = json.loads((tmp_path / "cli.json").read_text())
    assert {**cli, "robot_bias": {**cli["robot_bias"], "stored": None}} == {
        **live, "robot_bias": {**live["robot_bias"], "stored": None}}
    assert "as the live store_bias would store it" in capsys.readouterr().out


def test_store_bias_offline_refuses_what_the_live_one_refuses_and_writes_nothing(base, tmp_path):
    ref, folder = base
    result, _ = recompute(folder)
    bad = {**result, "metrics": {**result["metrics"], "fit": None}}
    with pytest.raises(BiasNotStored, match="NOT stored: the experiment fitted no robot-frame bias"):
        store_bias_offline(folder, bad, tmp_path / "out.json")
    assert not (tmp_path / "out.json").exists()
    with pytest.raises(ValueError, match="applies to an experiment dataset, not a referencing"):
        store_bias_offline(folder, {**result, "procedure": "referencing"}, tmp_path / "out.json")


def test_a_measure_mark_states_the_sigma_the_last_experiment_validated(base):
    ref, folder = base
    stop = json.loads((folder / "state.json").read_text())["obs"]["stops"][0]

    def load(name):
        return cv2.imread(str(folder / name), cv2.IMREAD_GRAYSCALE)

    plain = compute_measure_mark({"calibration": ref, "stop": stop, "compensation": "none"}, load)
    calib = {**ref, "sigma_check": {"scale": 1.7, "birge_ratio": 1.7, "ok": False, "job": "e1"}}
    scaled = compute_measure_mark({"calibration": calib, "stop": stop, "compensation": "none"}, load)
    assert plain["mark"]["std_mm"] == plain["mark"]["sigma"]["stated_mm"] and plain["messages"] == []
    assert scaled["mark"]["std_mm"] == pytest.approx(1.7 * plain["mark"]["std_mm"])
    assert scaled["mark"]["sigma"]["scale_source"] == "e1" and "(e1)" in scaled["messages"][0]
    # a stored bias's covariance is a part of the mark it corrects; a record that is not one is named
    biased = {**ref, "robot_bias_mm": [0.01, 0.0], "robot_bias": {"cov_mm2": [[4e-4, 0.0], [0.0, 1e-4]]}}
    mark = compute_measure_mark({"calibration": biased, "stop": stop, "compensation": "bias"}, load)
    assert mark["mark"]["sigma"]["parts_mm"]["bias"] == pytest.approx(np.sqrt(5e-4))
    assert mark["messages"] == []
    assert check_file(mark, "result", "result.json") == []
    bad = {**biased, "robot_bias": {"cov_mm2": [[4e-4, 1.0], [0.0, 1e-4]]}}
    odd = compute_measure_mark({"calibration": bad, "stop": stop, "compensation": "bias"}, load)
    assert "bias" not in odd["mark"]["sigma"]["parts_mm"]
    assert any("robot_bias.cov_mm2: [[0.0004, 1.0], [0.0, 0.0001]] is not" in m for m in odd["messages"])


def test_a_weight_learned_under_other_conditions_warns_naming_both_and_reports_the_chord(base, tmp_path):
    ref, folder = base
    own = recompute(folder, compensation="heading_fit")[0]
    cond = own["heading_weight"]["conditions"]
    assert cond["stream_rate_hz"] == RATE and cond["speed_mm_s"] == pytest.approx(SPEED, rel=1e-3)
    assert cond["distance_mm"] == pytest.approx(200.0, rel=1e-3) and cond["tilt"] is False
    assert "shape_model" in cond  # the paths' bend model (ungated weights): recorded, None when not made
    assert own["checks"]["heading_weight"] is None  # the calibration holds no weight: nothing to re-check
    assert own["chord"]["fit"] is not None and "pairwise_mean_mm" in own["chord"]
    stored = {**own["heading_weight"], "conditions": {**cond, "speed_mm_s": 300.0}, "job": "e0"}
    (tmp_path / "cal.json").write_text(json.dumps({**ref, "heading_weight": stored}))
    result = recompute(folder, compensation="heading_fit", calibration={**ref, "heading_weight": stored})[0]
    check = result["checks"]["heading_weight"]
    assert result["verdict"] == "warn" and not check["ok"]
    assert "speed_mm_s 300 learned, 100 now" in check["message"] and check["message"] in result["messages"]
    assert "applied weight" in check["message"] and "this experiment's own" in check["message"]
    assert check["shape_model"] == cond["shape_model"] and isinstance(check["chord_better"], bool)
    assert check_file(result, "result", "result.json") == []  # the new fields validate, and are checked:
    bad = {**result, "heading_weight": {**result["heading_weight"],
                                        "conditions": {**cond, "shape_model": "quartic"}}}
    assert check_file(bad, "result", "result.json") != [], "a bend model the schema does not know validates"


def test_the_mount_skip_names_the_referencings_own_reason():
    why = "P0 carries no abs_H_trk: the line of sight to the tracker is unknown"
    assert why in no_mount_why({"reversal": {"n": 2}, "reflector_mount_why": why})
    assert "--reversal" not in no_mount_why({"reversal": {"n": 2}, "reflector_mount_why": why})
    assert "one run (reference with --reversal)" in no_mount_why({"reversal": None})
    older = {"reversal": {"n": 2}, "messages": [f"reflector mount offset not estimated: {why}"]}
    assert no_mount_why(older).endswith(why)


def test_the_stored_bias_states_its_covariance_and_is_rechecked_where_it_is_applied(base, tmp_path):
    """store_bias keeps b's covariance; a mark corrected by b carries it as the part ``bias``; an experiment
    that applies a b its own marks contradict warns, naming both; one that applies b as fitted does not."""
    ref, folder = base
    first = recompute(folder, compensation="tilt,bias,mount")[0]
    data = tmp_path / "data"
    (data / "calibration").mkdir(parents=True)
    (data / "calibration" / "active.json").write_text(json.dumps(ref))
    store_bias(data, first)
    cal = json.loads((data / "calibration" / "active.json").read_text())
    C = np.array(cal["robot_bias"]["cov_mm2"])
    assert C.shape == (2, 2) and np.all(np.linalg.eigvalsh(C) > 0)
    assert C.tolist() == first["checks"]["bias"]["cov_mm2"]
    # the stored calibration validates, and its new field is checked (a reader we did not write: jsonschema)
    assert check_file(cal, "result", "active.json") == []
    assert check_file({**cal, "robot_bias": {**cal["robot_bias"], "cov_mm2": [[1.0, 0.0]]}}, "result", "a.json")
    held = recompute(folder, compensation="tilt,bias,mount", calibration=cal)[0]
    check = held["checks"]["bias"]
    assert check["ok"] and check["chi2"] < 1e-6  # the same stops: nothing of b is left
    assert all(m["sigma"]["parts_mm"]["bias"] == pytest.approx(np.sqrt(np.trace(C))) for m in held["marks"])
    assert check_file(held, "result", "result.json") == []
    moved = {**cal, "robot_bias_mm": (np.array(cal["robot_bias_mm"]) + [0.2, 0.0]).tolist()}
    off = recompute(folder, compensation="tilt,bias,mount", calibration=moved)[0]
    check = off["checks"]["bias"]
    assert off["verdict"] == "warn" and not check["ok"] and check["message"] in off["messages"]
    assert "does not hold here" in check["message"] and f"χ² {check['chi2']:.1f}" in check["message"]
    assert check["b_left_mm"][0] == pytest.approx(-0.2, abs=0.01)
    bad = {**cal, "robot_bias": {**cal["robot_bias"], "cov_mm2": [[1.0, 2.0], [0.0, 1.0]]}}
    odd = recompute(folder, compensation="tilt,bias,mount", calibration=bad)[0]
    assert odd["verdict"] == "warn" and "robot_bias.cov_mm2: [[1.0, 2.0], [0.0, 1.0]] is not" in " ".join(
        odd["messages"])
    older = {**cal, "robot_bias": {k: v for k, v in cal["robot_bias"].items() if k != "cov_mm2"}}
    old = recompute(folder, compensation="tilt,bias,mount", calibration=older)[0]
    assert "chi2" not in old["checks"]["bias"] and "bias" not in old["marks"][0]["sigma"]["parts_mm"]
