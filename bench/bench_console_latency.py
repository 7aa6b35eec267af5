"""The console's and the STOP's latencies: what the browser and STOP tests leave to a benchmark (issue 34).

The tests assert order and causality (the base idle after the STOP, no motion after it, the stop latched, a
second tab showing the job done); how soon is measured here, in the tests' own set-up: ritad on the fakes (the
fake base at the simulator's 50× speed; no worker: the bench ends jobs as the worker reports them),
``ritactl console`` and a headless chromium page
(tools/harness/browser.py), a viewer key's page over CURVE tcp. Each round starts a slow move (300 mm at
1 mm/s: 6 s of wall time) and stops it; times are from just before the stop's action to the first
``robot.status`` that reads IDLE (polled every 5 ms, so a figure may be up to ~5 ms late).

Rows (the test each replaces):
- ``robot.stop`` from a bus client → IDLE (tests/system/test_stop_latch.py, ≤ 0.5 s there);
- STOP button on the operator's page → IDLE (test_console_browser.py
  test_stop_during_a_move_stops_the_robot, < 2 s);
- Ctrl+Space / the STOP button with the Move dialog open → IDLE (test_console_browser.py
  test_stop_works_with_the_confirmation_dialog_open, ≤ 0.5 s; test_console_stop_acceptance.py
  operator-shortcut, ≤ 0.5 s);
- STOP button on a viewer key's page → IDLE (test_viewer_key_page_has_no_enabled_control and
  test_console_stop_acceptance.py viewer-button, ≤ 0.5 s);
- Start of the live view → first frame drawn (test_camera_panel_shows_a_frame, < 5 s);
- a job ended by another client → a second tab shows it done (test_console_browser.py
  test_a_second_tab_follows_a_job_run_from_the_bus, ≤ 2 s; the job here is posted and ended through the bus,
  as the worker reports it).

Run: ``.venv/bin/python bench/bench_console_latency.py [--rounds 5]`` (needs chromium + chromium-driver).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Callable

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.common import machine, pct  # noqa: E402
from daemon.bus.client import Client  # noqa: E402
from tools.harness.browser import console_session, start_robot, wait_for  # noqa: E402


def idle_after(c: Client, act: Callable[[], Any]) -> float:
    """Seconds from just before ``act()`` to the first status that reads IDLE."""
    t0 = time.monotonic()
    act()
    wait_for("the base idle", lambda: c.call("robot.status")["state"] == "IDLE", 30, poll=0.005)
    return time.monotonic() - t0


def moving(c: Client) -> None:
    if c.call("state")["latch"]["latched"]:
        c.call("robot.release")
    c.call("robot.move", distance_mm=300.0, speed_mm_s=1.0, confirm=True, wait=False)
    wait_for("the robot moving", lambda: c.call("robot.status")["state"] == "MOVING", 30, poll=0.005)


def with_dialog_open(drv: Any, c: Client) -> None:
    moving(c)
    drv.execute_script("document.getElementById('move-mm').value = '300';"
                       "document.getElementById('move-speed').value = '1';")
    drv.find_element("id", "robot-move").click()
    wait_for("the dialog open", lambda: drv.find_element("id", "confirm").is_displayed(), 30)


def close_dialog(drv: Any) -> None:
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.keys import Keys

    ActionChains(drv).send_keys(Keys.ESCAPE).perform()
    wait_for("the dialog closed", lambda: not drv.find_element("id", "confirm").is_displayed(), 30)


def shortcut(drv: Any) -> None:
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.keys import Keys

    ActionChains(drv).key_down(Keys.CONTROL).send_keys(" ").key_up(Keys.CONTROL).perform()


def first_frame(drv: Any, c: Client) -> float:
    drawn = drv.execute_script("return window.rita.framesDrawn")
    t0 = time.monotonic()
    drv.find_element("id", "stream-start").click()
    try:
        wait_for("a frame drawn", lambda: drv.execute_script("return window.rita.framesDrawn") > drawn, 60,
                 poll=0.01)
        return time.monotonic() - t0
    finally:
        c.call("camera.stream.stop")


def second_tab_done(drv: Any, base: str, c: Client) -> float:
    """A job posted and ended through the bus (as the worker reports it); its end → a second tab shows it
    done."""
    job = c.call("calib.start", procedure="referencing", params={})["job"]
    wait_for("the tab shows the job", lambda: drv.find_element("id", "job-id").text == job, 30, poll=0.01)
    t0 = time.monotonic()
    c.call("calib.report", job=job, kind="result",
           data={"procedure": "referencing", "verdict": "ok", "messages": ["bench"], "dataset": "d1",
                 "files": []})
    wait_for("shown done", lambda: "done" in drv.find_element("id", "job-state").text, 30, poll=0.01)
    return time.monotonic() - t0


def row(label: str, values: list[float], goal: str) -> str:
    ms = [v * 1e3 for v in values]
    return (f"| {label} | p50 {pct(ms, 50):.0f} ms, max {max(ms):.0f} ms (n={len(ms)}) | {goal} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5, help="measurements per row")
    n = ap.parse_args().rounds
    print(f"# bench_console_latency\n\nMachine: {machine()}\n")
    tmp = Path(tempfile.mkdtemp(prefix="rita-bench-console-latency-"))
    r, laptop = start_robot(tmp, worker=False)  # the bench plays the worker: jobs end when it reports them
    rows = []
    try:
        with r.client(timeout=30) as c, \
                console_session(["--endpoint", r.endpoint], tmp / "operator") as (con, drv):
            bus = [idle_after(c, lambda: c.call("robot.stop")) for _ in range(n) if moving(c) is None]
            button = [idle_after(c, lambda: drv.find_element("id", "stop").click()) for _ in range(n)
                      if moving(c) is None]
            dialog_key, dialog_button = [], []
            for _ in range(n):
                with_dialog_open(drv, c)
                dialog_key.append(idle_after(c, lambda: shortcut(drv)))
                close_dialog(drv)
                with_dialog_open(drv, c)
                dialog_button.append(idle_after(c, lambda: drv.find_element("id", "stop").click()))
                close_dialog(drv)
            c.call("robot.release")
            frames = [first_frame(drv, c) for _ in range(n)]
            drv.switch_to.new_window("tab")
            drv.get(con.base)
            wait_for("the second tab connected",
                     lambda: drv.execute_script("return window.rita.role") != "unknown", 60)
            tab = [second_tab_done(drv, con.base, c) for _ in range(n)]
            viewer_args = ["--endpoint", r.endpoints[1], "--keys", str(laptop), "--key", "vic"]
            with console_session(viewer_args, tmp / "viewer") as (_, vdrv):
                viewer = [idle_after(c, lambda: vdrv.find_element("id", "stop").click()) for _ in range(n)
                          if moving(c) is None]
            c.call("robot.release")
        rows = [row("`robot.stop` from a bus client → base IDLE", bus, "≤ 0.5 s"),
                row("STOP button, operator's page → base IDLE", button, "< 2 s"),
                row("Ctrl+Space with the Move dialog open → base IDLE", dialog_key, "≤ 0.5 s"),
                row("STOP button with the Move dialog open → base IDLE", dialog_button, "≤ 0.5 s"),
                row("STOP button, viewer key's page (CURVE tcp) → base IDLE", viewer, "≤ 0.5 s"),
                row("live view Start → first frame drawn", frames, "≤ 5 s"),
                row("job ended by another client → a second tab shows it done", tab, "≤ 2 s")]
    finally:
        r.stop()
    print("| latency | measured | goal |\n|---|---|---|")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
