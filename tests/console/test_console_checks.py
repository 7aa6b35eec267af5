"""The console shows a commissioning's result as its table of checks (daemon/console/static/checks.js).

One simulated ritad without a worker, one operator console, one browser: a commissioning result reported
as the worker reports it must show one row per check with its verdict, device, name, the measured value
and why; the daemon's text stays text (a value carrying markup shows as that text and never runs).
"""
from __future__ import annotations

import pytest

from daemon.bus.procedures import COMMISSION
from tools.harness.browser import browser_available, console_session, start_robot, wait_for

pytestmark = [pytest.mark.slow, pytest.mark.skipif(browser_available() is not None,
                                                   reason=browser_available() or "")]

P = 'x" data-xss="1"><img src=x data-xss onerror=window.__xss=1>'
CHECKS = [
    {"device": "tracker", "name": "frame_cleared", "verdict": "fail",
     "value": "transformation applied: (100, 50, -20) mm", "detail": "another client's frame"},
    {"device": "camera", "name": "ptp_role", "verdict": "pass", "value": "PtpStatus Slave (3 looks)", "detail": ""},
    {"device": "base", "name": "t_us", "verdict": "warn", "value": P, "detail": "below 2^32 | a bar"},
    {"device": "camera", "name": "timestamp_latch", "verdict": "skip", "value": "no capture timed by PTP",
     "detail": "needs the PTP lock"},
]

ROWS = """return [...document.querySelectorAll('#commission-report table.checks tbody tr')].map(r => ({
    check: r.dataset.check, verdict: r.dataset.verdict, cells: [...r.cells].map(c => c.textContent)}))"""


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("console-checks")
    r, _ = start_robot(tmp, worker=False)
    try:
        with r.client(timeout=30) as c:
            yield {"ritad": r, "tmp": tmp, "client": c}
    finally:
        r.stop()


def test_a_commissioning_result_shows_its_table_of_checks(robot):
    c = robot["client"]
    with console_session(["--endpoint", robot["ritad"].endpoint], robot["tmp"] / "operator") as (_, drv):
        c.call("calib.report", job="commission-1", kind="result", procedure=COMMISSION.name,
               data={"procedure": COMMISSION.name, "verdict": "fail", "checks": CHECKS,
                     "messages": ["tracker frame_cleared: fail"], "table_markdown": "| a |\n|---|\n| b |\n"})
        rows = wait_for("the table of checks", lambda: drv.execute_script(ROWS), 15)
        assert [r["check"] for r in rows] == [f"{c['device']}.{c['name']}" for c in CHECKS]
        assert [r["verdict"] for r in rows] == [c["verdict"] for c in CHECKS]
        assert [r["cells"] for r in rows] == [
            [c["verdict"].upper(), c["device"], c["name"], c["value"], c["detail"]] for c in CHECKS]
        summary = drv.execute_script("return document.querySelector('#commission-report p').textContent")
        assert summary == "1 passed, 1 failed, 1 warned, 1 skipped"
        assert drv.execute_script("return document.getElementById('commission-panel').hidden") is False
        assert drv.execute_script("return document.getElementById('result-table').textContent") == ""
        assert drv.execute_script("return document.querySelectorAll('[data-xss]').length") == 0
        assert drv.execute_script("return window.__xss") is None
