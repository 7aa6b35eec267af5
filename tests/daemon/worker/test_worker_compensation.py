"""The compensations in the worker's compute path, on small written datasets (no daemon).

The datasets come from tests/dataset_writer.py (the robot upright on a level floor, exact
approach points); the compensation inputs are added to their stop records the way the
worker stores them, so every expected figure follows from the geometry alone.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from calibration.compensation import tilt_of_pose
from calibration.heading_weight import NOT_LEARNED, HeadingWeight
from daemon.bus.datasets import DatasetInvalid, check_file, validate_folder
from daemon.ctl import main as ctl
from daemon.worker.compensations import store_bias
from daemon.compute.procedures import compute_referencing
from daemon.compute.inputs import heading_weight
from daemon.compute.recompute import recompute
from tests.dataset_writer import write_experiment, write_referencing

MARK = np.array([1500.0, 200.0, 3.0])
HEADINGS = (0.0, 90.0, 180.0, 270.0)
TILT = {"roll_deg": 0.02, "pitch_deg": -0.03, "n": 10, "roll_std_deg": 0.001, "pitch_std_deg": 0.001}


@pytest.fixture(scope="module")
def ref(tmp_path_factory):
    root = tmp_path_factory.mktemp("ref") / "ref"
    truth = write_referencing(root)
    return root, truth, recompute(root)[0]


def _state(root: Path) -> dict:
    return json.loads((root / "state.json").read_text())


def _edit(root: Path, fn) -> None:
    s = _state(root)
    fn(s)
    (root / "state.json").write_text(json.dumps(s))


def _with_inputs(stop: dict, stream: bool = True) -> None:
    """Level robot, the inclinometer reading its offset TILT; a straight stream P_prev → P_at."""
    stop["imu_prev"], stop["imu_at"] = dict(TILT), dict(TILT)
    if stream:
        a, b = np.array(stop["P_prev"]["abs_xyz"]), np.array(stop["P_at"]["abs_xyz"])
        pts = a + np.linspace(0, 1, 21)[:, None] * (b - a)
        stop["stream"] = {"rate_hz": 100.0, "n": 21, "abs_xyz": pts.tolist(), "host_time_ns": list(range(21)),
                          "tilt_samples": 3, "tilt_deg": [[TILT["roll_deg"], TILT["pitch_deg"]]] * 21}


@pytest.fixture(scope="module")
def exp(ref, tmp_path_factory):
    """An experiment whose calibration holds the inclinometer offset and a 0.5 mm robot-frame bias."""
    root, truth, calib = ref
    cal = {**calib, "job": "cal-1", "imu_offset_deg": [TILT["roll_deg"], TILT["pitch_deg"]],
           "robot_bias_mm": [0.5, 0.0]}
    folder = tmp_path_factory.mktemp("exp") / "exp"
    write_experiment(folder, cal, truth, MARK, headings=HEADINGS, reps=1)
    _edit(folder, lambda s: [_with_inputs(st, stream=i != 3) for i, st in enumerate(s["obs"]["stops"])])
    return folder


def _errors(result: dict) -> np.ndarray:
    return np.array([np.array(m["abs_xyz"][:2]) - MARK[:2] for m in result["marks"]])


def test_imu_offset_is_the_plate_reading_minus_the_plate_tilt(ref, tmp_path):
    root, _, calib = ref
    assert "imu_offset_deg" not in calib  # no readings: nothing stored
    s = _state(root)
    s["obs"]["runs"][0]["imu0"] = dict(TILT)
    res = compute_referencing(s["obs"], lambda f: __import__("cv2").imread(str(root / f), 0))
    roll, pitch = tilt_of_pose(np.array(res["runs"][0]["abs_H_rob"]))
    assert res["imu_offset_deg"] == pytest.approx([TILT["roll_deg"] - roll, TILT["pitch_deg"] - pitch],
                                                  abs=1e-12)
    assert check_file(res, "result", "result.json") == []


def test_none_all_and_skips_on_a_level_robot(exp):
    assert validate_folder(exp) == []
    none = recompute(exp, compensation="none")[0]
    assert none["compensation"]["requested"] == [] and none["recomputed_with"] == ["compensation"]
    assert np.abs(_errors(none)).max() < 1e-3
    both = recompute(exp, compensation="tilt,heading_fit")[0]
    # the calibration holds no weight an experiment learned: the chord, with the reason at each stop
    assert both["compensation"]["applied"] == {"tilt": 4, "heading_fit": 0}
    assert both["compensation"]["skipped"] == {
        "heading_fit": sorted(["no tracker stream was recorded along the approach", NOT_LEARNED.why])}
    assert both["compensation"]["skipped_stops"] == {
        "heading_fit": {NOT_LEARNED.why: 3, "no tracker stream was recorded along the approach": 1}}
    assert both["heading_weight"]["applied"] is False and ">= 8" in both["heading_weight"]["why"]
    assert np.abs(_errors(both)).max() < 1e-3  # level robot, offset removed, straight path: nothing changes
    full = recompute(exp)[0]  # the default: all
    assert full["compensation"]["applied"]["bias"] == 4
    # b is removed in the robot frame: it turns with the heading
    for m, e in zip(full["marks"], _errors(full)):
        psi = math.radians(m["heading_deg"])
        assert e == pytest.approx([-0.5 * math.cos(psi), -0.5 * math.sin(psi)], abs=1e-3)
    assert check_file(full, "result", "result.json") == []


def test_a_tilt_reading_moves_the_mark_by_the_reflector_height(exp, tmp_path):
    """The inclinometer says pitched 0.1° at the stop: the ground chord and the mapping change accordingly."""
    folder = tmp_path / "tilted"
    import shutil

    shutil.copytree(exp, folder)
    _edit(folder, lambda s: [st["imu_at"].update(pitch_deg=TILT["pitch_deg"] + 0.1)
                             for st in s["obs"]["stops"]])
    none = _errors(recompute(folder, compensation="none")[0])
    tilt = _errors(recompute(folder, compensation="tilt")[0])
    moved = np.linalg.norm(tilt - none, axis=1)
    # the writer's reflector height (300 mm) times the 0.1° the inclinometer claims
    assert moved == pytest.approx(300.0 * math.sin(math.radians(0.1)), rel=0.05)


def test_ritactl_recompute_compensation_and_bad_name(exp, capsys):
    assert ctl.main(["--json", "recompute", str(exp), "--compensation", "none"]) == 0
    assert json.loads(capsys.readouterr().out)["compensation"]["requested"] == []
    assert ctl.main(["recompute", str(exp), "--compensation", "tilt,heading_fit"]) == 0
    shown = capsys.readouterr().out
    assert "compensations (stops applied): tilt 4/4, heading_fit 0/4" in shown, shown
    # each reason once, counted over the stops that gave it (three stops without the learned weight)
    line = next(ln for ln in shown.splitlines() if "heading_fit skipped:" in ln)
    assert "; no tracker stream was recorded along the approach" in line, line
    assert f"{NOT_LEARNED.why} ×3" in line, line
    assert ctl.main(["recompute", str(exp), "--compensation", "tilt,wobble"]) == 5
    err = capsys.readouterr().err
    assert "wobble" in err and "Traceback" not in err, err


def test_stored_bias_round_trip(ref, tmp_path):
    """A 0.5 mm calibration error → the experiment fits b → stored → the next run applies it."""
    root, truth, calib = ref
    wrong = json.loads(json.dumps({**calib, "job": "cal-1"}))
    wrong["rob_H_scn"][0][3] += 0.5
    data = tmp_path / "data"
    (data / "calibration" / "history").mkdir(parents=True)
    (data / "calibration" / "active.json").write_text(json.dumps(wrong))
    write_experiment(tmp_path / "e1", wrong, truth, MARK, headings=HEADINGS, reps=1)
    first = {**recompute(tmp_path / "e1")[0], "job": "exp-1"}
    assert first["compensation"]["skipped"]["bias"]
    note = store_bias(data, first)
    assert "stored" in note, note
    active = json.loads((data / "calibration" / "active.json").read_text())
    assert active["robot_bias_mm"] == pytest.approx(first["metrics"]["fit"]["b"])
    assert np.hypot(*active["robot_bias_mm"]) == pytest.approx(0.5, abs=2e-3)
    assert active["robot_bias"]["job"] == "exp-1"
    # beside the history
    assert (data / "calibration" / "history" / "bias" / "cal-1.bias-exp-1.json").exists()
    assert check_file(active, "result", "active.json") == []
    write_experiment(tmp_path / "e2", active, truth, MARK, headings=HEADINGS, reps=1)
    second = recompute(tmp_path / "e2")[0]
    assert second["compensation"]["applied"]["bias"] == 4
    assert np.abs(_errors(second)).max() < 2e-3 and np.hypot(*second["metrics"]["fit"]["b"]) < 2e-3
    # the table shows the b it applied (the stored one) and names its fit for what it is: the b left
    b0 = active["robot_bias_mm"]
    assert second["compensation"]["robot_bias_mm"] == pytest.approx(b0)
    table = second["table_markdown"]
    assert f"*Robot-frame bias b applied at every stop, the calibration's (x, y) [mm]*: {b0[0]:.4f}, " \
           f"{b0[1]:.4f}" in table
    assert "*Robot-frame bias b left after the applied b, fitted to these marks (x, y) [mm]*" in table
    assert "applied at every stop" not in first["table_markdown"] and "b left" not in first["table_markdown"]
    # a bias belongs to the calibration it was measured with
    other = {**first, "calibration_job": "cal-0"}
    assert "NOT stored" in store_bias(data, other)
    # a second fit adds to what ITS experiment applied (the copy in its calibration), whatever is active now
    again = {**second, "job": "exp-2", "calibration_job": "cal-1"}
    again["compensation"] = {**again["compensation"], "robot_bias_mm": [0.2, 0.0]}
    note = store_bias(data, again)
    b = json.loads((data / "calibration" / "active.json").read_text())["robot_bias_mm"]
    # the stored b is not the table's: the message says what it is made of
    fit_b = second["heading_weight"]["b_mm"]
    assert f"b = ({b[0]:+.4f}, {b[1]:+.4f}) mm (the fitted ({fit_b[0]:+.4f}, {fit_b[1]:+.4f}) plus the " \
           f"(+0.2000, +0.0000) the stops already applied)" in note, note
    # with heading_fit (the default) the b stored is the one fitted jointly with the weight (here the chord's)
    assert b == pytest.approx(np.add(second["heading_weight"]["b_mm"], [0.2, 0.0]))
    assert second["heading_weight"]["b_mm"] == pytest.approx(second["metrics"]["fit"]["b"], abs=1e-6)
    # a b no calibration can have is refused before anything is written
    bad = {**second, "job": "exp-3", "calibration_job": "cal-1", "heading_weight": None,
           "metrics": {**second["metrics"], "fit": {**second["metrics"]["fit"], "b": [7.0, 0.0]}}}
    # 7 fitted + 0.5 applied
    assert "NOT stored" in store_bias(data, bad) and "7.500 mm" in store_bias(data, bad)
    assert json.loads((data / "calibration" / "active.json").read_text())["robot_bias_mm"] == b


def test_a_bias_the_data_contradict_is_not_stored():
    """The experiment's cluster means do not follow M + R(ψ)·b: storing b would compensate blindly."""
    from daemon.worker.compensations import biased_calibration

    result = {"job": "e1", "metrics": {"fit": {"b": [0.05, 0.0], "rms_mm": 0.08}},
              "compensation": {"requested": [], "applied": {}, "stops": 8},
              "checks": {"bias_model": {"ok": False,
                                        "message": "the cluster means do not follow M + R(ψ)·b: ..."}}}
    with pytest.raises(ValueError, match="do not follow"):
        biased_calibration({"job": "c1"}, result)
    result["checks"]["bias_model"] = {"ok": True}
    assert biased_calibration({"job": "c1"}, result)["robot_bias_mm"] == [0.05, 0.0]


def test_the_reflector_mount_offset_moves_every_mark_along_its_line_of_sight(exp, tmp_path):
    """A calibration whose reversal showed the mount 80 µm toward the tracker and 30 µm left of it:
    with `mount` each mark moves by minus that offset turned to its stop's line of sight, and its σ
    names the estimate's share; an offset not shown is not subtracted but stated in σ; a stop
    without abs_H_trk says why it cannot apply it."""
    import shutil

    from calibration.mount import MountOffset, los_R
    from daemon.compute.inputs import tracker_position

    cov = np.diag([1e-4, 1e-4])
    shown = MountOffset(np.array([0.08, 0.03]), cov, True).to_dict()
    folder = tmp_path / "mount"
    shutil.copytree(exp, folder)
    _edit(folder, lambda s: s["obs"]["calibration"].update(reflector_mount=shown))
    assert validate_folder(folder) == []
    without = recompute(folder, compensation="tilt")[0]
    res = recompute(folder, compensation="tilt,mount")[0]
    assert res["compensation"]["applied"]["mount"] == len(HEADINGS)
    assert check_file(res, "result", "result.json") == []
    assert res["compensation"]["reflector_mount_los_mm"] == pytest.approx([0.08, 0.03])
    stops = _state(folder)["obs"]["stops"]
    for m0, m1, st in zip(without["marks"], res["marks"], stops):
        P_at = np.array(st["P_at"]["abs_xyz"])
        expect = -(los_R(P_at, tracker_position(st["P_at"]))[:, :2] @ [0.08, 0.03])
        # each tracker point turned to its own line of sight: the chord turns the mark by < 1 µm here
        assert np.subtract(m1["abs_xyz"], m0["abs_xyz"])[:2] == pytest.approx(expect[:2], abs=1e-3)
        assert m1["sigma"]["parts_mm"]["mount"] == pytest.approx(math.sqrt(2e-4), rel=1e-6)
    _edit(folder, lambda s: s["obs"]["calibration"].update(
        reflector_mount={**shown, "significant": False, "why": "not shown by the data"}))
    quiet = recompute(folder, compensation="tilt,mount")[0]
    assert quiet["compensation"]["skipped"] == {"mount": ["not shown by the data"]}
    assert _errors(quiet) == pytest.approx(_errors(without), abs=1e-9)
    assert quiet["marks"][0]["sigma"]["parts_mm"]["mount"] == pytest.approx(
        math.sqrt(2e-4 + 0.08 ** 2 + 0.03 ** 2))
    _edit(folder, lambda s: [st["P_at"].pop("abs_H_trk") for st in s["obs"]["stops"]])
    blind = recompute(folder, compensation="mount")[0]
    assert "abs_H_trk" in blind["compensation"]["skipped"]["mount"][0]
    # a record the schema passes but no offset can be read from (a zero covariance) skips the compensation,
    # naming it; the marks are still measured
    _edit(folder, lambda s: s["obs"]["calibration"].update(
        reflector_mount={**shown, "cov_los_mm2": [[0, 0], [0, 0]]}))
    bad = recompute(folder, compensation="tilt,mount")[0]
    assert "reflector_mount" in bad["compensation"]["skipped"]["mount"][0]
    assert len(bad["marks"]) == len(HEADINGS)


def test_the_experiments_heading_weight_is_stored_with_the_bias_and_read_back(ref, tmp_path):
    """store_bias keeps the experiment's learned weight with b; a later job reads it (calibration_inputs'
    sibling heading_weight), and a record that cannot be read keeps the chord, naming the bad value."""
    root, truth, calib = ref
    data = tmp_path / "data"
    (data / "calibration" / "history").mkdir(parents=True)
    (data / "calibration" / "active.json").write_text(json.dumps({**calib, "job": "cal-1"}))
    write_experiment(tmp_path / "e1", {**calib, "job": "cal-1"}, truth, MARK, headings=HEADINGS, reps=1)
    first = {**recompute(tmp_path / "e1")[0], "job": "exp-1"}
    learned = HeadingWeight(0.6, 0.61, 0.05, 40, 3e-4, 1.4e-4, True, "", "cubic", 0.02)
    assert "heading_fit's weight 0.60" in store_bias(data, {**first, "heading_weight": learned.to_dict()})
    active = json.loads((data / "calibration" / "active.json").read_text())
    assert active["heading_weight"]["job"] == "exp-1" and check_file(active, "result", "active.json") == []
    assert heading_weight(active) == (learned, "")
    bad, why = heading_weight({**active, "heading_weight": {**active["heading_weight"], "weight": 7}})
    assert bad is NOT_LEARNED and "weight=7.0" in why


def test_a_stored_weight_is_applied_with_its_sigma_and_a_bad_one_keeps_the_chord(exp, tmp_path):
    """The calibration's learned weight turns the chord at every stop whose bend was fitted (here straight
    streams: slope ~0, so the marks stay), the marks state the weight's heading σ, the summary and the
    result pass the schema; a record outside the schema makes the dataset invalid, naming the field
    (one that passes the schema but not HeadingWeight.from_dict keeps the chord: the test above)."""
    import shutil
    folder = tmp_path / "exp"
    shutil.copytree(exp, folder)
    learned = HeadingWeight(0.5, 0.5, 0.05, 40, 3e-4, 1.2e-4, True, "", "lowest", 0.02, 5e-3, (0.0, 0.0))
    _edit(folder, lambda s: s["obs"]["calibration"].update(heading_weight=learned.to_dict()))
    res = recompute(folder, compensation="tilt,heading_fit")[0]
    assert res["compensation"]["applied"]["heading_fit"] == 3 and res["compensation"]["heading_weight"] == 0.5
    fitted = [m for m in res["marks"] if "heading_fit" in m["compensation"]["applied"]]
    assert len(fitted) == 3 and all(m["sigma"]["heading_source"] == "heading_fit" for m in fitted)
    assert all(m["sigma"]["heading_rad"] == pytest.approx(1.2e-4) for m in fitted)
    assert np.abs(_errors(res)).max() < 1e-3 and check_file(res, "result", "result.json") == []
    _edit(folder, lambda s: s["obs"]["calibration"]["heading_weight"].update(weight=7))
    with pytest.raises(DatasetInvalid, match="calibration.heading_weight"):  # the dataset's schema names it
        recompute(folder, compensation="tilt,heading_fit")
