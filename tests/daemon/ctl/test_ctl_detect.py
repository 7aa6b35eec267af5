"""``ritactl camera detect`` (camera.detect through the command table's cli words) against a
simulated ritad."""
from __future__ import annotations

import json
import time

import cv2
import numpy as np

from daemon.bus.protocol import CommandError
from daemon.ctl.main import main as ritactl
from tests.ritad_up import ritad_in_process


def test_camera_detect_prints_the_corner_count_and_json_and_fails_clearly(tmp_path, capsys):
    with ritad_in_process(tmp_path, camera="sim:?size=1000x750&noise=0&fps=10") as (d, c):
        ep = ["--endpoint", d.server.endpoints[0]]
        # no stream yet: refused
        assert ritactl([*ep, "camera", "detect", "--plate-file", "sim/plate.json"]) == 4
        err = capsys.readouterr().err
        assert "camera.stream.start first" in err and "Traceback" not in err
        c.call("sim.place_robot_on_plate")
        c.call("camera.stream.start")
        try:
            end = time.monotonic() + 10
            while True:  # until the first streamed frame
                try:
                    c.call("camera.preview", width=16)
                    break
                except CommandError:
                    assert time.monotonic() < end, "no streamed frame within 10 s"
                    time.sleep(0.05)
            assert ritactl([*ep, "camera", "detect", "--plate-file", "sim/plate.json", "--width", "640"]) == 0
            text = capsys.readouterr().out
            assert ritactl([*ep, "--json", "camera", "detect", "--plate-file", "sim/plate.json",
                            "--width", "640"]) == 0
            doc = json.loads(capsys.readouterr().out)
            assert ritactl([*ep, "camera", "detect", "--plate-file", "sim/none.json"]) == 4
            missing = capsys.readouterr().err
        finally:
            c.call("camera.stream.stop")
    assert doc["target"] == "plate" and doc["found"] and doc["n"] > 30 and len(doc["uv"]) == doc["n"]
    words = text.split()  # another frame than the --json call's: its own count, shown first
    assert int(words[0]) > 30 and words[1:5] == ["corners", "of", "plate", doc["plate_id"]], text
    assert "searched 640×480 of 1000×750 px" in text
    assert "sim/none.json" in missing


def test_camera_detect_bad_width_is_a_usage_error(capsys):
    assert ritactl(["camera", "detect", "--width", "10"]) == 64
    assert "--width" in capsys.readouterr().err


def test_mark_detection_answers_one_point_and_ritactl_prints_it(capsys):
    """The dot's position is [u, v] in sensor px (docs/protocol.md), also from a downscaled search."""
    import argparse

    from daemon.ctl.device import cmd_device
    from daemon.ritad.detect import Detections
    from daemon.ritad.server import Request
    from drivers.base import Frame

    img = np.full((200, 300), 220, np.uint8)
    cv2.circle(img, (150, 100), 10, 30, -1)  # a dark dot, radius 10 px, centred on pixel (150, 100)
    det = Detections(lambda: Frame(img, 3, "sim", "Mono8"), "/nonexistent")
    try:
        r = det.handle(Request(1, "camera.detect", {"target": "dot", "plate_file": "unused", "width": 150,
                                                    "size_px": None}, "test")).result(timeout=30)
    finally:
        det.close()
    assert r["found"] and np.allclose(r["uv"], [150, 100], atol=0.2), r

    class Fake:  # the daemon's answer, through ritactl's printing
        def call_raw(self, cmd, args, timeout=None):
            return (r if args.get("target") == "dot" else {**r, "target": "cross", "found": False,
                                                                            "message": "no cross found"}), []

    for target, code in (("dot", 0), ("cross", 2)):
        a = argparse.Namespace(command="camera.detect", arg_target=target, timeout=None, json=False)
        assert cmd_device(Fake(), a) == code
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("dot mark at u 150.0") and out[1].startswith("no cross mark found")
