"""STOP means stop, from the console page: a latched stop during a running experiment.

One simulated ritad with its worker, a referencing through the bus (the world's own camera
model and the plate's design file: this is about stopping, not accuracy), then an
8-direction experiment per case, stopped from a page in headless chromium at a random
moment of one of its moves: by the shortcut on an operator's page, by the button on a
viewer key's page. The robot must reach idle and stay still for 10 s, the job
``stopped``; resume is refused until an operator releases the latch, then the job completes.
"""
from __future__ import annotations

import json
import random
import time
from typing import Any

import pytest

from daemon.bus.client import Client
from fakes.operator import lock_on_robot, rough_mark
from tools.harness.load import hang_s
from tools.harness.browser import browser_available, console_session, start_robot, wait_for
from tests.system.test_stop_latch import _jobs, assert_still, code_of, wait_end

pytestmark = [pytest.mark.slow, pytest.mark.skipif(browser_available() is not None,
                                                   reason=browser_available() or "")]


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("console-stop")
    r, laptop = start_robot(tmp)
    try:
        with r.client(timeout=30) as c:
            sim = tmp / "data" / "sim"  # the installer's files (docs/operations.md: `ritactl fetch sim`)
            c.call("sim.place_robot_on_plate")
            p = lock_on_robot(c)
            params = {"plate": json.loads((sim / "plate.json").read_text()),
                      "nests_approx_trk": json.loads((sim / "nests.json").read_text()),
                      "robot_approx_trk": [p["x"], p["y"], p["z"]],
                      "camera_model": c.call("sim.truth")["camera_model"]}
            job = c.call("calib.start", procedure="referencing", params=params)["job"]
            assert wait_end(c, job)["state"] == "done"
            yield {"ritad": r, "laptop": laptop, "tmp": tmp, "client": c}
    finally:
        r.stop()


def _stop_from_the_page(drv: Any, c: Client, how: str, rng: random.Random) -> str:
    """An experiment started; STOP from the page at a random moment of one of its moves; the base idle after
    it (how soon: bench/bench_console_latency.py)."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.keys import Keys

    _, mark = rough_mark(c)
    job = c.call("calib.start", procedure="experiment", params={"mark_xy": mark, "repetitions": 1})["job"]
    moving = lambda: c.call("robot.status")["state"] == "MOVING"  # noqa: E731
    for _ in range(rng.randint(1, 3)):  # a few motions first: the STOP lands inside the procedure
        wait_for("the experiment moves the robot", moving, 120, poll=0.01)
        wait_for("the motion ends", lambda: not moving(), 120, poll=0.01)
    wait_for("the experiment moves the robot", moving, 120, poll=0.005)
    time.sleep(rng.uniform(0.0, 0.05))  # a random moment of the move (the fake base runs 50x real time)
    if how == "shortcut":
        ActionChains(drv).key_down(Keys.CONTROL).send_keys(" ").key_up(Keys.CONTROL).perform()
    else:
        drv.find_element("id", "stop").click()
    wait_for("the base idle after STOP", lambda: c.call("robot.status")["state"] == "IDLE", hang_s(5),
             poll=0.005)
    return job


def _stopped_and_still(drv: Any, c: Client, job: str) -> None:
    assert_still(c, 10.0)  # no motion after the STOP
    assert _jobs(c)[job]["state"] == "stopped"
    wait_for("the page shows the job stopped", lambda: drv.find_element("id", "job-id").text == job
             and "stopped" in drv.find_element("id", "job-state").text, 5)
    wait_for("the latch shown", lambda: "STOPPED (latched by" in drv.find_element("id", "latch").text, 5)
    assert not drv.find_element("id", "proc-resume").is_enabled()  # no resume while latched
    assert code_of(c, "calib.resume", job=job) == "stopped"


@pytest.mark.parametrize("key,how", [("operator", "shortcut"), ("viewer", "button")])
def test_stop_from_the_page_during_an_experiment_latches_and_the_job_resumes_after_release(robot, key, how):
    c: Client = robot["client"]
    args = ["--endpoint", robot["ritad"].endpoint]
    if key == "viewer":
        args = ["--endpoint", robot["ritad"].endpoints[1], "--keys", str(robot["laptop"]), "--key", "vic"]
    with console_session(args, robot["tmp"] / key) as (_, drv):
        assert drv.execute_script("return window.rita.role") == key
        job = _stop_from_the_page(drv, c, how, random.Random(19 if key == "operator" else 7))
        _stopped_and_still(drv, c, job)
        if key == "operator":  # Release, then Resume, from the page
            drv.find_element("id", "release").click()
            wait_for("released", lambda: not c.call("state")["latch"]["latched"], 5)
            wait_for("Resume enabled", lambda: drv.find_element("id", "proc-resume").is_enabled(), 5)
            drv.find_element("id", "proc-resume").click()
            # the page's resume travels page -> console -> bus: until it lands the job still reads stopped
            wait_for("resume accepted", lambda: _jobs(c)[job]["state"] != "stopped", 30, poll=0.1)
        else:  # a viewer may stop, never release or resume: an operator does, here through the bus
            assert not drv.find_element("id", "release").is_enabled()
            assert not drv.find_element("id", "proc-resume").is_enabled()
            c.call("robot.release")
            wait_for("resume accepted", lambda: code_of(c, "calib.resume", job=job) == "ok", 30, poll=0.5)
        end = wait_end(c, job)
        assert end["state"] == "done", (end["error"], end["result"])
        wait_for("the page shows it done", lambda: "done" in drv.find_element("id", "job-state").text, 5)
