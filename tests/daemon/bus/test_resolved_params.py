"""A job's parameters are resolved once (``Procedure.resolve``): every default applied, frozen, by attribute.

ritad stores the resolved form with the job; the worker reads it (also from a state.json an earlier
version wrote, which holds only the parameters given); the computation resolves the settings the
worker recorded in the observations the same way. No other module applies a default.
"""
from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import pytest

from daemon.bus.procedures import ALL, EXPERIMENT, INTRINSICS, MEASURE_MARK, REFERENCING, ParamError
from daemon.compute.procedures import recorded
from daemon.worker.job import JobContext

ROOT = Path(__file__).resolve().parents[3]


def test_every_default_is_applied_and_the_result_is_frozen():
    r = EXPERIMENT.resolve({"mark_xy": [1, 2], "repetitions": 3})
    assert (r.mark_xy, r.repetitions, r.directions, r.seed) == ((1.0, 2.0), 3, 8, 1)
    assert (r.psi0_deg, r.offset_mm, r.kind, r.distance_mm, r.speed_mm_s) == (0.0, 3.0, "dot", 200.0, 100.0)
    assert (r.imu_readings, r.imu_interval_s) == (10, 0.1)
    assert r.compensation == "tilt,heading_fit,bias,mount" and r.store_bias is False
    # what the run decides stays None: the installed calibration, the tracker's rate, the computation's σ
    assert (r.calibration, r.stream_rate_hz, r.sigma_t_mm) == (None, None, None)
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.seed = 2  # type: ignore[misc]
    with pytest.raises(AttributeError, match="experiment: no parameter 'seeds'"):
        r.seeds  # noqa: B018 - a misspelt name fails loudly, it never reads as a default
    assert [f.name for f in dataclasses.fields(r)] == [p.name for p in EXPERIMENT.params]  # type: ignore


def test_a_default_may_follow_an_earlier_parameter():
    """The mark's size follows its kind; the recorded approach's speed follows the drive speed."""
    assert MEASURE_MARK.resolve({"mark_xy": [0, 0]}).mark_size_mm == 0.4
    assert MEASURE_MARK.resolve({"mark_xy": [0, 0], "kind": "cross"}).mark_size_mm == 0.6
    assert MEASURE_MARK.resolve({"mark_xy": [0, 0], "kind": "cross", "mark_size_mm": 1.5}).mark_size_mm == 1.5
    assert MEASURE_MARK.resolve({"mark_xy": [0, 0], "speed_mm_s": 40}).approach_speed_mm_s == 40.0
    assert MEASURE_MARK.resolve({"mark_xy": [0, 0], "speed_mm_s": 40,
                                 "approach_speed_mm_s": 5}).approach_speed_mm_s == 5.0


@pytest.mark.parametrize("proc", ALL, ids=lambda p: p.name)
def test_a_resolved_record_resolves_to_itself_and_an_old_one_to_the_same(proc):
    """The stored form (``to_dict``, JSON) read back is the same; a record of an earlier version (only the
    parameters given) resolves to what a new one holds."""
    given = {"mark_xy": [3, 4]} if any(p.required for p in proc.params) else {}
    new = proc.resolve(given)
    stored = json.loads(json.dumps(new.to_dict()))
    assert proc.resolve(stored) == new and set(stored) == {p.name for p in proc.params}


def test_resolve_refuses_what_calib_start_refuses():
    with pytest.raises(ParamError, match="'mark_xy' is required"):
        MEASURE_MARK.resolve({})
    with pytest.raises(ParamError, match="'directions'"):
        EXPERIMENT.resolve({"mark_xy": [0, 0], "directions": 0})
    assert EXPERIMENT.resolve({}, required=False).mark_xy is None


def test_the_worker_resumes_a_state_json_an_earlier_version_wrote(tmp_path):
    """state.json's ``params`` held only the parameters given: the worker resolves them the same way."""
    root = tmp_path / "procedures" / "old-job"
    root.mkdir(parents=True)
    (root / "state.json").write_text(json.dumps({
        "schema": 1, "job": "old-job", "procedure": REFERENCING.name, "params": {"distance_mm": 150.0},
        "status": "running", "done": [], "obs": {}}))
    ctx = JobContext(None, {"job": "old-job", "procedure": REFERENCING.name}, tmp_path)  # type: ignore
    assert ctx.resumed and ctx.params == REFERENCING.resolve({"distance_mm": 150.0})
    assert ctx.params.reversal is True and ctx.params.speed_mm_s == 100.0


def test_a_missing_installed_file_names_it_and_the_option(tmp_path):
    ctx = JobContext(None, {"job": "j", "procedure": INTRINSICS.name, "params": {}}, tmp_path)  # type: ignore
    with pytest.raises(ValueError, match=r"calibration/board.json does not exist: pass it with ritactl "
                                         r"intrinsics --board FILE or install it there"):
        ctx.definition("board")
    (tmp_path / "calibration").mkdir()
    (tmp_path / "calibration" / "board.json").write_text('{"board_id": "B"}')
    assert ctx.definition("board") == {"board_id": "B"}


def test_the_computation_resolves_the_recorded_settings_like_the_job():
    """An older worker's obs without a kind, compensation or size: the declared defaults, as the job's."""
    s = recorded(MEASURE_MARK, {"calibration": {}, "stop": {}})
    assert (s.kind, s.mark_size_mm, s.sigma_t_mm) == ("dot", 0.4, None)
    assert s.compensation == "tilt,heading_fit,bias,mount"
    obs = {"kind": "cross", "mark_size_mm": None, "compensation": "none", "sigma_t_mm": 0.02, "stops": []}
    s = recorded(EXPERIMENT, obs)
    assert (s.kind, s.mark_size_mm, s.compensation, s.sigma_t_mm) == ("cross", 0.6, "none", 0.02)


def test_no_other_module_applies_a_parameter_default():
    """The worker and the computation read resolved attributes: no ``params.get(…)`` with a fallback, no
    defaults table of their own."""
    found = []
    for pkg in ("worker", "compute"):
        for path in sorted((ROOT / "daemon" / pkg).glob("*.py")):
            for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                if re.search(r"params\.get\(|params\[|\bDEFAULTS\b|PARAM_DEFAULTS", line):
                    found.append(f"{path.relative_to(ROOT)}:{i}: {line.strip()}")
    assert found == []
