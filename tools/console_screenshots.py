"""Regenerate the console screenshots under docs/img/ (referenced from README and docs/operations.md).

Runs what the browser tests run: a simulated ritad, ``ritactl console`` and headless
Debian chromium; then drives the page as an operator (live view, tracker aim + find,
referencing from its form with its prompt, the detected plate corners, the 8-direction experiment, the plate
survey) and as a viewer key, and
saves one picture per view. The operator's hands (placing the robot, locking the
tracker on the robot when the prompt asks) are the simulation's, as in the demo.

Run: ``.venv/bin/python tools/console_screenshots.py [--out docs/img]`` (about a minute).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fakes.operator import lock_on_robot  # noqa: E402
from tools.harness.browser import console_session, start_robot, wait_for  # noqa: E402


def press(drv, element_id: str) -> None:
    """Click a control where a person would: scrolled to the middle, clear of the sticky header."""
    el = drv.find_element("id", element_id)
    drv.execute_script("arguments[0].scrollIntoView({block: 'center'})", el)
    el.click()


def set_value(drv, element_id: str, value: str) -> None:
    drv.execute_script("document.getElementById(arguments[0]).value = arguments[1];", element_id, value)


def run_procedure(drv, procedure: str, fields: dict, answer=None, timeout: float = 300) -> None:
    """Choose ``procedure``, type ``fields`` (form input id → text) into its form, start it."""
    drv.execute_script("const s = document.getElementById('proc'); s.value = arguments[0];"
                       "s.dispatchEvent(new Event('change'));", procedure)
    for element_id, value in fields.items():
        el = drv.find_element("id", element_id)
        el.clear()
        el.send_keys(value)
    press(drv, "proc-start")
    if answer is not None:
        wait_for("the prompt", lambda: drv.find_element("id", "prompt").is_displayed(), 60)
        answer()
    wait_for(f"{procedure} result", lambda: drv.find_element("id", "result").is_displayed(), timeout)
    time.sleep(1.5)  # the plot and the history fetch their files


def operator_views(drv, c, data: Path, out: Path) -> None:
    sim = {n: json.loads((data / "sim" / f"{n}.json").read_text()) for n in ("plate", "board", "nests")}
    press(drv, "stream-start")
    wait_for("frames", lambda: drv.execute_script("return window.rita.framesDrawn") >= 3, 20)
    x, y, z = sim["nests"]["red"]
    for axis, v in zip("xyz", (x, y, z)):
        set_value(drv, f"aim-{axis}", str(v))
    press(drv, "tracker-aim")
    wait_for("aimed", lambda: "aimed" in drv.find_element("id", "toast").text, 30)
    press(drv, "tracker-find")
    wait_for("locked", lambda: drv.find_element("id", "tracker-locked").text == "locked", 30)
    press(drv, "tracker-measure")
    time.sleep(1.5)
    drv.execute_script("window.scrollTo(0, 0)")  # the page as it opens: STOP, live view and procedures
    drv.save_screenshot(str(out / "console-live.png"))
    c.call("camera.stream.stop")

    from fakes.board import answer_intrinsics_prompt, run_intrinsics

    def install(client, question, rng):  # the camera model from the product's own intrinsics, installed
        return "install" if "Install" in question else answer_intrinsics_prompt(client, question, rng)

    run_intrinsics(c, {"board": sim["board"]}, seed=1, timeout=300, answer=install)
    c.call("sim.place_robot_on_plate")
    fields = {"pp-plate": "sim/plate.json", "pp-nests_approx_trk": "sim/nests.json"}  # files on the robot

    def answer() -> None:
        drv.find_element("id", "prompt").location_once_scrolled_into_view
        drv.save_screenshot(str(out / "console-prompt.png"))
        lock_on_robot(c)
        press(drv, "prompt-choice-ok")

    run_procedure(drv, "referencing", fields, answer)
    time.sleep(1.0)
    drv.execute_script("document.getElementById('result').scrollIntoView({block: 'center'})")
    drv.save_screenshot(str(out / "console-referencing.png"))
    detect_view(drv, c, out)
    mark = c.call("sim.truth")["marks"][0]  # where the simulated floor mark is: the operator can see it
    run_procedure(drv, "experiment", {"pp-mark_xy-0": f"{mark['x_mm']:.1f}", "pp-mark_xy-1": f"{mark['y_mm']:.1f}",
                                      "pp-repetitions": "2"})
    time.sleep(1.0)  # the plot reads the dataset's result.json
    drv.execute_script("document.getElementById('result-plot').scrollIntoView({block: 'end'})")
    drv.save_screenshot(str(out / "console-experiment.png"))
    drv.execute_script("document.getElementById('live-panel').scrollIntoView({block: 'end'})")
    time.sleep(1.0)  # the plots redraw twice a second
    drv.save_screenshot(str(out / "console-plots.png"))  # the experiment's last minute: pose, wheels, tracker
    survey_view(drv, c, data, out)


def survey_view(drv, c, data: Path, out: Path) -> None:
    """The plate survey run from the page on photographs the simulated installer took (a laptop folder)."""
    made = c.call("sim.survey_images", views=4, width_px=1800, timeout=300)
    for element_id, value in (("survey-folder", str(data / made["folder"])),
                              ("survey-plate", str(data / "sim" / "plate.json")),
                              ("survey-out", str(data.parent / "surveyed-plate.json"))):
        set_value(drv, element_id, value)
    press(drv, "survey-start")
    wait_for("the survey", lambda: drv.execute_script("return (window.rita.survey || {}).state") == "done", 120)
    drv.find_element("id", "survey-panel").location_once_scrolled_into_view
    drv.save_screenshot(str(out / "console-survey.png"))


def detect_view(drv, c, out: Path) -> None:
    """The robot still on the plate after referencing: the plate corners camera.detect finds, over the live view."""
    set_value(drv, "detect-plate", "sim/plate.json")  # the installer's plate file
    press(drv, "stream-start")
    wait_for("frames", lambda: drv.execute_script("return window.rita.framesDrawn") >= 3, 20)
    press(drv, "detect")
    wait_for("a detection", lambda: drv.execute_script("return window.rita.detections") >= 1, 60)
    time.sleep(1.0)
    drv.find_element("id", "camera-panel").location_once_scrolled_into_view
    drv.save_screenshot(str(out / "console-detect.png"))
    c.call("camera.stream.stop")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(Path(__file__).resolve().parents[1] / "docs" / "img"))
    a = ap.parse_args()
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="console-shots-"))
    r, laptop = start_robot(tmp)
    try:
        with r.client(timeout=60) as c:
            with console_session(["--endpoint", r.endpoint], tmp / "operator") as (_, drv):
                drv.set_window_size(1366, 768)  # the laptop screen the layout is made for
                operator_views(drv, c, tmp / "data", out)
            viewer = ["--endpoint", r.endpoints[1], "--keys", str(laptop), "--key", "vic"]
            with console_session(viewer, tmp / "viewer") as (_, drv):
                drv.set_window_size(1366, 768)
                time.sleep(2)
                drv.save_screenshot(str(out / "console-viewer.png"))
    finally:
        r.stop()
    for p in sorted(out.glob("console-*.png")):
        print(p, p.stat().st_size)
    return 0


if __name__ == "__main__":
    sys.exit(main())
