"""The page's motions follow the robot's latched STOP and the jobs that drive (issue 30).

One simulated ritad without a worker (a job posted here stays queued: a job that is about to
drive, as the daemon's STOP counts it), one operator console, one browser. The page's outgoing
WebSocket messages are recorded, so "nothing was sent" is read from the page itself; the base's
pose from the daemon says it did not move.
"""
from __future__ import annotations

from typing import Any

import pytest

from daemon.bus.client import Client
from tools.harness.browser import browser_available, console_session, start_robot, wait_for

pytestmark = [pytest.mark.slow, pytest.mark.skipif(browser_available() is not None,
                                                   reason=browser_available() or "")]

RECORD_SENDS = """window.__sent = []; const orig = window.send;
    window.send = (o) => { window.__sent.push(o); return orig(o); };"""
# state messages held back: the page's picture of the latch lags the daemon's, as over a slow link
HOLD_STATE = """const ws = window.rita.ws, orig = ws.onmessage; window.__held = [];
    window.__resume = () => { ws.onmessage = orig; for (const ev of window.__held.splice(0)) orig(ev); };
    ws.onmessage = (ev) => (typeof ev.data === 'string' && JSON.parse(ev.data).type === 'state')
        ? window.__held.push(ev) : orig(ev);"""
LAST_MOTION = """const done = arguments[arguments.length - 1];
    Promise.resolve(window.rita.lastMotion).then(done, (e) => done('error: ' + e));"""


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("console-latch")
    r, laptop = start_robot(tmp, worker=False)
    try:
        with r.client(timeout=30) as c:
            yield {"ritad": r, "tmp": tmp, "client": c}
    finally:
        r.stop()


@pytest.fixture(scope="module")
def page(robot):
    with console_session(["--endpoint", robot["ritad"].endpoint], robot["tmp"] / "operator") as (_, drv):
        drv.execute_script(RECORD_SENDS)
        yield drv


@pytest.fixture
def released(robot, page):
    """Each test starts released, with Move… enabled on the page, and ends released."""
    c: Client = robot["client"]
    c.call("robot.release")
    wait_for("Move… enabled", lambda: page.find_element("id", "robot-move").is_enabled(), 10)
    yield c
    c.call("robot.release")


def click(drv, element_id: str) -> None:
    el = wait_for(f"#{element_id} enabled",
                  lambda: (e := drv.find_element("id", element_id)).is_enabled() and e, 10)
    drv.execute_script("arguments[0].scrollIntoView({block: 'center'})", el)  # not under the sticky header
    el.click()


def dialog_open(drv) -> bool:
    return drv.find_element("id", "confirm").is_displayed()


def open_move_dialog(drv) -> None:
    click(drv, "robot-move")
    wait_for("the Move dialog open", lambda: dialog_open(drv), 5)


def motions_sent(drv) -> list[Any]:
    return drv.execute_script("return window.__sent.filter(o => o.op === 'call' && "
                              "['robot.move', 'robot.turn'].includes(o.cmd))")


def pose(c: Client) -> tuple[float, float, float]:
    s = c.call("robot.status")
    return s["x_mm"], s["y_mm"], s["heading_deg"]


def motion_buttons_enabled(drv) -> list[bool]:
    return [drv.find_element("id", i).is_enabled() for i in ("robot-move", "robot-turn")]


def test_a_dialog_opened_before_a_stop_is_closed_and_never_sends_after_the_release(page, released):
    """The finding: Move… opened, STOP, release: the dialog was still open and its Move drove 100 mm."""
    c = released
    before = pose(c)
    open_move_dialog(page)
    page.execute_script("window.__staleMove = document.getElementById('confirm-yes').onclick;")
    c.call("robot.stop")
    c.call("robot.release")  # at once: the page may never see a state in which the latch holds
    wait_for("the dialog closed by the STOP", lambda: not dialog_open(page), 5)
    outcome = page.execute_async_script(LAST_MOTION)
    assert outcome.startswith("STOP latched"), outcome
    wait_for("Move… enabled after the release", lambda: all(motion_buttons_enabled(page)), 10)
    # the dialog's own Move, however it is reached now, sends nothing
    page.execute_script("window.__staleMove && window.__staleMove();"
                        "document.getElementById('confirm-yes').click();")
    assert page.execute_async_script(LAST_MOTION) == outcome
    assert motions_sent(page) == []
    assert pose(c) == before and c.call("robot.status")["state"] == "IDLE"


def test_move_and_turn_are_disabled_while_latched_and_both_panels_say_so(page, released):
    c = released
    c.call("robot.stop")
    wait_for("Move… and Turn… disabled", lambda: motion_buttons_enabled(page) == [False, False], 5)
    assert "latched" in page.find_element("id", "motion-note").text
    robot_row = "#daemon-health [data-robot-state]"
    same = lambda: (page.find_element("id", "robot-state").text  # noqa: E731
                    == page.find_element("css selector", robot_row).text)
    wait_for("the Robot and Daemon panels agree on the latch",
             lambda: same() and "STOP latched" in page.find_element("id", "robot-state").text, 5)
    c.call("robot.release")
    wait_for("enabled after the release", lambda: motion_buttons_enabled(page) == [True, True], 5)
    wait_for("both panels released",
             lambda: same() and "latched" not in page.find_element("id", "robot-state").text, 5)


def test_a_page_that_has_not_yet_seen_the_latch_checks_the_daemon_at_the_click(page, released):
    """The page's latch lags (state held back); its Move asks the daemon first and sends nothing."""
    c = released
    before = pose(c)
    open_move_dialog(page)
    page.execute_script(HOLD_STATE)
    try:
        c.call("robot.stop")
        assert c.call("state")["latch"]["latched"]
        assert dialog_open(page)  # the page does not know yet
        click(page, "confirm-yes")
        outcome = page.execute_async_script(LAST_MOTION)
    finally:
        page.execute_script("window.__resume()")
    assert "latched" in outcome, outcome
    assert motions_sent(page) == []
    wait_for("the latch shown once the state arrives",
             lambda: "STOPPED (latched by" in page.find_element("id", "latch").text, 5)
    assert pose(c) == before


def test_a_job_that_drives_closes_the_dialog_and_disables_move_and_turn(page, released, robot):
    c = released
    before = pose(c)
    open_move_dialog(page)
    job = c.call("calib.start", procedure="experiment", params={"mark_xy": [100.0, 200.0]})["job"]
    try:
        wait_for("the dialog closed by the job", lambda: not dialog_open(page), 10)
        assert job in page.execute_async_script(LAST_MOTION)
        wait_for("Move… and Turn… disabled", lambda: motion_buttons_enabled(page) == [False, False], 5)
        assert job in page.find_element("id", "motion-note").text
        page.execute_script("document.getElementById('robot-move').onclick()")  # past the disabled button
        # refused before any dialog opens
        assert page.execute_async_script(LAST_MOTION).endswith("drives the robot")
        assert not dialog_open(page)
        assert motions_sent(page) == []
    finally:
        c.call("robot.stop")  # the daemon stops every job that drives, a queued one too
    assert {j["job"]: j["state"] for j in c.call("calib.jobs")["jobs"]}[job] == "stopped"
    c.call("robot.release")
    wait_for("enabled once the job is over", lambda: motion_buttons_enabled(page) == [True, True], 10)
    assert pose(c) == before
