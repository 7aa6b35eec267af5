"""End to end on the simulated world: ritad + calibration worker + bus, as an operator drives it.

One daemon (reduced image size) serves the whole module. The loop is closed as on a real
Rita: the camera model comes from the guided intrinsics (the simulated operator holds
the board), the plate from the survey of rendered photographs; the referencing and
the 8-direction experiment consume them. ``sim.truth`` only scores results (and is the
simulated operator's eye in fakes/operator.py: where to point the tracker, the marks'
rough positions). Also: offline recompute to 1e-9, a worker killed mid-procedure that
resumes without re-measuring, prompts, cancel and resume.
"""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from calibration.referencing import rob_H_cam_error
from daemon.compute.recompute import recompute
from daemon.bus.client import Client, ClientTimeout
from daemon.bus.datasets import validate_folder
from fakes.demo import operator_files
from daemon.compute.survey import survey_plate
from fakes.board import run_intrinsics
from fakes.operator import lock_on_robot, rough_mark
from fakes.score import score_camera_model, score_experiment, score_nests
from fakes.launch import start_ritad
from tools.harness.load import hang_s

ROOT = Path(__file__).resolve().parents[2]
#: the closed loops' bound: the longest test (paper+imu, ~100 s alone on the 2-core machine; the module's
#: set-up adds ~30 s to the first test) with room, times the load factor (tools/harness/load.py: 450 s at
#: the default 3, where pytest's 300 s was one 3× slowdown from failing)
QUIET_S = 150.0
pytestmark = [pytest.mark.slow, pytest.mark.timeout(hang_s(QUIET_S))]


@pytest.fixture(scope="module")
def daemon(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("e2e")
    with start_ritad(tmp=tmp, args=["--seed", "3"], timeout=90) as r:
        try:
            r.wait_ready(timeout=90, worker=True)
        except ClientTimeout as exc:
            raise AssertionError(f"daemon not ready: {exc}\n{r.log_tail()}") from None
        with r.client() as c:
            produce_operator_inputs(c, tmp)
            yield c, tmp


def produce_operator_inputs(c: Client, tmp: Path) -> None:
    """The camera model (installed by the guided intrinsics) and the surveyed plate (tmp/plate.json)."""
    board = json.loads(operator_files(c, tmp)["board"].read_text())
    intr = run_intrinsics(c, {"board": board}, seed=3, timeout=300)
    assert intr.get("verdict") == "ok", intr
    c.call("sim.survey_images", views=8, width_px=1800, timeout=300)
    files = operator_files(c, tmp)
    plate = survey_plate(files["survey"], json.loads(files["plate_design"].read_text()))
    (tmp / "plate.json").write_text(json.dumps(plate))
    truth = c.call("sim.truth")  # scoring only
    installed = json.loads((Path(c.call("data.dir")["data_dir"]) / "calibration" / "camera_model.json").read_text())
    model_err = score_camera_model(installed, truth)
    assert model_err["df_rel"] <= 0.001 and model_err["pp_full_px"] <= 1.5, model_err
    assert max(score_nests(plate, truth).values()) <= 0.060, score_nests(plate, truth)  # 1800 px photos: see docs


def run_job(c: Client, procedure: str, params: dict, timeout: float = hang_s(QUIET_S),
            answers: dict | None = None,
            job: str | None = None) -> dict:
    """Post a job (or resume ``job``) and wait for its result message (subscribe first: Clone pattern).

    ``answers`` maps a word of a prompt's question to the answer the 'operator' gives;
    the prompts seen are returned under ``_prompts``."""
    sub = c.subscriber(["calib.result", "calib.prompt"])
    time.sleep(0.2)
    if job is None:
        job = c.call("calib.start", procedure=procedure, params=params)["job"]
    else:
        c.call("calib.resume", job=job)
    prompts = []
    try:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            msg = sub.recv(1.0)
            if not msg or msg[1]["data"].get("job") != job:
                continue
            data = msg[1]["data"]
            if msg[0] == "calib.prompt":
                prompts.append(data)
                word = next((w for w in answers or {} if w in data["question"]), None)
                assert word is not None, f"unexpected prompt: {data}"
                c.call("calib.answer", job=job, answer=answers[word])
                continue
            return {**data, "job": job, "_prompts": prompts}
        raise AssertionError(f"{procedure} did not finish in {timeout} s: {c.call('calib.jobs')}")
    finally:
        sub.close()


def run_ok(c: Client, procedure: str, params: dict, **kw) -> dict:
    data = run_job(c, procedure, params, **kw)
    assert not data.get("failed"), data
    return data


def referencing_params(c: Client, tmp: Path) -> dict:
    """The surveyed plate and rough positions; the camera model is the one the intrinsics installed."""
    files = operator_files(c, tmp)
    p = lock_on_robot(c)
    surveyed = tmp / "plate.json"  # else the plate's design file: what an operator has before a survey
    return {"plate": json.loads((surveyed if surveyed.exists() else files["plate_design"]).read_text()),
            "nests_approx_trk": json.loads(files["nests"].read_text()),
            "robot_approx_trk": [p["x"], p["y"], p["z"]]}


def ensure_calibrated(c: Client, tmp: Path) -> None:
    """Tests that need an active calibration make one when run on their own."""
    if c.call("calib.results")["active"] is None:
        c.call("sim.place_robot_on_plate")
        run_ok(c, "referencing", referencing_params(c, tmp))


def test_referencing_then_experiment_meet_the_nominal_thresholds(daemon):
    c, tmp = daemon
    truth = c.call("sim.truth")
    ref = run_ok(c, "referencing", referencing_params(c, tmp))
    assert ref["verdict"] in ("ok", "warn")
    err = rob_H_cam_error(np.array(ref["rob_H_cam"]), np.array(truth["rob_H_cam"]))
    print(f"\nclosed loop rob_H_cam vs truth: {err}")
    assert err["t_xy_mm"] < 0.06 and err["t_z_mm"] < 0.045, err
    # the acceptance threshold: rotation < 0.015° (measured 0.0047° here; the demo's seed 1 still misses it, 0.016°:
    # docs/accuracy.md, "The closed loop without ground truth")
    assert err["rot_deg"] < 0.015, err
    active = c.call("calib.results")["active"]
    assert active["job"] == ref["job"] and Path(active["dataset"], "result.yaml").exists()

    mark = truth["marks"][0]
    exp = run_ok(c, "experiment", {"mark_xy": rough_mark(c, 0)[1], "repetitions": 5})
    stored = json.loads(Path(exp["dataset"], "result.json").read_text())
    m = stored["metrics"]
    assert len(stored["marks"]) == 40 and len(m["clusters"]) == 8
    assert m["enclosing_diameter_mm"] < 0.22, m["enclosing_diameter_mm"]
    assert m["pairwise_mean_mm"] < 0.09, m["pairwise_mean_mm"]
    grand = np.mean([p["abs_xyz"][:2] for p in stored["marks"]], axis=0)
    assert np.hypot(*(grand - [mark["x_mm"], mark["y_mm"]])) < 0.07
    for name in ("report.md", "report.csv", "report_metrics.csv", "report_stops.csv", "clusters.png"):
        assert Path(exp["dataset"], name).stat().st_size > 100
    report = Path(exp["dataset"], "report.md").read_text()  # the live report: header, goals, shifts given
    assert f"- **job**: {exp['job']}" in report and "NOT in report_stops.csv" not in report
    assert sum(ln.endswith((": met", ": **MISSED**")) for ln in report.splitlines()) == 2

    # offline recompute from the stored datasets reproduces the stored results
    for dataset in (ref["dataset"], exp["dataset"]):
        assert validate_folder(dataset) == [], dataset  # the live worker writes what docs/datasets.md says
        result, diff = recompute(Path(dataset))
        assert diff is not None and diff < 1e-9, (dataset, diff)
    out = subprocess.run([sys.executable, "-m", "daemon.ctl.main", "recompute", ref["dataset"]], cwd=ROOT,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and "largest difference to the stored result" in out.stdout
    stop = json.loads(Path(exp["dataset"], "state.json").read_text())["obs"]["stops"][0]
    assert {"x", "y", "z", "abs_xyz", "abs_H_trk"} <= stop["P_at"].keys()  # both frames stored


def test_killed_worker_resumes_without_remeasuring(daemon):
    c, tmp = daemon
    ensure_calibrated(c, tmp)
    truth = c.call("sim.truth")
    mark = truth["marks"][1]
    sub = c.subscriber(["calib."])
    time.sleep(0.2)
    job = c.call("calib.start", procedure="experiment",
                 params={"mark_xy": rough_mark(c, 1)[1], "kind": mark["kind"], "directions": 4,
                         "repetitions": 1})["job"]
    root = Path(c.call("data.dir")["data_dir"]) / "procedures" / job
    end = time.monotonic() + 200
    while time.monotonic() < end:  # wait until two stops are stored
        st = json.loads((root / "state.json").read_text()) if (root / "state.json").exists() else {"done": []}
        if len(st["done"]) >= 2:
            break
        time.sleep(0.1)
    pid = c.call("status")["worker"]["pid"]
    os.kill(pid, signal.SIGKILL)
    killed_at = time.time()
    done_before = list(json.loads((root / "state.json").read_text())["done"])
    mtimes = {s: (root / f"{s}.png").stat().st_mtime for s in done_before}
    result = None
    end = time.monotonic() + 300
    while time.monotonic() < end and result is None:
        msg = sub.recv(1.0)
        if msg and msg[0] == "calib.result" and msg[1]["data"].get("job") == job:
            result = msg[1]["data"]
    sub.close()
    assert result is not None and not result.get("failed"), result
    assert c.call("status")["worker"]["pid"] != pid  # the daemon restarted the worker
    state = json.loads((root / "state.json").read_text())
    assert state["status"] == "done" and len(state["obs"]["stops"]) == 4
    for s in done_before:  # completed stops were not captured again
        assert (root / f"{s}.png").stat().st_mtime == mtimes[s] < killed_at
    names = [e["name"] for e in json.loads((root / "dataset.json").read_text())["entries"]]
    assert len(names) == len(set(names)) == 4


def test_measure_mark(daemon):  # the intrinsics: tests/system/test_intrinsics_e2e.py
    c, tmp = daemon
    truth = c.call("sim.truth")
    ensure_calibrated(c, tmp)
    mark = truth["marks"][1]  # the cross
    r = run_ok(c, "measure-mark", {"mark_xy": rough_mark(c, 1)[1], "kind": mark["kind"]})
    x, y, _ = r["mark"]["abs_xyz"]
    assert np.hypot(x - mark["x_mm"], y - mark["y_mm"]) < 0.1
    # the stop's own σ; the calibration's last experiment may scale it (its Birge ratio, which a loaded
    # machine's simulated stream timing can raise): then the σ is the product and a message says so
    sigma = r["mark"]["sigma"]
    assert 0 < sigma["stated_mm"] < 0.1, sigma
    assert sigma["scale"] >= 1.0 and r["mark"]["std_mm"] == pytest.approx(sigma["stated_mm"] * sigma["scale"])
    assert (sigma["scale"] > 1.0) == any("σ scaled by" in m for m in r["messages"]), r["messages"]
    assert validate_folder(r["dataset"]) == []


def test_prompt_when_the_tracker_cannot_find_a_nest(daemon):
    """A nest far from its approximate position: the worker asks; the 'operator' locks on and answers."""
    c, tmp = daemon
    c.call("sim.place_robot_on_plate")
    params = referencing_params(c, tmp)
    good = params["nests_approx_trk"]["green"]
    params["nests_approx_trk"]["green"] = [good[0] + 400.0, good[1] - 300.0, good[2]]
    sub = c.subscriber(["calib."])
    time.sleep(0.2)
    job = c.call("calib.start", procedure="referencing", params=params)["job"]
    answered = False
    result = None
    end = time.monotonic() + 300
    try:
        while time.monotonic() < end and result is None:
            msg = sub.recv(1.0)
            if not msg or msg[1]["data"].get("job") != job:
                continue
            if msg[0] == "calib.prompt":
                assert "green" in msg[1]["data"]["question"]
                c.call("tracker.aim", timeout=60, x=good[0], y=good[1], z=good[2])  # the operator helps
                c.call("tracker.find", timeout=60)
                c.call("calib.answer", job=job, answer="ok")
                answered = True
            elif msg[0] == "calib.result":
                result = msg[1]["data"]
    finally:
        sub.close()
    assert answered and result is not None and not result.get("failed"), result
    truth = c.call("sim.truth")
    err = rob_H_cam_error(np.array(result["rob_H_cam"]), np.array(truth["rob_H_cam"]))
    assert err["t_xy_mm"] < 0.06 and err["rot_deg"] < 0.015, err  # the acceptance thresholds


def test_cancel_then_resume(daemon):
    """ritactl cancel stops a job between steps; posting the same job id resumes it."""
    c, tmp = daemon
    ensure_calibrated(c, tmp)
    sub = c.subscriber(["calib.result"])
    time.sleep(0.2)
    params = {"mark_xy": rough_mark(c, 0)[1], "directions": 3, "repetitions": 1}
    job = c.call("calib.start", procedure="experiment", params=params)["job"]
    root = Path(c.call("data.dir")["data_dir"]) / "procedures" / job
    end = time.monotonic() + 120
    while time.monotonic() < end:
        if (root / "state.json").exists() and json.loads((root / "state.json").read_text())["done"]:
            break
        time.sleep(0.05)
    c.call("calib.cancel", job=job)
    results = []
    try:
        end = time.monotonic() + 120
        while time.monotonic() < end and len(results) < 2:
            msg = sub.recv(1.0)
            if msg and msg[1]["data"].get("job") == job:
                results.append(msg[1]["data"])
                if len(results) == 1:
                    assert results[0].get("failed") and results[0].get("cancelled"), results[0]
                    state = json.loads((root / "state.json").read_text())
                    assert state["status"] == "cancelled" and len(state["obs"]["stops"]) < 3
                    c.call("calib.start", procedure="experiment", job=job, params=params)
    finally:
        sub.close()
    assert len(results) == 2 and not results[1].get("failed"), results
    state = json.loads((root / "state.json").read_text())
    assert state["status"] == "done" and len(state["obs"]["stops"]) == 3
    names = [e["name"] for e in json.loads((root / "dataset.json").read_text())["entries"]]
    assert len(names) == len(set(names)) == 3


def test_paper_imu_experiment_with_compensations_beats_the_paper(daemon, tmp_path):
    """The compensations through ritad and the worker: the module's camera model and surveyed plate on a
    realistic floor (``--profile paper+imu``, same seed: same camera, plate and robot). Referencing
    with reversal calibrates the inclinometer's offset; a short learning experiment on mark M2
    stores the robot-frame bias; the 8 × 5 experiment on M1 then runs with the compensations.
    Per-seed bounds of the issue: enclosing ≤ 0.25, pairwise ≤ 0.07, absolute RMS ≤ 0.10 mm
    (the rendering-free budget's p95 over 10 seeds: 0.227 / 0.039 / 0.063, docs/accuracy.md)."""
    c0, tmp = daemon
    model = json.loads((Path(c0.call("data.dir")["data_dir"]) / "calibration" / "camera_model.json").read_text())
    with start_ritad(tmp=tmp_path, args=["--seed", "3", "--profile", "paper+imu"], timeout=90) as r:
        r.wait_ready(timeout=90, worker=True)
        with r.client() as c:
            # the simulated base runs 50× faster than real time: its inclinometer's 0.1 s is 2 ms here
            imu = {"imu_interval_s": 0.002}
            params = {**referencing_params(c, tmp), "camera_model": model, "reversal": True, **imu}
            ref = run_ok(c, "referencing", params)
            assert ref["verdict"] in ("ok", "warn"), ref
            assert len(c.call("calib.results")["active"]["imu_offset_deg"]) == 2  # calibrated on the plate
            truth = c.call("sim.truth")  # scoring only
            # the product's own path to the mount's offset (compute_referencing) against the world's
            m = c.call("calib.results")["active"]["reflector_mount"]
            e = np.subtract(m["los_mm"], truth["errors"]["mount_offset_mm"][:2])
            assert float(e @ np.linalg.solve(np.array(m["cov_los_mm2"]), e)) < 3.5 ** 2, (m, truth["errors"])
            run_ok(c, "experiment", {"mark_xy": rough_mark(c, 1)[1], "kind": truth["marks"][1]["kind"],
                                     "repetitions": 1, "store_bias": True, **imu})
            assert "robot_bias_mm" in c.call("calib.results")["active"]
            exp = run_ok(c, "experiment", {"mark_xy": rough_mark(c, 0)[1], "repetitions": 5, **imu})
    stored = json.loads(Path(exp["dataset"], "result.json").read_text())
    applied = stored["compensation"]["applied"]
    # heading_fit needs the inclinometer along the stream, which the 50×-fast simulated move does not
    # give through ritad (docs/operations.md): it is skipped with that reason, or applied
    assert applied["tilt"] == 40 and applied["bias"] == 40, stored["compensation"]
    on = score_experiment(stored, truth["marks"][0])
    off = score_experiment(recompute(Path(exp["dataset"]), compensation="none")[0], truth["marks"][0])
    print(f"\npaper+imu through ritad, without / with compensations: {off} / {on}")
    assert on["enclosing"] <= 0.25 and on["pairwise"] <= 0.07 and on["abs_rms"] <= 0.10, on
    assert on["abs_rms"] < off["abs_rms"] / 3, (on, off)  # the floor's tilt was the absolute error
