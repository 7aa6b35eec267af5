"""ritactl watch: a compact status line (not raw JSON), --json per message, --frames with a hint.

Unit tests fold hand-made telemetry into ``LiveStatus`` and drive ``Screen`` with a fake
clock; live tests run ``ritactl watch`` in-process against a sim daemon while the tracker
streams at 200 Hz, and check the output stays a few lines.
"""
from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Iterator

import pytest

from daemon.ctl import main as ctl
from daemon.bus.client import Client
from daemon.ctl.watch import NO_FRAMES, LiveStatus, Screen
from fakes.operator import lock_on_robot
from daemon.ritad.daemon import Daemon
from tests.ritad_up import SMALL_CAMERA, ritad_in_process


def health(uptime: float, frames: int, state: str = "READY") -> dict:
    return {"uptime_s": uptime, "frames": {"sent": frames},
            "devices": {k: {"state": state} for k in ("tracker", "robot", "camera")}}


def test_status_line_folds_telemetry() -> None:
    s = LiveStatus()
    assert s.update("daemon.health", health(10.0, 100)) is None
    s.update("daemon.health", health(12.0, 110))
    s.update("tracker.event", {"event": "status_change", "change_name": "MeasStatus_NotReady"})
    assert "no lock" in s.line() and "no point yet" in s.line()
    s.update("tracker.point", {"n": 2, "x": [1.0, 2800.1234], "y": [2.0, -2500.5], "z": [3.0, -830.25]})
    s.update("robot.state", {"state": "MOVING", "x_mm": 12.34, "y_mm": -5.0, "heading_deg": 90.0,
                             "roll_deg": 0.012, "pitch_deg": -0.034, "battery_v": 25.2})
    s.update("calib.progress", {"job": "J1", "step": "run0: drive 200 mm", "percent": 50.0,
                                "waiting_for": "robot moving"})
    line = s.line()
    assert "tracker READY locked (2800.123, -2500.500, -830.250) mm" in line
    assert "robot READY MOVING x 12.3 y -5.0 hdg 90.0° tilt 0.012/-0.034°" in line
    assert "camera READY 5.0 fps" in line  # 10 frames in 2 s of uptime
    assert "job J1 50% run0: drive 200 mm (robot moving)" in line
    assert "J1" in s.update("calib.prompt", {"job": "J1", "question": "put the SMR in red", "choices": ["ok"]})
    assert "verdict ok" in s.update("calib.result", {"job": "J1", "procedure": "referencing", "verdict": "ok"})
    assert "job" not in s.line()
    assert "FAILED: boom" in s.update("calib.result", {"job": "J2", "failed": True, "message": "boom"})
    assert s.update("log", {"level": "WARNING", "message": "disk 90% full"}) == "WARNING: disk 90% full"
    assert "FAULT: port gone" in s.update("daemon.state", {"device": "robot", "state": "FAULT",
                                                           "reason": "port gone"})
    assert "robot FAULT" in s.line()
    s.update("robot.state", {"state": "IDLE", "x_mm": 0.0, "y_mm": 0.0, "heading_deg": 0.0,
                             "roll_deg": None, "pitch_deg": None})
    assert "tilt n/a" in s.line()


class Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_status_line_shows_a_struggling_camera_link() -> None:
    s = LiveStatus()
    assert "link" not in s.line()
    s.update("camera.link", {"serial": "X", "resend_requests": 40, "lost_packets": 3, "incomplete_frames": 2,
                             "lost_frames": None, "source": {}})
    assert "link: 2 incomplete, 3 packets lost, 40 resends" in s.line()
    s.update("camera.link", {"resend_requests": None, "lost_packets": 1, "incomplete_frames": 2})
    assert "link: 2 incomplete, 1 packets lost, ? resends" in s.line()


def test_screen_redraws_in_place_on_a_tty_and_prints_changes_otherwise(monkeypatch) -> None:
    out = io.StringIO()
    scr = Screen(out, tty=False)
    for t, text in ((0.0, "a"), (0.1, "b"), (0.5, "b"), (1.2, "b"), (1.3, "c"), (2.4, "c")):
        scr.status(text, t)
    scr.event("WARNING: x")
    scr.status("c", 3.5)
    # a change is printed at most once a second, an unchanged status never again
    assert out.getvalue() == "a\nb\nc\nWARNING: x\n"
    tty = Tty()
    scr = Screen(tty, tty=True)
    scr.status("a", 0.0)
    scr.status("b", 0.3)
    scr.event("job J1 finished")
    scr.status("b", 0.6)
    scr.close()
    assert tty.getvalue() == "\r\x1b[Ka\r\x1b[Kb\r\x1b[Kjob J1 finished\n\r\x1b[Kb\n"
    monkeypatch.setenv("COLUMNS", "20")
    narrow = Tty()
    Screen(narrow, tty=True).status("x" * 50, 0.0)
    assert narrow.getvalue() == "\r\x1b[K" + "x" * 18 + "…"  # never wraps, so it can be redrawn


@pytest.fixture
def live(tmp_path: Path) -> Iterator[tuple[Daemon, Client, str]]:
    with ritad_in_process(tmp_path / "rt", tmp_path / "data", timeout=30, camera=SMALL_CAMERA + "&fps=20") as (d, c):
        yield d, c, d.server.endpoints[0]


def test_watch_is_a_few_status_lines_while_the_tracker_streams(live, capsys) -> None:
    d, c, ep = live
    lock_on_robot(c)
    c.call("tracker.stream.start", rate_hz=200.0)
    try:
        assert ctl.main(["--endpoint", ep, "watch", "--duration", "3"]) == 0
        lines = capsys.readouterr().out.splitlines()
        assert 1 <= len(lines) <= 5, lines  # one per second at most, not one per message
        assert not any(ln.lstrip().startswith("{") for ln in lines), lines
        assert "locked (" in lines[-1] and "robot READY IDLE" in lines[-1], lines[-1]
        for argv in (["--json", "watch", "--duration", "1.5"], ["watch", "--json", "--duration", "1.5"]):
            assert ctl.main(["--endpoint", ep, *argv]) == 0
            msgs = [json.loads(ln) for ln in capsys.readouterr().out.splitlines()]
            points = [m for m in msgs if m["topic"] == "tracker.point" and not m.get("snapshot")]
            assert len(points) >= 5 and all("seq" in m and "data" in m for m in msgs)
            seqs = [m["seq"] for m in msgs if not m.get("snapshot")]
            assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)  # no update twice, none before the state
        assert ctl.main(["--endpoint", ep, "--json", "watch", "--duration", "0"]) == 0
        now = {m["topic"]: m for m in map(json.loads, capsys.readouterr().out.splitlines())}
        # the current state (no daemon.health here: the in-process daemon runs no supervisor)
        assert now["robot.state"]["snapshot"] and now["tracker.point"]["data"]["n"] >= 1
    finally:
        c.call("tracker.stream.stop")


def test_watch_frames_says_how_to_start_the_stream(live, capsys) -> None:
    d, c, ep = live
    assert ctl.main(["--endpoint", ep, "watch", "--frames", "--duration", "2.5"]) == 0
    out = capsys.readouterr().out
    assert NO_FRAMES in out and "nan" not in out
    c.call("camera.stream.start")
    try:
        assert ctl.main(["--endpoint", ep, "watch", "--frames", "--duration", "2.5"]) == 0
        out = capsys.readouterr().out
        assert "frames " in out and "latency p50" in out and "nan" not in out, out
    finally:
        c.call("camera.stream.stop")
