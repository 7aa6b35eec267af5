"""ritad checks ``calib.start``'s params against the procedures' parameter table before it creates
a job: every bad value drawn from the table is ``bad_args`` naming the parameter, and no job
appears in ``calib.jobs``. The table's checks and the command table's are one code path."""
from __future__ import annotations

import math
from typing import Any, Iterator

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from daemon.bus.command_table import Arg, BadValue
from daemon.bus.procedure_params import Param
from daemon.bus.procedures import MEASURE_MARK, PARAMS, check_params
from daemon.bus.protocol import CommandError
from tests.fuzzscale import cases
from tests.ritad_up import ritad_in_process

#: a valid base per procedure: the required parameters only
BASE: dict[str, dict[str, Any]] = {p: {q.name: [1.0, 2.0] for q in ps if q.required} for p, ps in PARAMS.items()}


def bad_values(p: Param) -> Iterator[Any]:
    """Values the table says are wrong for ``p``: outside its range, wrong type, not a choice."""
    if p.type in ("int", "float"):
        if p.lo is not None:
            yield p.lo if p.lo_open else p.lo - 1
        if p.hi is not None:
            yield p.hi + 1
        yield "1"
        if p.type == "int":
            yield 1.5
        else:
            yield math.inf
    elif p.type == "bool":
        yield "yes"
    elif p.type == "str":
        yield 3
        if p.choices:
            yield "nope"
    elif p.type == "vec":
        yield [1.0] * (p.length + 1)
        yield [math.nan] * p.length
    elif p.type == "file":
        yield 5
        yield "calibration/plate.json"  # a path is the console's form; on the bus the file's object
        if p.content == "xyz_map":
            yield {"red": [1, 2]}


def table_cases() -> list[tuple[str, str, Any]]:
    out = [(proc, p.name, v) for proc, params in PARAMS.items() for p in params for v in bad_values(p)]
    return out + [(proc, "bogus", 1) for proc in PARAMS] + [(proc, "repetitons", 5) for proc in PARAMS]


CASES = table_cases()


@pytest.fixture(scope="module")
def bus(tmp_path_factory):
    with ritad_in_process(tmp_path_factory.mktemp("rt"), ready=False) as (_, c):
        yield c


def refused(c: Any, procedure: str, params: dict[str, Any]) -> str:
    with pytest.raises(CommandError) as exc:
        c.call("calib.start", procedure=procedure, params=params)
    assert exc.value.code == "bad_args", exc.value
    return str(exc.value)


def test_the_table_gives_at_least_twenty_bad_requests():
    assert len(CASES) >= 20 and len({(proc, name) for proc, name, _ in CASES}) >= 20


def test_daemon_refuses_every_bad_parameter_from_the_table_and_creates_no_job(bus):
    before = bus.call("calib.jobs")["jobs"]
    for proc, name, value in CASES:
        message = refused(bus, proc, {**BASE[proc], name: value})
        assert repr(name) in message, (proc, name, value, message)
    assert bus.call("calib.jobs")["jobs"] == before


def test_directions_eight_and_bogus_are_both_named(bus):
    message = refused(bus, "experiment", {"mark_xy": [1, 2], "directions": "eight", "bogus": 1})
    assert "'directions'" in message and "'eight'" in message and "'bogus'" in message, message
    with pytest.raises(CommandError) as exc:
        check_params("experiment", {"mark_xy": [1, 2], "directions": "eight", "bogus": 1})
    assert exc.value.field == "directions" and set(exc.value.fields) == {"directions", "bogus"}


def test_missing_required_parameter_is_refused_but_a_resume_needs_none(bus):
    assert "'mark_xy'" in refused(bus, "measure-mark", {})
    job = bus.call("calib.start", procedure="measure-mark", params={"mark_xy": [1, 2.5], "imu_readings": 3})["job"]
    posted = {j["job"]: j for j in bus.call("calib.jobs")["jobs"]}[job]
    # checked, normalised and resolved: every default applied, one following another parameter's value too
    assert {k: posted["params"][k] for k in ("mark_xy", "imu_readings", "mark_size_mm", "approach_speed_mm_s",
                                              "heading_deg")} == {"mark_xy": [1.0, 2.5], "imu_readings": 3,
                                                                  "mark_size_mm": 0.4, "approach_speed_mm_s": 100.0,
                                                                  "heading_deg": None}
    assert posted["params"] == MEASURE_MARK.resolve({"mark_xy": [1, 2.5], "imu_readings": 3}).to_dict()
    bus.call("calib.cancel", job=job)
    bus.call("calib.report", job=job, kind="error", data={"message": "cancelled", "cancelled": True})
    assert bus.call("calib.start", procedure="measure-mark", job=job, params={})["job"] == job  # resumes
    assert "'imu_readings'" in refused(bus, "measure-mark", {"imu_readings": 0})


@settings(max_examples=cases(400, 60), derandomize=True, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(data=st.data())
def test_fuzz_from_the_table_agrees_with_the_table(bus, data):
    """Random values for a random parameter: ritad accepts exactly what the table's check accepts."""
    proc = data.draw(st.sampled_from(sorted(PARAMS)))
    p = data.draw(st.sampled_from(PARAMS[proc]))
    value = data.draw(st.one_of(st.sampled_from(list(bad_values(p)) or [None]), st.integers(-2000, 2000),
                                st.floats(allow_nan=True, allow_infinity=True), st.booleans(),
                                st.text(max_size=5), st.lists(st.floats(-1e3, 1e3), max_size=4)))
    params = {**BASE[proc], p.name: value}
    try:
        absent = value is None or (p.type == "file" and value == "")  # the worker's default
        ok = not (absent and p.required)
        if not absent:
            p.checked(value, paths=False)
    except BadValue:
        ok = False
    if ok:
        bus.call("calib.start", procedure=proc, params=params)
    else:
        assert repr(p.name) in refused(bus, proc, params)


def test_one_checking_path_for_arguments_and_parameters():
    arg = Arg("n", "int", "a count", lo=1)
    param = Param("n", "int", "a count", lo=1)
    for value in (0, 1.5, "x", True, 7):
        outcomes = []
        for a in (arg, param):
            try:
                outcomes.append(("ok", a.checked(value, "x")))
            except BadValue as exc:
                outcomes.append(("bad", str(exc)))
        assert outcomes[0] == outcomes[1], outcomes
