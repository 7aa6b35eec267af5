"""The dataset contract: an independent writer's folder recomputes exactly; bad folders give clear reports.

The writer (tests/dataset_writer.py) uses only docs/datasets.md and the schemas, its own
projection and its own ChArUco rendering; nothing of fakes/simulate.py or fakes/.
"""
import json
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from daemon.ctl import main as ctl
from daemon.bus.datasets import check_file, png_info, validate_folder
from tests.dataset_writer import ABS_H_TRK, write_experiment, write_referencing

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """One good referencing folder and its truth (copied per test that changes it)."""
    root = tmp_path_factory.mktemp("writer") / "ref"
    return root, write_referencing(root)


def copy(written, tmp_path) -> Path:
    dst = tmp_path / "ref"
    shutil.copytree(written[0], dst)
    return dst


def edit_state(root: Path, fn) -> None:
    state = json.loads((root / "state.json").read_text())
    fn(state)
    (root / "state.json").write_text(json.dumps(state))


def rob_H_cam_error(H: np.ndarray, truth: np.ndarray) -> tuple[float, float]:
    """(translation error mm, rotation error deg)."""
    R = H[:3, :3].T @ truth[:3, :3]
    angle = np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1)))
    return float(np.linalg.norm(H[:3, 3] - truth[:3, 3])), float(angle)


def run_ctl(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "daemon.ctl.main", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)


@pytest.mark.parametrize("bits", [8, 16])
def test_independent_writer_recomputes_within_1um(tmp_path, bits, capsys):
    truth = write_referencing(tmp_path / "ref", bits=bits)
    assert png_info(tmp_path / "ref" / "run0.png")[3] == bits
    assert ctl.main(["validate", str(tmp_path / "ref")]) == 0
    code = ctl.main(["recompute", str(tmp_path / "ref"), "--out", str(tmp_path / "out")])
    assert code == 0, capsys.readouterr()
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    assert result["verdict"] == "ok" and result["job"] == "ref"  # job defaults to the folder name
    t_err, r_err = rob_H_cam_error(np.array(result["rob_H_cam"]), truth)
    assert t_err < 1e-3 and r_err < 1e-3, (t_err, r_err)
    assert check_file(result, "result", "result.json") == []
    fs = cv2.FileStorage(str(tmp_path / "out" / "result.yaml"), cv2.FILE_STORAGE_READ)
    assert np.allclose(fs.getNode("rob_H_cam").mat(), result["rob_H_cam"], atol=1e-12)
    fs.release()


def test_missing_key_names_the_file_and_json_path(written, tmp_path):
    root = copy(written, tmp_path)
    edit_state(root, lambda s: s["obs"]["runs"][0].pop("P1"))
    out = run_ctl("validate", str(root))
    assert out.returncode == 5 and "state.json: $.obs.runs[0].P1: missing" in out.stdout, out
    out = run_ctl("recompute", str(root))
    assert out.returncode == 5 and "state.json: $.obs.runs[0].P1: missing" in out.stderr, out
    assert "Traceback" not in out.stderr


def test_every_problem_is_reported_at_once(written, tmp_path):
    root = copy(written, tmp_path)

    def damage(s):
        s["obs"]["nests"]["red"]["abs_xyz"][0] = float("nan")
        s["obs"]["nests"]["green"]["x"] += 0.01  # tracker frame no longer matches abs_xyz
        s["obs"]["camera_model"]["dist"] = [0.0] * 4
        s["obs"]["plate"]["marker_mm"] = 2.5
        s["obs"]["runs"][0]["header"]["shape"] = [960, 1281]
    edit_state(root, damage)
    data = (root / "run0.png").read_bytes()
    (root / "run0.png").write_bytes(data[: len(data) // 2])
    problems = {(p.file, p.path): p.message for p in validate_folder(root)}
    assert "not a finite number" in problems["state.json", "$.obs.nests.red.abs_xyz[0]"]
    assert "differs from abs_H_trk" in problems["state.json", "$.obs.nests.green.abs_xyz"]
    assert "too short" in problems["state.json", "$.obs.camera_model.dist"]
    assert "smaller than square_mm" in problems["state.json", "$.obs.plate.marker_mm"]
    assert "truncated" in problems["state.json", "$.obs.runs[0].image"]


def test_image_must_match_its_header_and_the_camera_model(written, tmp_path):
    root = copy(written, tmp_path)
    img = cv2.imread(str(root / "run0.png"), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(root / "run0.png"), img[:, :1000])
    messages = [str(p) for p in validate_folder(root)]
    assert any("header says shape [960, 1280]" in m for m in messages), messages
    assert any("camera model size is [1280, 960]" in m for m in messages), messages
    (root / "run0.png").unlink()
    assert sorted(str(p) for p in validate_folder(root)) == [
        "dataset.json: $.entries[0].image: image run0.png: missing",
        "state.json: $.obs.runs[0].image: image run0.png: missing"]


def test_abs_H_trk_must_be_rigid(written, tmp_path):
    root = copy(written, tmp_path)
    bad = ABS_H_TRK.copy()
    bad[0, 0] *= 1.01
    edit_state(root, lambda s: s["obs"]["runs"][0]["P0"].update(abs_H_trk=bad.tolist()))
    msgs = {p.path: p.message for p in validate_folder(root)}
    assert "not orthonormal" in msgs["$.obs.runs[0].P0.abs_H_trk"]


def test_calibration_errors_exit_2_without_traceback(written, tmp_path):
    root = copy(written, tmp_path)
    edit_state(root, lambda s: s["obs"]["runs"][0].update(P1=s["obs"]["runs"][0]["P0"]))  # P0 = P1
    out = run_ctl("recompute", str(root))
    assert out.returncode == 2, out
    assert "calibration failed" in out.stderr and "robot heading undefined" in out.stderr
    assert "Traceback" not in out.stderr


def test_swapped_nest_labels_exit_2(written, tmp_path, capsys):
    root = copy(written, tmp_path)

    def swap(s):
        n = s["obs"]["nests"]
        n["red"], n["green"] = n["green"], n["red"]
    edit_state(root, swap)
    assert ctl.main(["recompute", str(root)]) == 2
    err = capsys.readouterr().err
    assert "ritactl: calibration failed" in err and "Traceback" not in err


def test_fail_verdict_exits_2_and_warn_exits_1(tmp_path, capsys):
    write_referencing(tmp_path / "short", move_mm=30.0)
    assert ctl.main(["recompute", str(tmp_path / "short")]) == 2
    assert "P0→P1 move 30.0 mm < 50 mm" in capsys.readouterr().out
    write_referencing(tmp_path / "shortish", move_mm=100.0)
    assert ctl.main(["recompute", str(tmp_path / "shortish")]) == 1
    assert "verdict=warn" in capsys.readouterr().out


def test_recompute_with_another_camera_model_and_plate(written, tmp_path, capsys):
    root = written[0]
    state = json.loads((root / "state.json").read_text())
    model = state["obs"]["camera_model"]
    other = {**model, "K": [[610.0, 0, 639.5], [0, 610.0, 479.5], [0, 0, 1]]}
    (tmp_path / "model.json").write_text(json.dumps(other))
    assert ctl.main(["--json", "recompute", str(root), "--camera-model", str(tmp_path / "model.json")]) in (0, 1)
    res = json.loads(capsys.readouterr().out)
    assert res["camera_model"]["K"][0][0] == 610.0 and res["recomputed_with"] == ["camera_model"]
    t_err, _ = rob_H_cam_error(np.array(res["rob_H_cam"]), written[1])
    assert t_err > 0.01  # a 1.7 % focal length error moves the camera by far more than 10 µm

    plate = {**state["obs"]["plate"], "smr_offset_mm": 12.7}  # a smaller reflector in the nests
    (tmp_path / "plate.json").write_text(json.dumps(plate))
    ctl.main(["--json", "recompute", str(root), "--plate", str(tmp_path / "plate.json")])
    res = json.loads(capsys.readouterr().out)
    assert res["recomputed_with"] == ["plate"]
    assert abs(res["rob_H_cam"][2][3] - written[1][2, 3]) > 1.0  # nest heights now 6.35 mm off

    (tmp_path / "bad.json").write_text(json.dumps({**model, "size": [1280]}))
    assert ctl.main(["recompute", str(root), "--camera-model", str(tmp_path / "bad.json")]) == 5
    assert "--camera-model: $.size: [1280] is too short" in capsys.readouterr().err
    assert ctl.main(["recompute", str(root), "--calibration", str(tmp_path / "model.json")]) == 5
    assert "does not apply to a referencing dataset" in capsys.readouterr().err


def test_validate_json_output_and_missing_folder(tmp_path, capsys):
    assert ctl.main(["--json", "validate", str(tmp_path / "nothing")]) == 5
    report = json.loads(capsys.readouterr().out)
    assert report["problems"][0]["message"].startswith("not a folder")
    (tmp_path / "caps").mkdir()
    assert ctl.main(["validate", str(tmp_path / "caps")]) == 5
    assert "dataset.json: $: missing file" in capsys.readouterr().out


@pytest.fixture(scope="module")
def calibration(written):
    """The referencing result of the writer's folder: what an experiment is measured with."""
    from daemon.compute.recompute import recompute

    return recompute(written[0])[0]


@pytest.mark.parametrize("bits", [8, 16])
def test_experiment_marks_within_1um_and_out_writes_report_and_plot(written, calibration, tmp_path, bits):
    mark = np.array([1500.0, 200.0, 3.0])
    write_experiment(tmp_path / "exp", calibration, written[1], mark, bits=bits)
    assert validate_folder(tmp_path / "exp") == []
    assert ctl.main(["recompute", str(tmp_path / "exp"), "--out", str(tmp_path / "out")]) == 0
    result = json.loads((tmp_path / "out" / "result.json").read_text())
    errors = [np.hypot(*(np.array(m["abs_xyz"][:2]) - mark[:2])) for m in result["marks"]]
    assert len(errors) == 4 and max(errors) < 1e-3, errors
    assert result["files"] == ["report.md", "report.csv", "report_metrics.csv", "report_stops.csv", "clusters.png"]
    report = (tmp_path / "out" / "report.md").read_text()
    assert result["table_markdown"] in report and f"- **job**: {result['job']}" in report
    assert (tmp_path / "out" / "report.csv").read_text() == result["table_csv"]
    assert (tmp_path / "out" / "clusters.png").read_bytes().startswith(b"\x89PNG")
    assert check_file(result, "result", "result.json") == []


def test_the_report_gives_each_compensations_move_per_stop(written, calibration, tmp_path):
    """report_stops.csv: the bias moved each mark by −R(ψ)·b (it removes the calibration's b, turned into
    ACS), what report_shifts.py gets from the stored pixel positions; tilt, not recorded here, moved nothing."""
    import csv

    b = np.array([0.012, -0.020])
    write_experiment(tmp_path / "exp", {**calibration, "robot_bias_mm": b.tolist()}, written[1],
                     np.array([1500.0, 200.0, 3.0]), headings=(0.0, 90.0, 180.0), reps=1)
    assert ctl.main(["recompute", str(tmp_path / "exp"), "--out", str(tmp_path / "out")]) in (0, 1)
    assert "NOT in report_stops.csv" not in (tmp_path / "out" / "report.md").read_text()
    rows = list(csv.DictReader((tmp_path / "out" / "report_stops.csv").open(encoding="utf-8")))
    assert len(rows) == 3
    for r in rows:
        psi = np.radians(float(r["heading_deg"]))
        expect = -np.array([[np.cos(psi), -np.sin(psi)], [np.sin(psi), np.cos(psi)]]) @ b
        got = [float(r["shift_bias_x_mm"]), float(r["shift_bias_y_mm"])]
        assert r["bias"] == "applied" and np.allclose(got, expect, atol=2e-5), (got, expect)
        assert r["tilt"] == "skipped" and r["shift_tilt_x_mm"] == ""
    # without compensation: the figures ritactl recompute --compensation none gives; the bias (wrong for this
    # data, which has none) made them worse, and the report names it (left out alone, the figure recovers)
    from daemon.compute.recompute import recompute

    plain = recompute(tmp_path / "exp", compensation="none")[0]["metrics"]
    figures = {r["metric"]: r for r in csv.DictReader((tmp_path / "out" / "report_metrics.csv").open())}
    assert float(figures["pairwise_mean_without_compensation"]["value"]) == pytest.approx(
        plain["pairwise_mean_mm"], abs=1e-9)
    md = (tmp_path / "out" / "report.md").read_text()
    shown = f"{plain['pairwise_mean_mm']:.3f}"
    assert f"mean pairwise distance of cluster means without compensation {shown} mm" in md
    worse = [ln for ln in md.splitlines() if "WORSE with the compensations: mean pairwise distance" in ln]
    assert len(worse) == 1 and worse[0].endswith("; bias made it worse"), worse
    shutil.rmtree(tmp_path / "out")  # a recompute with another calibration: no shifts, and the report says why
    (tmp_path / "cal.json").write_text(json.dumps(calibration))
    assert ctl.main(["recompute", str(tmp_path / "exp"), "--calibration", str(tmp_path / "cal.json"), "--out",
                     str(tmp_path / "out")]) in (0, 1)
    assert "NOT in report_stops.csv: recomputed with another calibration" in \
        (tmp_path / "out" / "report.md").read_text()


def test_mark_uncertainty_uses_the_datasets_tracker_sigma(written, calibration, tmp_path):
    from daemon.compute.recompute import recompute

    marks = []
    for sigma in (0.005, 0.050):
        write_experiment(tmp_path / f"s{sigma}", calibration, written[1], [1500.0, 200.0, 3.0], reps=1,
                         sigma_t_mm=sigma)
        marks.append(recompute(tmp_path / f"s{sigma}")[0]["marks"][0])
    # the tracker term (two points, ~1.7σ each in xy) scales with σ_t; the heading term (250 µrad × the
    # ~0.2 m lever arm, issue #20) does not
    assert [m["sigma"]["tracker_mm"] for m in marks] == [0.005, 0.050]
    assert all(m["sigma"]["tracker_source"] == "dataset" for m in marks)
    tracker = [m["sigma"]["parts_mm"]["tracker"] for m in marks]
    assert tracker[1] == pytest.approx(10 * tracker[0], rel=1e-6) and tracker[1] > 0.05, tracker
    assert marks[0]["sigma"]["parts_mm"]["heading"] == pytest.approx(marks[1]["sigma"]["parts_mm"]["heading"])
    assert marks[1]["std_mm"] > marks[0]["std_mm"] + 0.04, marks


def test_without_a_stated_sigma_the_tracker_sigma_is_the_mpe_at_its_distance(written, calibration, tmp_path):
    """Issue #20: no obs.sigma_t_mm: ½·(15 µm + 6 µm/m·D), D the larger tracker-frame norm of P_prev, P_at; a
    stop whose points carry no tracker-frame x y z falls back to 10 µm; either way the state validates."""
    from calibration.measure import tracker_sigma_mm
    from daemon.compute.recompute import recompute

    folder = tmp_path / "exp"
    write_experiment(folder, calibration, written[1], [1500.0, 200.0, 3.0], reps=1, sigma_t_mm=None)
    state = json.loads((folder / "state.json").read_text())
    assert "sigma_t_mm" not in state["obs"] and validate_folder(folder) == []
    result = recompute(folder)[0]
    for mark, stop in zip(result["marks"], state["obs"]["stops"]):
        d = max(np.linalg.norm([stop[k]["x"], stop[k]["y"], stop[k]["z"]]) for k in ("P_prev", "P_at"))
        sig = mark["sigma"]
        assert sig["tracker_source"] == "distance" and sig["tracker_distance_mm"] == pytest.approx(d)
        assert sig["tracker_mm"] == pytest.approx(tracker_sigma_mm(d))
        assert sig["heading_source"] == "chord" and sig["heading_rad"] == pytest.approx(250e-6)
        assert np.sqrt(sum(v ** 2 for v in sig["parts_mm"].values())) == pytest.approx(mark["std_mm"])
    assert check_file(result, "result", "result.json") == []
    for stop in state["obs"]["stops"]:
        for k in ("P_prev", "P_at"):
            stop[k] = {"abs_xyz": stop[k]["abs_xyz"]}
    (folder / "state.json").write_text(json.dumps(state))
    assert validate_folder(folder) == []
    sig = recompute(folder)[0]["marks"][0]["sigma"]
    assert (sig["tracker_mm"], sig["tracker_source"], sig["tracker_distance_mm"]) == (0.010, "default", None)


def test_recompute_an_experiment_with_another_calibration(written, calibration, tmp_path, capsys):
    write_experiment(tmp_path / "exp", calibration, written[1], [1500.0, 200.0, 3.0], reps=1)
    moved = json.loads(json.dumps(calibration))
    moved["rob_H_scn"][0][3] += 0.5  # the camera 0.5 mm further forward
    (tmp_path / "cal.json").write_text(json.dumps(moved))
    assert ctl.main(["--json", "recompute", str(tmp_path / "exp"), "--calibration", str(tmp_path / "cal.json")]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["recomputed_with"] == ["calibration"]
    for m, psi in zip(res["marks"], (0.0, 180.0)):  # the bias turns with the robot
        want = 1500.0 + 0.5 * np.cos(np.radians(psi))
        assert abs(m["abs_xyz"][0] - want) < 1e-3, (m["abs_xyz"], want)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_captures_store_both_tracker_frames_and_validate(tmp_path, dtype):
    from daemon.bus.storage import save_capture
    from drivers.base import Frame, RobotState, TrackerPoint

    pixels = (np.arange(48 * 64).reshape(48, 64) % 251).astype(dtype)
    parts = {"camera": Frame(pixels, 7, "SN1", "Mono8" if dtype == np.uint8 else "Mono12", 2000.0),
             "tracker": TrackerPoint(1000.0, -20.0, 5.0, (0.003, 0.003, 0.004)),
             "robot": RobotState("IDLE", 1.0, 2.0, 30.0)}
    path = save_capture(tmp_path, parts, "demo", "set1", meta={"abs_H_trk": ABS_H_TRK.tolist()})
    entry = json.loads(path.read_text())
    want = ABS_H_TRK[:3, :3] @ [1000.0, -20.0, 5.0] + ABS_H_TRK[:3, 3]
    assert np.allclose(entry["tracker"]["abs_xyz"], want, atol=1e-9)
    assert entry["tracker"]["abs_H_trk"] == ABS_H_TRK.tolist()
    folder = path.parent
    assert validate_folder(folder) == []
    entry["tracker"]["z"] = 5.5  # the tracker-frame point no longer gives abs_xyz
    path.write_text(json.dumps(entry))
    assert [p.path for p in validate_folder(folder)] == ["$.tracker.abs_xyz"]


def test_the_writer_is_independent_of_the_project():
    code = ("import sys, tests.dataset_writer; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('calibration', 'fakes', 'daemon', 'drivers')))")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60, check=True)
    assert out.stdout.strip() == "[]"
