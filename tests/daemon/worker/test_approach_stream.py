"""The compensations' inputs on the real path: a paper+imu approach move records the tracker
stream and the tilt.

ritad in-process with the fakes of the ``paper+imu`` profile; the worker's Navigator drives
one short recorded straight move (what ``nav.approach`` ends with) through the bus.
"""
from __future__ import annotations

import numpy as np

from daemon.worker.job import JobContext
from daemon.worker.nav import Navigator
from daemon.worker.stream import MIN_TILT_SAMPLES
from fakes.operator import lock_on_robot
from tests.ritad_up import ritad_in_process


def _paper_imu(cfg) -> None:
    cfg.plugins["sim"]["profile"] = "paper+imu"


def test_recorded_approach_holds_stream_and_tilt(tmp_path):
    # the base at a tenth of real time (not the sim's default fiftieth): the move takes 1.5 s of wall time,
    # so a host stalled for tens of ms under load (which the clock map's offset then carries) costs
    # millimetres of the stream's end, not centimetres; 1 kHz of wall time is 100 Hz of robot time
    with ritad_in_process(tmp_path / "rt", tmp_path / "data", configure=_paper_imu,
                          robot="sim:?time_scale=0.1") as (_, c):
        lock_on_robot(c)
        # 10 mm/s: 1.5 s of wall time, many robot.status polls for tilt samples
        params = {"mark_xy": [0.0, 0.0], "imu_readings": 5, "stream_rate_hz": 1000.0, "speed_mm_s": 10.0}
        job = c.call("calib.start", procedure="measure-mark", params=params)["job"]  # no worker takes it
        ctx = JobContext(c, {"job": job, "procedure": "measure-mark", "params": params}, tmp_path / "data")
        nav = Navigator(ctx)
        a, b = nav.straight(150.0, record=True)
        rec = nav.last_record
        assert rec["imu_prev"]["n"] == 5 and abs(rec["imu_prev"]["roll_deg"]) < 1.0, rec["imu_prev"]
        s = rec["stream"]
        P = np.array(s["abs_xyz"])
        assert s["n"] == len(P) >= 10, s["n"]
        # the points run from the start to the end stop, in time order, close to the chord
        u = (b - a) / np.linalg.norm(b - a)
        along = (P - a) @ u
        assert along.min() < 20.0 and along.max() > 130.0, (along.min(), along.max())
        assert np.all(np.diff(along) > -1.0), "stream points are not in time order"
        side = u[0] * (P - a)[:, 1] - u[1] * (P - a)[:, 0]
        assert np.abs(side).max() < 5.0, np.abs(side).max()
        assert len(s["t_sigma_ns"]) == len(P) and min(s["t_sigma_ns"]) > 0, s.get("t_sigma_ns")
        assert s["tilt_samples"] >= MIN_TILT_SAMPLES, s["tilt_samples"]
        T = np.array(s["tilt_deg"])
        assert T.shape == (len(P), 2)
        # anchored at the standstill reading before the move; the floor tilts by well under 0.1° here
        assert np.abs(T[0] - [rec["imu_prev"]["roll_deg"], rec["imu_prev"]["pitch_deg"]]).max() < 0.02, T[0]


def _approach(tmp_path, robot: str) -> tuple[dict, dict]:
    """One recorded straight move of 150 mm at the Navigator's default speed: (stop record, its stream)."""
    with ritad_in_process(tmp_path / "rt", tmp_path / "data", configure=_paper_imu, robot=robot) as (_, c):
        lock_on_robot(c)
        params = {"mark_xy": [0.0, 0.0], "imu_readings": 5, "stream_rate_hz": 1000.0}
        job = c.call("calib.start", procedure="measure-mark", params=params)["job"]  # no worker takes it
        ctx = JobContext(c, {"job": job, "procedure": "measure-mark", "params": params}, tmp_path / "data")
        nav = Navigator(ctx)
        nav.straight(150.0, record=True)
        return nav.last_record, nav.last_record["stream"]


def test_approach_at_default_sim_speed_takes_the_tilt_from_the_inclinometer_stream(tmp_path):
    # the sim's default fiftieth of real time: the move is over in a fraction of a second of wall
    # time, too short for robot.status polls; the base's INCL samples (10 Hz of robot time) cover it
    rec, s = _approach(tmp_path, "sim:")
    assert s["tilt_source"] == "robot.incl", s.get("tilt_source")
    assert s["tilt_samples"] >= 2 * MIN_TILT_SAMPLES, s["tilt_samples"]
    T = np.array(s["tilt_deg"])
    assert T.shape == (s["n"], 2) and s["n"] >= 10, (T.shape, s["n"])
    # the inclinometer's readings: near the standstill reading before the move (the floor tilts by well
    # under 0.1° here), with its noise
    start = [rec["imu_prev"]["roll_deg"], rec["imu_prev"]["pitch_deg"]]
    assert np.abs(T - start).max() < 0.05, (T[[0, -1]], start)
    assert np.ptp(T, axis=0).max() > 0, "the tilt is the same at every point: not sampled along the move"


def test_approach_with_a_version_1_base_polls_the_tilt_as_before(tmp_path):
    _, s = _approach(tmp_path, "sim:?time_scale=0.1&protocol=1")
    assert s.get("tilt_source") in ("robot.status", None), s.get("tilt_source")
    assert s["tilt_source"] == "robot.status" if "tilt_deg" in s else s["tilt_samples"] < MIN_TILT_SAMPLES
