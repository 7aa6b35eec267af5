"""The operator console in a real headless chromium against a simulated ritad.

One ritad (worker, CURVE tcp for the viewer key), one ``ritactl console`` for the local
operator and one browser serve the module; the viewer test points the same browser at
a second console that uses the viewer key. Tests run in file order (the robot is on the
plate after referencing, the STOP test drives it a little).
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from daemon.bus.client import Client
from tools.harness.browser import browser_available, console_session, start_robot
from tools.harness.browser import wait_for as _wait_for
from tools.harness.load import hang_s

pytestmark = [pytest.mark.slow, pytest.mark.skipif(browser_available() is not None,
                                                   reason=browser_available() or "")]


@pytest.fixture(scope="module")
def robot(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("console")
    r, laptop = start_robot(tmp)
    try:
        with r.client(timeout=30) as c:
            yield {"ritad": r, "laptop": laptop, "tmp": tmp, "client": c}
    finally:
        r.stop()


@pytest.fixture(scope="module")
def session(robot):
    with console_session(["--endpoint", robot["ritad"].endpoint], robot["tmp"] / "operator") as (con, drv):
        yield con, drv


@pytest.fixture(scope="module")
def page(session):
    return session[1]


def wait_for(what: str, fn, timeout: float, poll: float = 0.1):
    """The harness's wait, its bound (what the step takes on a quiet machine, with room) times the load
    factor: a wait here only catches a hang (tools/harness/load.py)."""
    return _wait_for(what, fn, hang_s(timeout), poll)


def js(drv, script: str):
    return drv.execute_script(script)


def text(drv, element_id: str) -> str:
    return drv.find_element("id", element_id).text


#: true when the element is shown, enabled and what a click at its centre would reach (not covered by a dialog
#: or the sticky header); scrolled to the middle of the window first
CLICKABLE = """const e = arguments[0]; e.scrollIntoView({block: 'center'});
    const r = e.getBoundingClientRect(), x = r.left + r.width / 2, y = r.top + r.height / 2;
    const top = document.elementFromPoint(x, y);
    return r.width > 0 && r.height > 0 && !e.disabled && top !== null && (top === e || e.contains(top));"""


def click(drv, element_id: str) -> None:
    """Click once the page is ready for it: the element shown, enabled and not covered (no race)."""
    el = wait_for(f"#{element_id} shown, enabled and not covered",
                  lambda: drv.execute_script(CLICKABLE, e := drv.find_element("id", element_id)) and e,
                  10)
    el.click()


def dialog_open(drv) -> bool:
    """The motion confirmation shown with its text filled in (console.js confirmMotion)."""
    return drv.find_element("id", "confirm").is_displayed() and bool(text(drv, "confirm-text"))


def non_blank(png: bytes) -> float:
    """Standard deviation of the grey levels of a screenshot: 0 for a blank picture."""
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_GRAYSCALE)
    return float(img.std())


def operator_file(robot, name: str) -> dict:
    """The files the simulated installer left for the operator (docs/operations.md: `ritactl fetch sim`)."""
    return json.loads((robot["tmp"] / "data" / "sim" / name).read_text())


def install_camera_model(c: Client, robot) -> None:
    """Run the guided intrinsics with the simulated operator's hands; install the model even on warn
    (a small test image may not reach the 0.1 % focal goal; the UI test needs a model, not that goal)."""
    from fakes.board import answer_intrinsics_prompt, run_intrinsics

    def answer(client, question, rng):
        return "install" if "Install" in question else answer_intrinsics_prompt(client, question, rng)

    r = run_intrinsics(c, {"board": operator_file(robot, "board.json")}, seed=1, timeout=300, answer=answer)
    assert r.get("verdict") in ("ok", "warn"), r


def test_camera_panel_shows_a_frame(page, robot):
    """A frame drawn after Start (how soon: bench/bench_console_latency.py)."""
    drawn = js(page, "return window.rita.framesDrawn")
    click(page, "stream-start")
    try:
        wait_for("a frame drawn", lambda: js(page, "return window.rita.framesDrawn") > drawn, 5)
        shot = page.find_element("id", "cam").screenshot_as_png
    finally:
        robot["client"].call("camera.stream.stop")
    assert non_blank(shot) > 10, "the camera canvas is blank"
    assert "frame" in text(page, "cam-info") and "exposure" in text(page, "cam-info")


#: where the page's key elements are at the window's size, scrolled to the top: each inside the viewport
IN_VIEW = """const r = (e) => e.getBoundingClientRect(), inside = (e) => { const b = r(e);
        return b.top >= 0 && b.left >= 0 && b.bottom <= innerHeight && b.right <= innerWidth
            && b.width > 0; };
    const byId = (id) => document.getElementById(id), cam = r(byId('cam')), panel = r(byId('camera-panel'));
    const ids = ['stop', 'latch', 'pose-head', 'robot-state', 'robot-pose', 'proc', 'proc-start'];
    return {...Object.fromEntries(ids.map((id) => [id, inside(byId(id))])),
            header_state: inside(document.querySelector('#robot-head [data-robot-state]')),
            cam_top: cam.top < innerHeight - 200, cam_wide: cam.width >= panel.width - 40,
            no_hscroll: document.documentElement.scrollWidth <= innerWidth, height: innerHeight};"""


def test_at_1366x768_stop_latch_robot_state_and_pose_the_live_view_and_the_procedures_need_no_scrolling(page):
    """Issue 35: the Robot panel was below the fold. STOP, the latch, the robot's state and pose in sight."""
    wait_for("the pose shown", lambda: text(page, "pose-head") not in ("", "–"), 10)
    wait_for("the latch's state shown", lambda: "latch" in text(page, "latch").lower(), 10)
    page.set_window_size(1366, 768)
    try:
        js(page, "window.scrollTo(0, 0)")
        out = js(page, IN_VIEW)
    finally:
        page.set_window_size(1400, 1100)
    height = out.pop("height")
    assert height >= 500, f"the browser's viewport at 1366x768 is only {height} px: not a laptop's window"
    assert all(out.values()), out
    assert text(page, "robot-pose") == text(page, "pose-head")  # one pose, one text
    assert "ago" in text(page, "pose-head-age")


def test_tracker_panel_shows_locked_after_aim_and_find(page, robot):
    x, y, z = operator_file(robot, "nests.json")["red"]  # the operator's rough nest position
    for axis, v in zip("xyz", (x, y, z)):
        el = page.find_element("id", f"aim-{axis}")
        el.clear()
        el.send_keys(str(v))
    click(page, "tracker-aim")
    wait_for("aimed", lambda: "aimed" in text(page, "toast"), 30)
    click(page, "tracker-find")
    assert wait_for("tracker panel says locked", lambda: text(page, "tracker-locked") == "locked", 30)


def choose_procedure(drv, name: str) -> None:
    js(drv, f"const s = document.getElementById('proc'); s.value = '{name}'; s.dispatchEvent(new Event('change'));")
    wait_for(f"the {name} form", lambda: drv.find_element("id", "proc-form").get_attribute("data-procedure") == name, 5)


def fill(drv, element_id: str, value: str) -> None:
    el = drv.find_element("id", element_id)
    el.clear()
    el.send_keys(value)


def test_procedure_form_shows_defaults_and_refuses_bad_values_naming_the_field(page, robot):
    c: Client = robot["client"]
    posted = len(c.call("calib.jobs")["jobs"])
    choose_procedure(page, "experiment")
    assert page.find_element("id", "pp-directions").get_attribute("value") == "8"  # the table's default, shown
    assert page.find_element("id", "pp-kind").tag_name == "select"
    assert page.find_element("id", "pp-calibration").get_attribute("placeholder").startswith("calibration/active.json")
    fill(page, "pp-mark_xy-0", "100")
    fill(page, "pp-mark_xy-1", "200")
    fill(page, "pp-directions", "0")
    click(page, "proc-start")
    wait_for("the page's message", lambda: "directions" in text(page, "proc-error"), 5)
    assert "0 is outside" in text(page, "proc-error") or "≥ 1" in text(page, "proc-error"), text(page, "proc-error")
    marked = js(page, "return [...document.querySelectorAll('#proc-form .bad-field')].map(e => e.dataset.param)")
    assert marked == ["directions"]
    fill(page, "pp-directions", "8")
    fill(page, "pp-speed_mm_s", "fast")
    click(page, "proc-start")
    wait_for("the page's message", lambda: "speed_mm_s" in text(page, "proc-error"), 5)
    assert "not a number" in text(page, "proc-error")
    # the console checks too: a value the page let through (advanced JSON) is refused there, naming the field
    fill(page, "pp-speed_mm_s", "100")
    js(page, "document.getElementById('proc-params').value = '{\"repetitions\": -2}';")
    click(page, "proc-start")
    wait_for("the console's message", lambda: "repetitions" in text(page, "proc-error"), 10)
    js(page, "document.getElementById('proc-params').value = '';")
    assert len(c.call("calib.jobs")["jobs"]) == posted, "a refused form posted a job"


def plot_pixels(drv) -> int:
    """Pixels of the result plot that are not white: axes, ticks, labels and the points."""
    return js(drv, """
        const c = document.getElementById('result-plot'), d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
        let n = 0; for (let i = 0; i < d.length; i += 4) if (d[i] < 200 || d[i + 1] < 200 || d[i + 2] < 200) n++;
        return n;""")


@pytest.fixture(scope="module")
def camera_model(robot):
    """The camera model from the product's own intrinsics, run once for the module (the second-tab test runs it)."""
    if not robot.get("model_installed"):
        install_camera_model(robot["client"], robot)
        robot["model_installed"] = True
    return True


def test_a_second_tab_follows_a_job_run_from_the_bus(session, robot):
    """A job started and finished by another client (ritactl, a script): the page follows it, its prompts
    included, shows it done and refreshes the history (how soon after the job's end:
    bench/bench_console_latency.py)."""
    con, drv = session
    original = drv.current_window_handle
    drv.switch_to.new_window("tab")
    try:
        drv.get(con.base)  # the cookie the first tab got: no token in this URL
        wait_for("the second tab connected", lambda: js(drv, "return window.rita.role") != "unknown", 20)
        history0 = len(js(drv, "return [...document.querySelectorAll('#history tr')]") or [])
        install_camera_model(robot["client"], robot)
        robot["model_installed"] = True
        job = robot["client"].call("calib.jobs")["jobs"][-1]
        wait_for("the job shown done",
                 lambda: text(drv, "job-id") == job["job"] and "done" in text(drv, "job-state"), 5)
        assert js(drv, "return window.rita.promptsSeen") >= 1  # the job's prompts were shown as it asked them
        wait_for("the history refreshed",
                 lambda: len(js(drv, "return [...document.querySelectorAll('#history tr')]")) > history0, 5)
        wait_for("the intrinsics summary", lambda: "principal point" in text(drv, "result-rob-H-cam"), 10)
        assert "NaN" not in text(drv, "result-rob-H-cam") and "RMS" in text(drv, "result-rob-H-cam")
    finally:
        drv.close()
        drv.switch_to.window(original)


def test_referencing_from_the_ui_answers_a_prompt_and_shows_result_and_plot(page, robot, camera_model):
    from fakes.operator import lock_on_robot

    c: Client = robot["client"]
    c.call("sim.place_robot_on_plate")  # the installer's hands: the robot stands on the plate
    choose_procedure(page, "referencing")  # the plate's design file and the rough nests, files on the robot;
    fill(page, "pp-plate", "sim/plate.json")  # the model: the installed one; no robot position: the worker asks
    fill(page, "pp-nests_approx_trk", "sim/nests.json")
    click(page, "proc-start")
    wait_for("the prompt", lambda: page.find_element("id", "prompt").is_displayed(), 60)
    assert "reflector" in text(page, "prompt-question")
    assert int(page.find_element("id", "job-progress").get_attribute("value")) > 0
    assert text(page, "job-step")
    lock_on_robot(c)  # the operator's hands put the tracker on the robot's reflector, as the prompt asks
    click(page, "prompt-choice-ok")
    wait_for("the result", lambda: page.find_element("id", "result").is_displayed(), 120)
    assert text(page, "result-verdict") in ("ok", "warn")
    assert "rob_H_cam" in text(page, "result-rob-H-cam") and "1σ" in text(page, "result-rob-H-cam")
    assert wait_for("the result plot", lambda: plot_pixels(page) > 200, 10)


def overlay_pixels(png: bytes) -> int:
    """Pixels of the detection overlay's green (#00e676) in a screenshot: the camera image itself is grey."""
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR).astype(int)  # BGR
    b, g, r = img[..., 0], img[..., 1], img[..., 2]
    return int(((g > 180) & (r < 80) & (g - b > 60)).sum())


def test_detect_draws_the_plate_corners_over_the_live_view(page, robot):
    robot["client"].call("sim.place_robot_on_plate")  # the installer's hands: the target is under the camera
    js(page, "document.getElementById('detect-plate').value = 'sim/plate.json';"  # the installer's plate file
             "document.getElementById('detect-width').value = '1000';")
    click(page, "stream-start")
    try:
        drawn = js(page, "return window.rita.framesDrawn")
        wait_for("a frame", lambda: js(page, "return window.rita.framesDrawn") > drawn, 10)
        before = overlay_pixels(page.find_element("id", "cam").screenshot_as_png)
        click(page, "detect")
        wait_for("a detection", lambda: js(page, "return window.rita.detections") >= 1, 60)
        drawn = js(page, "return window.rita.framesDrawn")
        wait_for("a frame after it", lambda: js(page, "return window.rita.framesDrawn") > drawn, 10)
        shot = page.find_element("id", "cam").screenshot_as_png
    finally:
        robot["client"].call("camera.stream.stop")
    d, info = js(page, "return window.rita.detection"), text(page, "detect-info")
    assert d and d["target"] == "plate" and d["n"] > 30, info
    assert info.startswith(f"{d['n']} corners"), info  # the count is shown
    assert before == 0 and overlay_pixels(shot) > 30, (before, overlay_pixels(shot))  # the dots are drawn


def test_plate_survey_from_the_page_shows_progress_and_the_per_nest_report(page, robot):
    """The survey runs on the laptop (the console's child process) from photographs in a laptop folder."""
    made = robot["client"].call("sim.survey_images", views=3, width_px=1500, timeout=120)  # the installer's camera
    data, out = robot["tmp"] / "data", robot["tmp"] / "surveyed-plate.json"
    fill(page, "survey-folder", str(data / "no-such-folder"))
    fill(page, "survey-plate", str(data / "sim" / "plate.json"))
    fill(page, "survey-out", str(out))
    click(page, "survey-start")
    wait_for("the bad folder named", lambda: "not a folder of photographs" in text(page, "survey-message"), 30)
    assert str(data / "no-such-folder") in text(page, "survey-message")
    fill(page, "survey-folder", str(data / made["folder"]))
    click(page, "survey-start")
    wait_for("the survey done", lambda: js(page, "return (window.rita.survey || {}).state") == "done", 90)
    assert js(page, "return window.rita.surveySteps") >= 2  # progress was shown while it ran
    rows = page.find_element("id", "survey-nests").find_elements("tag name", "tr")
    assert [r.find_elements("tag name", "td")[0].text for r in rows[1:]] == ["red", "green", "blue"]
    verdict = json.loads(out.read_text())["survey"]["verdict"]  # the file written is the one reported
    assert text(page, "survey-message").startswith(verdict) and "µm" in text(page, "survey-message")
    # the surveyed plate to the robot's calibration folder, over the bus with the operator's key
    fill(page, "survey-name", "surveyed.json")
    choose_procedure(page, "referencing")
    click(page, "survey-upload")
    wait_for("stored on the robot", lambda: "stored on the robot as calibration/surveyed.json" in text(page, "survey-uploaded"), 30)
    assert json.loads((data / "calibration" / "surveyed.json").read_text()) == json.loads(out.read_text())
    assert page.find_element("id", "pp-plate").get_attribute("value") == "calibration/surveyed.json"
    bad = robot["tmp"] / "bad-plate.json"
    bad.write_text(json.dumps(dict(json.loads(out.read_text()), square_mm=-1)))
    fill(page, "survey-out", str(bad))
    click(page, "survey-upload")
    wait_for("refused naming the field", lambda: "square_mm" in text(page, "survey-uploaded"), 30)
    fill(page, "survey-out", str(out))


def test_capture_saves_on_the_laptop_and_datasets_download(session, robot):
    import urllib.request

    con, drv = session
    click(drv, "capture")
    saved = wait_for("the capture saved", lambda: "saved" in text(drv, "toast") and text(drv, "toast"), 30)
    path = Path(saved.split("saved ", 1)[1].split(" (", 1)[0])
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    assert img is not None and img.shape == (750, 1000) and img.std() > 10  # full resolution, not blank
    listing = urllib.request.urlopen(con.at("list/procedures"), timeout=30).read().decode()
    link = next(part.split('"')[0] for part in listing.split('href="/files/')[1:] if "result.json" in part)
    result = json.loads(urllib.request.urlopen(con.at("files/" + link.split("?")[0]), timeout=30).read())
    assert result["procedure"] in ("intrinsics", "referencing", "experiment")


def test_stop_during_a_move_stops_the_robot(page, robot):
    c: Client = robot["client"]
    # 300 mm at 1 mm/s: 300 s of motion, 6 s of wall time at the fake base's time_scale 0.02
    for el, v in (("move-mm", "300"), ("move-speed", "1")):
        page.find_element("id", el).clear()
        page.find_element("id", el).send_keys(v)
    before = c.call("robot.status")
    click(page, "robot-move")
    wait_for("the confirmation", lambda: dialog_open(page), 5)
    click(page, "confirm-no")  # no confirmation, no motion
    wait_for("the dialog closed", lambda: not page.find_element("id", "confirm").is_displayed(), 5)
    start = c.call("robot.status")
    assert start["state"] == "IDLE" and (start["x_mm"], start["y_mm"]) == (before["x_mm"], before["y_mm"])
    click(page, "robot-move")
    wait_for("the confirmation", lambda: dialog_open(page), 5)
    click(page, "confirm-yes")
    wait_for("the robot moving", lambda: c.call("robot.status")["state"] == "MOVING", 10)
    wait_for("the robot on its way", lambda: c.call("robot.status")["x_mm"] != start["x_mm"], 5)
    click(page, "stop")
    wait_for("the robot stopped", lambda: c.call("robot.status")["state"] == "IDLE", 5)
    a = c.call("robot.status")
    assert c.call("state")["latch"]["latched"]  # the page's STOP is the latched stop
    wait_for("the latch shown", lambda: "STOPPED (latched by" in text(page, "latch"), 5)
    b = c.call("robot.status")
    assert (a["x_mm"], a["y_mm"]) == (b["x_mm"], b["y_mm"]), "the robot still moves after STOP"
    driven = float(np.hypot(b["x_mm"] - start["x_mm"], b["y_mm"] - start["y_mm"]))
    assert driven < 200, f"STOP came too late: the robot drove {driven:.0f} of 300 mm"
    c.call("robot.release")


def _moving_with_the_dialog_open(page, c: Client) -> None:
    """A confirmed slow move, then the Move dialog opened again over the page."""
    if c.call("state")["latch"]["latched"]:
        c.call("robot.release")
    for el, v in (("move-mm", "300"), ("move-speed", "1")):
        page.find_element("id", el).clear()
        page.find_element("id", el).send_keys(v)
    click(page, "robot-move")
    wait_for("the confirmation", lambda: dialog_open(page), 5)
    assert "forwards 300 mm at 1 mm/s (about 300.0 s)" in text(page, "confirm-text")  # direction, distance, speed, time
    click(page, "confirm-yes")
    wait_for("the confirmation closed", lambda: not page.find_element("id", "confirm").is_displayed(), 5)
    wait_for("the robot moving", lambda: c.call("robot.status")["state"] == "MOVING", 10)
    click(page, "robot-move")  # waits until nothing covers the button
    wait_for("the dialog open again", lambda: dialog_open(page), 5)


def _stopped(c: Client) -> dict:
    """The base idle after the STOP and the stop latched; the base's state then (how soon after the STOP:
    bench/bench_console_latency.py)."""
    wait_for("the base idle", lambda: c.call("robot.status")["state"] == "IDLE", 5)
    assert c.call("state")["latch"]["latched"]
    return c.call("robot.status")


@pytest.mark.parametrize("how", ["shortcut", "button"])
def test_stop_works_with_the_confirmation_dialog_open(page, robot, how):
    """STOP is never covered: its button sits above every dialog and Ctrl+Space works from anywhere."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.keys import Keys

    c: Client = robot["client"]
    _moving_with_the_dialog_open(page, c)
    if how == "shortcut":
        ActionChains(page).key_down(Keys.CONTROL).send_keys(" ").key_up(Keys.CONTROL).perform()
    else:
        page.find_element("id", "stop").click()  # a real click at its place on the screen: nothing covers it
    idle = _stopped(c)
    wait_for("the latch shown", lambda: "STOPPED (latched by" in text(page, "latch"), 5)
    ActionChains(page).send_keys(Keys.ESCAPE).perform()
    wait_for("Esc closed the dialog", lambda: not page.find_element("id", "confirm").is_displayed(), 5)
    after = c.call("robot.status")  # no motion after the STOP, closing the dialog moved nothing
    assert after["state"] == "IDLE", after
    assert (after["x_mm"], after["y_mm"]) == (idle["x_mm"], idle["y_mm"]), (idle, after)
    click(page, "release")
    wait_for("released", lambda: not c.call("state")["latch"]["latched"], 5)
    wait_for("the latch shown released", lambda: text(page, "latch") == "STOP not latched", 5)


def series(page, name: str, since_ms: float = 0.0) -> list[dict]:
    """The points of one live series the page holds (live.js): [{t, v}], t on this computer's clock (ms),
    those sampled from ``since_ms`` on."""
    script = f"return window.rita.series[{name!r}].filter((p) => p.t >= arguments[0])"
    return page.execute_script(script, since_ms)


#: pixels of a line colour (#1565c0, the first line of each live plot) in a live plot's canvas
LINE_PIXELS = """const cv = document.querySelector('#' + arguments[0] + ' canvas'), ctx = cv.getContext('2d');
    const d = ctx.getImageData(0, 0, cv.width, cv.height).data;
    let n = 0;
    for (let i = 0; i < d.length; i += 4) {
        const near = (k, c) => Math.abs(d[i + k] - c) < 40;
        if (near(0, 0x15) && near(1, 0x65) && near(2, 0xc0)) n++;
    }
    return n;"""


def test_live_plots_follow_a_move_and_the_tracker_with_an_age_on_every_value(page, robot):
    """Pose, wheel speeds and the tracker's distance plotted from what the console kept, each with its
    age; the stream's last point, once the stream stops, says how old it is instead of standing as current."""
    from fakes.operator import lock_on_robot

    c: Client = robot["client"]
    if c.call("state")["latch"]["latched"]:
        c.call("robot.release")
    start, t0 = c.call("robot.status"), js(page, "return Date.now()")
    # 200 mm at 2 mm/s: 100 s of the base's time, 2 s of wall time at the fake base's time_scale 0.02
    c.call("robot.move", distance_mm=200.0, speed_mm_s=2.0, confirm=True, wait=True, timeout=hang_s(30))
    end = c.call("robot.status")

    def at_the_end() -> bool:
        p = series(page, "pose")
        return bool(p) and float(np.hypot(p[-1]["v"][0] - end["x_mm"], p[-1]["v"][1] - end["y_mm"])) < 1.0
    wait_for("the page's pose at the move's end", at_the_end, 10)
    pose = series(page, "pose", t0)
    travel = max(float(np.hypot(p["v"][0] - start["x_mm"], p["v"][1] - start["y_mm"])) for p in pose)
    assert travel > 190, f"the pose series shows {travel:.0f} mm of a 200 mm move"
    wheels = [p["v"] for p in series(page, "wheels", t0) if None not in p["v"]]
    top = [max(v[i] for v in wheels) for i in (0, 1)]  # straight ahead at 2 mm/s: both wheels at 2 mm/s
    assert all(abs(v - 2.0) < 0.2 for v in top), top
    lock_on_robot(c)  # the operator's hands: the reflector on the robot, so the tracker can stream
    t1 = js(page, "return Date.now()")  # earlier streams (referencing's) measured other places
    c.call("tracker.stream.start", rate_hz=100.0)
    try:
        wait_for("tracker distances on the page", lambda: len(series(page, "tracker", t1)) >= 10, 10)
        wait_for("the stream's point shown with its age",
                 lambda: "ago" in text(page, "tracker-point-age") and "stream" in text(page, "tracker-point"),
                 5)
    finally:
        c.call("tracker.stream.stop")
    xyz = c.call("tracker.measure")
    d = series(page, "tracker", t1)[-1]["v"][0]
    assert abs(d - float(np.linalg.norm([xyz["x"], xyz["y"], xyz["z"]]))) < 5.0  # the reflector stands still
    for plot in ("live-x", "live-y", "live-heading", "live-wheels", "live-tracker"):
        wait_for(f"{plot} drawn with its line", lambda: page.execute_script(LINE_PIXELS, plot) > 5, 5)
        caption = js(page, f"return document.querySelector('#{plot} figcaption').textContent")
        assert "ago" in caption and ("mm" in caption or "°" in caption), caption
    # the stream has stopped: its last point grows old on the page, marked so, not frozen as if current
    wait_for("the stopped stream's point marked old",
             lambda: "old" in page.find_element("id", "tracker-point-age").get_attribute("class"), 10)


#: for each panel scrolled into view at its end: its bottom against the message bar's top (px)
CLEAR_OF_BAR = """const bar = document.getElementById('toast-bar');
    return [...document.querySelectorAll('main section')].filter((s) => !s.hidden).map((s) => {
        s.scrollIntoView({block: 'end'});
        return [s.id, s.getBoundingClientRect().bottom, bar.getBoundingClientRect().top]; });"""


def test_a_message_never_covers_the_page_and_the_drift_plots_time_ticks_differ(page):
    """Issue 35: toasts covered the history table, the drift plot's x axis read the same five times."""
    js(page, "toast('a message long enough to have covered a table row: ' + 'x'.repeat(200))")
    page.set_window_size(1366, 768)
    try:
        for panel, bottom, bar_top in js(page, CLEAR_OF_BAR):
            assert bottom <= bar_top + 0.5, f"{panel} ends at {bottom} px, under the bar at {bar_top} px"
        js(page, "window.scrollTo(0, document.documentElement.scrollHeight)")
        last = js(page, "return document.getElementById('history').getBoundingClientRect().bottom")
        assert last <= js(page, "return document.getElementById('toast-bar').getBoundingClientRect().top")
    finally:
        page.set_window_size(1400, 1100)
    spans = {"20 s": 20, "3 min": 180, "5 h": 5 * 3600, "3 days": 3 * 86400, "40 days": 40 * 86400}
    for what, span in spans.items():
        script = "const t = timeTicks(1.8e9, 1.8e9 + arguments[0]); return t.ticks.map(t.fmt);"
        labels = page.execute_script(script, span)
        assert len(labels) >= 2 and len(set(labels)) == len(labels), (what, labels)
    drift = wait_for("the drift plot drawn", lambda: js(page, "return window.rita.driftTicks"), 10)
    assert len(drift["x"]) >= 2 and len(set(drift["x"])) == len(drift["x"]), drift


def test_a_page_that_never_asks_gets_one_frame_but_all_telemetry(session, robot):
    """A slow browser loses frames, never state: the console pushes state to a tab that stopped pulling."""
    import asyncio

    import aiohttp

    async def stalled_tab() -> tuple[int, int, set[str]]:
        frames, states, topics = 0, 0, set()
        async with aiohttp.ClientSession() as http:
            async with http.ws_connect(session[0].at("ws")) as ws:
                await ws.send_json({"op": "view", "width": 64, "fps": 30})
                end = time.monotonic() + 3.0
                while time.monotonic() < end:
                    try:
                        msg = await ws.receive(timeout=1.0)
                    except asyncio.TimeoutError:
                        continue
                    if msg.type == aiohttp.WSMsgType.BINARY:
                        frames += 1  # and never "next": a tab that cannot keep up
                    elif msg.type == aiohttp.WSMsgType.TEXT and (m := msg.json())["type"] == "state":
                        states += 1
                        topics |= set(m["topics"])
        return frames, states, topics

    robot["client"].call("camera.stream.start")
    try:
        frames, states, topics = asyncio.run(stalled_tab())
        drawn0 = js(session[1], "return window.rita.framesDrawn")
        wait_for("the other tab still gets frames", lambda: js(session[1], "return window.rita.framesDrawn") > drawn0, 5)
    finally:
        robot["client"].call("camera.stream.stop")
    assert frames == 1, frames
    assert states >= 10 and {"robot.state", "daemon.health"} <= topics, (states, topics)


def test_another_site_may_not_open_the_websocket(session):
    import urllib.error
    import urllib.request

    req = urllib.request.Request(session[0].at("ws"), headers={
        "Origin": "http://evil.example", "Connection": "Upgrade", "Upgrade": "websocket",
        "Sec-WebSocket-Version": "13", "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ=="})
    with pytest.raises(urllib.error.HTTPError) as exc:
        urllib.request.urlopen(req, timeout=10)
    assert exc.value.code == 403


def test_second_tab_works_and_a_page_reconnects_after_the_console_restarts(robot, page):
    from tools.harness.browser import ConsoleProcess

    first = ConsoleProcess(["--endpoint", robot["ritad"].endpoint], robot["tmp"] / "restart")
    port = first.base.rsplit(":", 1)[1].strip("/")
    original = page.current_window_handle
    page.switch_to.new_window("tab")
    try:
        page.get(first.url)
        wait_for("the second tab connected", lambda: js(page, "return window.rita.connects") == 1, 20)
        first.stop()  # the link drops
        wait_for("the page saw it", lambda: "lost" in text(page, "link"), 10)
        second = ConsoleProcess(["--endpoint", robot["ritad"].endpoint], robot["tmp"] / "restart2", port=int(port),
                                token=first.token)  # the same token: the open page's cookie still fits
        try:
            wait_for("the page reconnected by itself", lambda: js(page, "return window.rita.connects") == 2, 20)
            wait_for("state flows again", lambda: text(page, "link") == "robot link up", 10)
        finally:
            second.stop()
    finally:
        page.close()
        page.switch_to.window(original)


def test_viewer_key_page_has_no_enabled_control(page, robot):
    args = ["--endpoint", robot["ritad"].endpoints[1], "--keys", str(robot["laptop"]), "--key", "vic"]
    with console_session(args, robot["tmp"] / "viewer") as (_, drv):
        assert js(drv, "return window.rita.role") == "viewer"
        assert drv.find_element("id", "viewer-note").is_displayed()
        enabled = js(drv, """return [...document.querySelectorAll('button, input, select, textarea')]
            .filter(e => !e.classList.contains('view') && !e.disabled).map(e => e.id || e.outerHTML.slice(0, 60));""")
        assert enabled == ["stop"]  # stopping is never forbidden; every other control is
        c: Client = robot["client"]
        if c.call("state")["latch"]["latched"]:
            c.call("robot.release")
        c.call("robot.move", distance_mm=300.0, speed_mm_s=1.0, confirm=True, wait=False)
        wait_for("the robot moving", lambda: c.call("robot.status")["state"] == "MOVING", 10)
        drv.find_element("id", "stop").click()
        idle = _stopped(c)
        assert "vic (viewer)" in c.call("state")["latch"]["by"]
        wait_for("the latch shown", lambda: "STOPPED (latched by" in text(drv, "latch"), 5)
        assert not drv.find_element("id", "release").is_enabled()  # a viewer may stop, not release
        after = c.call("robot.status")
        assert (after["x_mm"], after["y_mm"]) == (idle["x_mm"], idle["y_mm"]), "the robot moved after STOP"
        c.call("robot.release")
        # it still sees everything: telemetry arrives
        wait_for("robot state shown", lambda: text(drv, "robot-state") not in ("", "?"), 10)


def test_reload_shows_the_latest_result_with_working_links_and_stale_marks_need_a_silent_daemon(page, session):
    """After a reload (or in a second tab) the links name data-dir paths (never `/files//tmp/...`) and answer."""
    import urllib.request

    con, _ = session
    page.get(con.url)
    wait_for("the page connected again", lambda: js(page, "return window.rita.role") != "unknown", 20)
    wait_for("the latest result", lambda: page.find_element("id", "result").is_displayed(), 20)
    assert wait_for("its plot drawn", lambda: plot_pixels(page) > 200, 10)
    results = js(page, "return [...document.querySelectorAll('#result-files a')].map(a => a.href)")
    assert results and all("/files//" not in h and "/list//" not in h for h in results), results
    for h in results:
        assert urllib.request.urlopen(con.at(h.split("/", 3)[3]), timeout=30).status == 200, h
    # one read of the history's and the active calibration's links: the history may be redrawn between two
    links = ("return document.querySelector('#history a') && "
             "[...document.querySelectorAll('#history a, #calib-active a')].map(a => a.href)")
    hrefs = wait_for("results listed", lambda: js(page, links), 20)
    assert hrefs and all("/files//" not in h and "/list//" not in h for h in hrefs), hrefs
    for h in hrefs[:6]:
        path = h.split("/", 3)[3]
        assert urllib.request.urlopen(con.at(path), timeout=30).status == 200, h
    assert not page.find_element("id", "robot-panel").get_attribute("class").count("stale")  # the daemon talks
