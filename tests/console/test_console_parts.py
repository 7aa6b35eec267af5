"""The console's pieces without a browser: frame pictures and `ritactl console` errors."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from daemon.bus.png_write import frame_png
from daemon.ctl.main import main as ritactl


def decode(png: bytes) -> np.ndarray:
    img = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    assert img is not None, "not a PNG OpenCV can read"
    return img


def frame(h: int = 300, w: int = 401, dtype: str = "|u1") -> tuple[dict, np.ndarray]:
    rng = np.random.default_rng(7)
    img = rng.integers(0, 255 if dtype == "|u1" else 65535, (h, w), endpoint=True).astype(np.dtype(dtype))
    return {"shape": [h, w], "dtype": dtype}, img


@pytest.mark.parametrize("shape, dtype", [((30, 40), "<u2"), ((30, 40, 3), "|u1"), ((30, 40), "|u1")])
def test_capture_png_keeps_the_frame_depth_and_channels(shape, dtype):
    """The console's Capture and `ritactl camera capture --out` write the frame as it came (lossless)."""
    img = np.random.default_rng(1).integers(0, 4096 if dtype == "<u2" else 256, shape).astype(np.dtype(dtype))
    png = frame_png({"shape": list(shape), "dtype": dtype}, img.tobytes())
    back = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    if back.ndim == 3:
        back = cv2.cvtColor(back, cv2.COLOR_BGR2RGB)
    assert back.dtype == img.dtype and np.array_equal(back, img)


def test_console_without_a_daemon_exits_3_without_traceback(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("RITA_CONFIG", str(tmp_path / "none.toml"))
    (tmp_path / "none.toml").write_text("")
    code = ritactl(["--endpoint", f"ipc://{tmp_path}/nobody", "--timeout", "0.5", "console", "--port", "0"])
    err = capsys.readouterr().err
    assert code == 3 and "no answer" in err and "Traceback" not in err


def test_console_bad_port_is_a_usage_error(capsys):
    assert ritactl(["console", "--port", "70000"]) == 64
    assert "70000" in capsys.readouterr().err


def test_camera_preview_is_a_small_jpeg_of_the_newest_streamed_frame(tmp_path):
    import time

    from daemon.bus.protocol import CommandError
    from tests.ritad_up import ritad_in_process

    with ritad_in_process(tmp_path, camera="sim:?size=400x300&noise=0&fps=20") as (_, c):
        with pytest.raises(CommandError, match="camera.stream.start first"):
            c.call("camera.preview")
        c.call("camera.stream.start")
        try:
            end = time.monotonic() + 10
            while True:
                try:
                    meta, parts = c.call_raw("camera.preview", {"width": 100})
                    break
                except CommandError:
                    assert time.monotonic() < end, "no preview within 10 s of stream start"
                    time.sleep(0.05)
            img = decode(parts[0].bytes)
            assert (meta["step"], meta["out_w"], meta["out_h"]) == (4, 100, 75) and img.shape == (75, 100)
            assert img.std() > 5  # a picture, not a blank
            roi, parts = c.call_raw("camera.preview", {"roi_x": 350, "roi_y": 0, "roi_w": 100, "roi_h": 40})
            assert (roi["x"], roi["w"], roi["h"], roi["step"]) == (350, 50, 40, 1)
            assert decode(parts[0].bytes).shape == (40, 50)
            c.call("camera.stream.stop")  # the last frame stays the newest
            time.sleep(0.3)
            newest = c.call("camera.preview")["header"]["frame_id"]
            assert c.call("camera.preview", after=newest) == {"unchanged": True, "frame_id": newest}
            assert "header" in c.call("camera.preview", after=newest + 1000)  # ids counting again: a picture
        finally:
            c.call("camera.stream.stop")


def _detect_when_streaming(c, args: dict, timeout: float = 20.0) -> dict:
    import time

    from daemon.bus.protocol import CommandError

    end = time.monotonic() + timeout
    while True:
        try:
            return c.call_raw("camera.detect", args, timeout)[0]
        except CommandError as exc:  # not_found until the first streamed frame
            assert exc.code == "not_found" and "stream" in str(exc) and time.monotonic() < end, exc
            time.sleep(0.1)


def test_camera_detect_finds_the_plate_corners_in_sensor_pixels(tmp_path):
    """camera.detect on the robot standing on the plate: the product's detector, the installer's
    plate file."""
    from daemon.bus.protocol import CommandError
    from tests.ritad_up import ritad_in_process

    with ritad_in_process(tmp_path, camera="sim:?size=1000x750&noise=0&fps=10") as (_, c):
        c.call("sim.place_robot_on_plate")
        c.call("camera.stream.start")
        try:
            with pytest.raises(CommandError, match="calibration/plate.json"):  # nothing installed: named
                c.call("camera.detect")
            with pytest.raises(CommandError, match="nope.json"):
                c.call("camera.detect", plate_file="sim/nope.json")
            with pytest.raises(CommandError, match="keys"):  # secrets stay private
                c.call("camera.detect", plate_file="keys/server.key_secret")
            full = _detect_when_streaming(c, {"plate_file": "sim/plate.json"})
            half = c.call("camera.detect", plate_file="sim/plate.json", width=500)
            dot = c.call("camera.detect", target="dot")
        finally:
            c.call("camera.stream.stop")
    assert (full["full_w"], full["full_h"], full["searched_w"]) == (1000, 750, 1000)
    assert half["searched_w"] == 500
    assert full["found"] and full["n"] > 30 and len(full["uv"]) == len(full["ids"]) == full["n"]
    uv = np.array(full["uv"])
    assert (uv[:, 0] >= 0).all() and (uv[:, 0] < 1000).all()
    assert (uv[:, 1] >= 0).all() and (uv[:, 1] < 750).all()
    # corners seen at both sizes are the same points in sensor pixels (the half-size search is coarser)
    common = {i: p for i, p in zip(half["ids"], half["uv"])}
    d = [np.hypot(*(np.array(p) - common[i])) for i, p in zip(full["ids"], full["uv"]) if i in common]
    assert len(d) > 10 and np.median(d) < 1.5, (len(d), np.median(d) if d else None)
    # no mark under the camera on the plate: found or not, no error
    assert "found" in dot and dot["target"] == "dot"


def test_camera_detect_runs_one_at_a_time_and_scales_back_to_sensor_pixels(tmp_path):
    """Directly on the handler: a second request while one runs is busy; a downscaled search
    answers sensor px."""
    from calibration.target import detect_corners, make_board
    from daemon.bus.protocol import CommandError
    from daemon.ritad.detect import Detections
    from daemon.ritad.server import Request
    from drivers.base import Frame
    from fakes.world import World

    plate = World().plate()  # the design the simulated installer hands over
    (tmp_path / "plate.json").write_text(json.dumps(plate.to_dict()))
    # a camera-sized part
    img = make_board(plate).generateImage((2000, 1500), marginSize=0)[300:750, 400:1000].copy()
    det = Detections(lambda: Frame(img, 7, "sim", "Mono8"), tmp_path)

    def req(**a):
        return Request(1, "camera.detect", {"target": "plate", "plate_file": "plate.json", "width": None,
                                            "size_px": None, **a}, "test")
    try:
        first = det.handle(req())
        with pytest.raises(CommandError, match="already running") as busy:
            det.handle(req())
        full = first.result(timeout=60)
        half = det.handle(req(width=450)).result(timeout=60)
    finally:
        det.close()
    assert busy.value.code == "busy" and half["searched_w"] == 450 and full["searched_w"] == 600
    ids, uv = detect_corners(img, plate)
    assert full["n"] == len(ids) > 30 and np.allclose(full["uv"], uv, atol=0.01)
    ref = dict(zip(full["ids"], full["uv"]))
    d = [np.hypot(*(np.array(p) - ref[i])) for i, p in zip(half["ids"], half["uv"]) if i in ref]
    assert len(d) > 30 and np.median(d) < 1.0, (len(d), np.median(d) if d else None)


def test_the_console_holds_a_page_command_in_flight_until_it_ends(tmp_path):
    """asyncio keeps only weak references to tasks: the task of a page's command is held by the console
    while the command runs, and let go when the reply has gone to the page."""
    import asyncio
    import gc
    import threading
    from concurrent.futures import ThreadPoolExecutor

    from daemon.console.server import Console, Tab

    release = threading.Event()
    replies: list[dict] = []

    class Bridge:
        pool = urgent = ThreadPoolExecutor(1)
        role = "operator"

        def call(self, cmd, args, timeout):
            release.wait(10)
            return {"cmd": cmd}

    class Socket:
        closed = False

        async def send_str(self, text):
            replies.append(json.loads(text))

    async def run() -> tuple[int, int]:
        console = Console(Bridge(), tmp_path)
        console._handle(Tab(Socket()), {"op": "call", "id": 7, "cmd": "ping", "args": {}})
        await asyncio.sleep(0.05)
        gc.collect()
        in_flight = len(console._tasks)
        release.set()
        for _ in range(500):
            if replies and not console._tasks:
                break
            await asyncio.sleep(0.01)
        return in_flight, len(console._tasks)

    try:
        in_flight, after = asyncio.run(run())
    finally:
        release.set()
        Bridge.pool.shutdown()
    assert (in_flight, after) == (1, 0)
    assert replies == [{"type": "reply", "id": 7, "ok": True, "result": {"cmd": "ping"}}]
