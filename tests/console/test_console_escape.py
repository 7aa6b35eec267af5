"""Text from the daemon is shown as text, never run as the page's markup (issue 30's stored XSS).

One simulated ritad without a worker, one operator console, one browser. The same payload goes
in through every source the page shows: data-dir file names (the finding: a file named
`x"><img src=x onerror=...>.json` ran script), the stored results and history, a job's step,
prompt, result and error (reported as the worker reports them), and, through the page's own
WebSocket handler as the console forwards them, the daemon's health (device names, states,
reasons), the base's state and fault, the latch's who and why, motion events, the plate survey's
report (nest and photograph names), the live series' points and the procedure form's parameter
table. The payload both breaks out of a quoted attribute and opens an element whose error handler
sets ``window.__xss``;
the page must hold no element or attribute of it, and the handler must not have run, while a
canary put in as markup on purpose does run.
"""
from __future__ import annotations

import json

import pytest

from daemon.bus.client import Client
from tools.harness.browser import browser_available, console_session, start_robot, wait_for

pytestmark = [pytest.mark.slow, pytest.mark.skipif(browser_available() is not None,
                                                   reason=browser_available() or "")]

P = 'x" data-xss="1"><img src=x data-xss onerror=window.__xss=1>'  # no "/": it is also a file name
STORED = {"job": P, "procedure": P, "verdict": P, "created": P, "dataset": f"procedures/{P}"}


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("console-escape")
    r, _ = start_robot(tmp, worker=False)
    try:
        data = tmp / "data"
        (data / "sim" / f"{P}.json").write_text("{}")  # the finding's file, offered by the procedure form
        (data / "calibration" / "history").mkdir(parents=True, exist_ok=True)
        (data / "calibration" / "history" / "29990101T000000-xss.json").write_text(json.dumps(STORED))
        (data / "calibration" / "active.json").write_text(json.dumps(STORED))
        with r.client(timeout=30) as c:
            yield {"ritad": r, "tmp": tmp, "client": c}
    finally:
        r.stop()


def text(drv, element_id: str) -> str:
    return drv.execute_script("return document.getElementById(arguments[0]).textContent", element_id)


INJECTED = """({elements: document.querySelectorAll('[data-xss]').length,
    handlers: [...document.querySelectorAll('[onerror]')].filter(e => e.id !== 'canary').length,
    ran: window.__xss !== undefined})"""
NOTHING = {"elements": 0, "handlers": 0, "ran": False}


def injected(drv) -> dict:
    """What of the payload became markup: elements or attributes it named, and whether its handler ran."""
    return drv.execute_script(f"return {INJECTED};")


def report(c: Client, job: str, kind: str, data: dict) -> None:
    c.call("calib.report", job=job, kind=kind, data=data, procedure="intrinsics")  # as the worker reports


def forward(drv, message: dict, shown: tuple[str, ...]) -> dict:
    """A message into the page's WebSocket handler, as the console forwards the daemon's telemetry, and the
    text of the ``shown`` elements read in the same script (the next real state message cannot interleave)."""
    return drv.execute_script("""window.rita.ws.onmessage({data: arguments[0]});
        const text = (id) => document.getElementById(id).textContent;
        return {injected: %s, ...Object.fromEntries(arguments[1].map(id => [id, text(id)]))};"""
                              % INJECTED, json.dumps(message), list(shown))


def crafted_state() -> dict:
    health = {"uptime_s": 1, "alive": P, "telemetry": {"dropped": {}}, "frames": {"sent": P, "dropped": P},
              "devices": {P: {"state": P, "reason": P, "reconnects": P},
                          "robot": {"state": "FAULT", "reason": P, "reconnects": 0}}}
    survey = {"state": "done", "out": P, "took_s": 1, "version": 10 ** 6, "percent": 100, "step": P,
              "result": {"verdict": P, "message": P, "skipped": {P: P},
                         "nests": {P: {"ref_P_nst_mm": [1, 2, 3], "sigma_mm": [0.001] * 3, "views": P}},
                         "views": [{"image": P, "corners": P, "corner_rms_px": 0.1,
                                    "rings_missing": {P: 1}}]}}
    topic = lambda data: {"seq": 10 ** 6, "t_ns": 0, "data": data}  # noqa: E731
    return {"type": "state", "link": {"bus": "up", "error": P}, "survey": survey,
            "console": {"frames_sent": P, "tabs": P, "preview_error": P},
            "topics": {"daemon.health": topic(health), "robot.state": topic({"state": P, "fault": P}),
                       "robot.latch": topic({"latched": True, "by": P, "reason": P, "since_ns": 1})},
            "series": [{"no": 10 ** 6, "s": P, "t": 1, "v": [P]},
                       {"no": 10 ** 6 + 1, "s": "pose", "t": P, "v": [P]},
                       {"no": 10 ** 6 + 2, "s": "tracker", "t": 1.8e12, "v": [P]}],
            "events": [{"no": 10 ** 6, "topic": "robot.event",
                        "data": {"event": P, "result": P, "reason": P}}]}


def crafted_form(drv) -> None:
    """The procedure form rebuilt from a parameter table whose every string is the payload."""
    base = {"help": P, "unit": P, "required": True, "default": P, "default_text": P, "lo": None, "hi": None,
            "lo_open": False, "range": P, "choices": [], "length": 2, "installed": P}
    params = [dict(base, name=P, kind="float"), dict(base, name="k", kind="str", choices=[P, "b"]),
              dict(base, name="f", kind="file"), dict(base, name="v", kind="vec"),
              dict(base, name="b", kind="bool")]
    drv.execute_script("""const S = window.rita, sel = document.getElementById('proc');
        S.ws.onmessage({data: JSON.stringify({type: 'hello', role: S.role, commands: S.commands,
            procedures: S.procedures, procedure_params: {...S.procParams, [sel.value]: arguments[0]},
            procedure_info: S.procInfo})});
        sel.dispatchEvent(new Event('change'));""", params)


def test_daemon_text_from_every_source_is_shown_as_text_and_never_runs(robot):
    c: Client = robot["client"]
    with console_session(["--endpoint", robot["ritad"].endpoint], robot["tmp"] / "operator") as (_, drv):
        options = lambda: drv.execute_script(  # noqa: E731
            "return [...document.querySelectorAll('#robot-json option')].map(o => o.value)")
        wait_for("the file offered by its name", lambda: f"sim/{P}.json" in options(), 20)
        wait_for("the stored history shown", lambda: text(drv, "history").count(P) >= 3, 20)
        assert P in text(drv, "calib-active")
        report(c, "xss-1", "progress", {"step": P, "percent": 10, "waiting_for": P})
        wait_for("the job's step", lambda: P in text(drv, "job-step"), 10)
        report(c, "xss-1", "prompt", {"question": P, "choices": [P, "ok"]})
        wait_for("the prompt",
                 lambda: text(drv, "prompt-question") == P and P in text(drv, "prompt-choices"), 10)
        table = f"| {P} | b |\n|---|---|\n| **{P}** | *{P}* |\n{P}"
        report(c, "xss-1", "result", {"procedure": P, "verdict": P, "messages": [P], "table_markdown": table,
                                      "dataset": f"procedures/{P}", "files": [P]})
        wait_for("the result",
                 lambda: text(drv, "result-messages") == P and text(drv, "result-table").count(P) == 4, 10)
        assert P in text(drv, "result-files") and text(drv, "result-verdict") == P
        report(c, "xss-2", "error", {"message": P})
        wait_for("the job's error", lambda: P in text(drv, "job-state"), 10)
        panels = ("daemon-health", "robot-state", "latch", "toast", "survey-nests", "survey-views",
                  "survey-message", "console-stats")
        shown = forward(drv, crafted_state(), panels)
        assert shown.pop("injected") == NOTHING
        assert {k: P in v for k, v in shown.items()} == dict.fromkeys(shown, True), shown
        crafted_form(drv)
        wait_for("the crafted form", lambda: text(drv, "proc-form").count(P) >= 2, 5)
        drv.execute_script("document.body.insertAdjacentHTML('beforeend', "
                           "'<img id=canary src=x onerror=\"window.__canary = 1\">')")
        wait_for("the canary's handler ran (handlers do run on this page)",
                 lambda: drv.execute_script("return window.__canary") == 1, 10)
        assert injected(drv) == NOTHING
