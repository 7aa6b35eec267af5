"""The console server without a browser: procedure parameters checked again and files read on the robot,
and the plate survey's start and errors."""
from __future__ import annotations

import asyncio
import contextlib
import json
import time
from pathlib import Path
from typing import Any, AsyncIterator

import pytest

pytest.importorskip("aiohttp")

from daemon.bus.client import Client  # noqa: E402
from daemon.bus.procedures import EXPERIMENT, PARAMS, REFERENCING, check_params  # noqa: E402
from daemon.bus.protocol import CommandError  # noqa: E402
from tests.ritad_up import ritad_in_process  # noqa: E402


@contextlib.asynccontextmanager
async def console_ws(endpoint: str, tmp: Path) -> AsyncIterator[Any]:
    """The console's web app on 127.0.0.1:0 in this loop, and one WebSocket to it (after its hello)."""
    import aiohttp
    from aiohttp import web

    from daemon.console.bridge import Bridge
    from daemon.console.server import Console

    bridge = Bridge(lambda: Client(endpoint, timeout=10))
    await asyncio.get_running_loop().run_in_executor(None, bridge.start)
    console = Console(bridge, tmp)
    runner = web.AppRunner(console.app(), access_log=None)
    await runner.setup()
    site = web.TCPSite(runner, "127.0.0.1", 0)
    await site.start()
    url = f"http://127.0.0.1:{runner.addresses[0][1]}/ws?token={console.token}"
    try:
        async with aiohttp.ClientSession() as http, http.ws_connect(url) as ws:
            hello = await ws.receive_json(timeout=10)
            assert hello["type"] == "hello"
            ws.hello = hello
            yield ws
    finally:
        console.survey.close()
        await runner.cleanup()
        bridge.stop()


async def ask(ws: Any, msg: dict[str, Any], timeout: float = 30.0) -> dict[str, Any]:
    """Send ``msg`` with a fresh id; its reply (state messages in between are skipped)."""
    ask.n = getattr(ask, "n", 0) + 1
    await ws.send_json({**msg, "id": ask.n})
    end = time.monotonic() + timeout
    while True:
        m = await ws.receive_json(timeout=max(0.1, end - time.monotonic()))
        if m.get("type") == "reply" and m.get("id") == ask.n:
            return m


async def survey_state(ws: Any, want: tuple[str, ...], timeout: float = 30.0) -> dict[str, Any]:
    end = time.monotonic() + timeout
    while True:
        m = await ws.receive_json(timeout=max(0.1, end - time.monotonic()))
        if m.get("type") == "state" and (m.get("survey") or {}).get("state") in want:
            return m["survey"]


def test_parameter_table_keeps_the_worker_defaults():
    """The defaults the worker used before the table existed, unchanged (same values and types)."""
    old = {"distance_mm": 200.0, "speed_mm_s": 100.0, "directions": 8, "repetitions": 5,
           "offset_mm": 3.0, "seed": 1, "kind": "dot"}
    resolved = EXPERIMENT.resolve({"mark_xy": [0, 0]})
    got = {k: getattr(resolved, k) for k in old}
    assert {k: (v, type(v)) for k, v in got.items()} == {k: (v, type(v)) for k, v in old.items()}
    # issue #20: sigma_t_mm (0.010 before) has no worker default; the computation states it (the referencing
    # still 0.010, calibration.measure.DEFAULT_SIGMA_T_MM; marks the tracker's MPE at its distance)
    from calibration.measure import DEFAULT_SIGMA_T_MM

    assert resolved.sigma_t_mm is None and DEFAULT_SIGMA_T_MM == 0.010


@pytest.mark.parametrize("proc, params, field, words", [
    ("experiment", {"mark_xy": [1, 2], "directions": 0}, "directions", "0 is not ≥ 1"),
    ("experiment", {"mark_xy": [1, 2], "seed": 1.5}, "seed", "integer"),
    ("experiment", {"mark_xy": [1]}, "mark_xy", "2 numbers"),
    ("experiment", {}, "mark_xy", "required"),
    ("measure-mark", {"mark_xy": [1, 2], "kind": "star"}, "kind", "'star'"),
    ("measure-mark", {"mark_xy": [1, float("nan")]}, "mark_xy", "finite"),
    ("referencing", {"reversal": "yes"}, "reversal", "true or false"),
    ("referencing", {"distance_mm": -5}, "distance_mm", "-5"),
    ("referencing", {"nests_approx_trk": {"red": [1, 2]}}, "nests_approx_trk", "'red'"),
    ("referencing", {"bogus": 1}, "", "unknown parameter 'bogus'"),
])
def test_bad_parameters_are_refused_naming_the_field(proc, params, field, words):
    with pytest.raises(CommandError) as exc:
        check_params(proc, params)
    assert exc.value.code == "bad_args" and exc.value.field == field and words in str(exc.value)


def test_every_procedure_has_a_form_and_the_page_gets_it():
    from daemon.bus.procedures import schema

    s = schema()
    assert set(s) == set(PARAMS) and all(s[p] for p in s)
    kinds = {f["kind"] for fields in s.values() for f in fields}
    assert kinds == {"float", "int", "bool", "str", "vec", "file"}


def test_console_checks_the_page_and_reads_the_chosen_files_on_the_robot(tmp_path):
    async def run(endpoint: str) -> dict[str, Any]:
        async with console_ws(endpoint, tmp_path / "captures") as ws:
            assert set(ws.hello["procedure_params"]) == set(PARAMS)
            start = {"op": "call", "cmd": "calib.start"}
            bad = await ask(ws, {**start, "args": {"procedure": "experiment", "params": {"mark_xy": [1, 2],
                                                                                          "repetitions": 0}}})
            missing = await ask(ws, {**start, "args": {"procedure": "referencing", "params": {
                "plate": "sim/nope.json"}}})
            good = await ask(ws, {**start, "args": {"procedure": "referencing", "params": {
                "plate": "sim/plate.json", "nests_approx_trk": "sim/nests.json", "reversal": True}}})
            return {"bad": bad, "missing": missing, "good": good}

    with ritad_in_process(tmp_path / "rt") as (d, c):
        r = asyncio.run(run(d.server.endpoints[0]))
        jobs = c.call("calib.jobs")["jobs"]
        data = Path(c.call("data.dir")["data_dir"])
    assert not r["bad"]["ok"] and r["bad"]["error"]["field"] == "repetitions"
    assert "repetitions" in r["bad"]["error"]["message"] and "0" in r["bad"]["error"]["message"]
    assert not r["missing"]["ok"] and r["missing"]["error"]["field"] == "plate"
    assert "sim/nope.json" in r["missing"]["error"]["message"]
    assert r["good"]["ok"], r["good"]
    assert len(jobs) == 1 and jobs[0]["job"] == r["good"]["result"]["job"]  # the refused ones posted nothing
    params = jobs[0]["params"]
    # the file's object, as ritactl
    assert params["plate"] == json.loads((data / "sim" / "plate.json").read_text())
    assert params["nests_approx_trk"] == json.loads((data / "sim" / "nests.json").read_text())
    # ritad stores them resolved: every parameter, the defaults applied (the installed camera model: None)
    assert params["reversal"] is True and set(params) == {p.name for p in REFERENCING.params}
    assert params["distance_mm"] == 200.0 and params["camera_model"] is None


def test_survey_from_the_console_reports_a_bad_folder_and_empty_fields_and_cancels(tmp_path, monkeypatch):
    import sys

    design = tmp_path / "rt" / "data" / "sim" / "plate.json"  # the simulated installer's design file

    async def cancel(ws: Any) -> tuple[dict, dict, dict]:
        """A survey that takes long (a stand-in child that prints one progress line and sleeps) cancelled."""
        slow = ("import sys, time; print('[ 12.5%] read a.png (1/8)', file=sys.stderr, flush=True); "
                "time.sleep(60)")
        monkeypatch.setattr("daemon.console.survey.SURVEY_ARGV", (sys.executable, "-c", slow))
        args = {"op": "survey", "action": "start", "folder": str(tmp_path), "plate": str(design),
                "out": str(tmp_path / "plate.json")}
        assert (await ask(ws, args))["ok"]
        running = await survey_state(ws, ("running",), 10)
        while running.get("percent") != 12.5:
            running = await survey_state(ws, ("running",), 10)
        second = await ask(ws, args)
        assert (await ask(ws, {"op": "survey", "action": "cancel"}))["ok"]
        return running, second, await survey_state(ws, ("cancelled", "failed", "done"), 10)

    async def run(endpoint: str) -> tuple[dict, dict, tuple]:
        async with console_ws(endpoint, tmp_path / "captures") as ws:
            empty = await ask(ws, {"op": "survey", "action": "start", "folder": " ", "plate": str(design),
                                   "out": "x.json"})
            started = await ask(ws, {"op": "survey", "action": "start", "folder": str(tmp_path / "no-photos"),
                                     "plate": str(design), "out": str(tmp_path / "plate.json")})
            assert started["ok"], started
            return empty, await survey_state(ws, ("failed", "done"), 60), await cancel(ws)

    with ritad_in_process(tmp_path / "rt") as (d, _):
        empty, end, (running, second, cancelled) = asyncio.run(run(d.server.endpoints[0]))
    assert not empty["ok"] and "photo folder is empty" in empty["error"]["message"]
    assert end["state"] == "failed" and end["exit"] == 5, end  # ritactl plate survey's bad-input exit code
    assert f"{tmp_path / 'no-photos'}: not a folder of photographs" in end["message"], end
    assert not (tmp_path / "plate.json").exists()
    assert running["step"] == "read a.png (1/8)"  # the verb's progress line, shown
    assert not second["ok"] and second["error"]["code"] == "busy"  # one survey at a time
    assert cancelled["state"] == "cancelled" and "nothing was written" in cancelled["message"]
