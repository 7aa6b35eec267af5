"""The console when ritad dies and comes back: stale values greyed with their age, then live again
by themselves.

Its own ritad (no worker: nothing here runs a procedure), one console, one browser; ritad is
killed and started again on the same ipc endpoints while the page stays open.
"""
from __future__ import annotations

import pytest

from tools.harness.browser import browser_available, console_session, robot_config, start_robot, wait_for
from fakes.launch import start_ritad

pytestmark = [pytest.mark.slow, pytest.mark.skipif(browser_available() is not None,
                                                   reason=browser_available() or "")]
PANELS = ("robot-panel", "daemon-panel", "tracker-panel", "camera-panel")


def _stale(drv) -> dict[str, str]:
    return drv.execute_script("""const out = {};
        for (const id of arguments[0]) { const p = document.getElementById(id);
          out[id] = p.classList.contains('stale') ? p.querySelector('.age').textContent : ''; }
        return out;""", list(PANELS))


def test_values_turn_stale_when_ritad_dies_and_live_again_when_it_returns(tmp_path):
    ritad, _ = start_robot(tmp_path, worker=False)
    try:
        with console_session(["--endpoint", ritad.endpoint], tmp_path / "console") as (_, drv):
            text = lambda i: drv.find_element("id", i).text  # noqa: E731
            wait_for("fresh values",
                     lambda: text("robot-state") == "IDLE" and not any(_stale(drv).values()), 20)
            assert "alive true" in text("daemon-health")
            ritad.kill()
            ages = wait_for("every panel stale", lambda: all((s := _stale(drv)).values()) and s, 15)
            assert all("stale: nothing from" in a and a.endswith(" s") for a in ages.values()), ages
            assert text("robot-state").startswith("unknown (was IDLE")  # not IDLE any more
            assert text("tracker-locked").startswith("unknown")
            assert "alive true" not in text("daemon-health")
            ritad = start_ritad(robot_config(worker=False), tmp=tmp_path, timeout=90)
            ritad.wait_ready(timeout=90, worker=False)
            wait_for("fresh again by itself", lambda: not any(_stale(drv).values()), 30)
            assert text("robot-state") == "IDLE"
            with ritad.client(timeout=30) as c:
                c.call("camera.stream.start")
                drawn = drv.execute_script("return window.rita.framesDrawn")
                wait_for("the live view resumed",
                         lambda: drv.execute_script("return window.rita.framesDrawn") > drawn, 20)
    finally:
        ritad.stop()
