"""A recording made while a procedure drives the robot and the tracker streams at 1 kHz.

ritad runs in-process on the simulated world (small camera, streaming); ``ritactl record`` runs
in a thread for a few seconds while the worker's own Navigator (the code the procedures move
with) drives and turns for a posted measure-mark job. (Its stationary ``tracker.measure`` is
refused while the tracker streams, so the steps are the motions alone.) The file is then read
with the mcap library: it validates, every tracker record is there with device times one stream
period apart, frames are present, and each of the procedure's motions is there as a
``daemon.command`` pair with its reply.
"""
from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from daemon.bus.names import Topic
from daemon.ctl import main as ctl
from daemon.ctl import mcapfile as fmt
from daemon.ctl.exitcodes import Exit
from daemon.worker.job import JobContext
from daemon.worker.nav import Navigator
from fakes.operator import lock_on_robot
from tests.ritad_up import SMALL_CAMERA, ritad_in_process
from tools.harness.load import hang_s

pytestmark = pytest.mark.timeout(120)
PERIOD_US = 1000  # the stream's 1 kHz
RECORD_S = hang_s(4 / 3)  # 4 s at the default load factor: outlasts the ~1 s procedure on a busy machine


def _procedure(c, data: Path) -> None:
    job = c.call("calib.start", procedure="measure-mark", params={"mark_xy": [0.0, 0.0]})["job"]  # no worker
    ctx = JobContext(c, {"job": job, "procedure": "measure-mark", "params": {"mark_xy": [0.0, 0.0]}}, data)
    nav = Navigator(ctx)  # the declared default speed, 100 mm/s
    nav.move(30.0)  # a heading probe's out and back, then a turn and a drive
    nav.move(-30.0)
    nav.turn(5.0)
    nav.move(40.0)


def test_recording_during_a_procedure_has_every_record_frames_and_the_motions(tmp_path: Path) -> None:
    out = tmp_path / "proc.mcap"
    with ritad_in_process(tmp_path / "rt", tmp_path / "data", timeout=30,
                          camera=SMALL_CAMERA + "&fps=10") as (d, c):
        lock_on_robot(c)
        c.call("tracker.stream.start", rate_hz=1000.0)
        c.call("camera.stream.start")
        result: list[int] = []
        rec = threading.Thread(target=lambda: result.append(ctl.main(
            ["--endpoint", d.server.endpoints[0], "record", "--out", str(out),
             "--duration", f"{RECORD_S:.2f}",
             "--frames", "every", "1"])), daemon=True)
        rec.start()
        end = time.monotonic() + 20
        while not (tmp_path / ".proc.mcap.partial").exists() and time.monotonic() < end:
            time.sleep(0.02)
        time.sleep(0.3)  # subscribed
        _procedure(c, tmp_path / "data")
        recording = rec.is_alive()
        rec.join(hang_s(30))
        c.call("tracker.stream.stop")
        c.call("camera.stream.stop")
    assert result == [Exit.OK] and recording  # the procedure ended inside the recording (its motions below)

    with open(out, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        msgs = [(fmt.bus_topic(ch.topic), sch, m)
                for sch, ch, m in reader.iter_messages(log_time_order=False)]
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == len(msgs)
        ended = {md.name: md.metadata for md in reader.iter_metadata()}[fmt.END_METADATA_NAME]
    assert ended["ended"] == "duration"

    points = [json.loads(m.data) for t, _, m in msgs if t == Topic.TRACKER_POINT]
    gaps = [(a["seq"], a["n"], b["seq"]) for a, b in zip(points, points[1:]) if a["seq"] + a["n"] != b["seq"]]
    assert not gaps and sum(p["n"] for p in points) >= 2000, gaps[:3]  # ~4 s at 1 kHz, no record missing
    device_us = [s * 1_000_000 + us for p in points for s, us in zip(*p["device_time"])]
    steps = {b - a for a, b in zip(device_us, device_us[1:])}
    assert steps == {PERIOD_US}, sorted(steps)[:5]  # continuous at the stream's period

    frames = [m for t, _, m in msgs if t == fmt.FRAME_TOPIC]
    assert len(frames) >= 10 and len(frames) == sum(t == fmt.FRAME_HEADER_TOPIC for t, _, _ in msgs)

    commands = [(json.loads(m.data), sch, m) for t, sch, m in msgs if t == Topic.DAEMON_COMMAND]
    motions = [(r["cmd"], r["args"].get("distance_mm", r["args"].get("angle_deg"))) for r, _, _ in commands
               if r["cmd"] in ("robot.move", "robot.turn")]
    assert motions == [("robot.move", 30.0), ("robot.move", -30.0), ("robot.turn", 5.0), ("robot.move", 40.0)]
    assert [r["cmd"] for r, _, _ in commands][0] == "calib.start"
    for r, sch, m in commands:  # the nulls are left out (the schema types them), the rest is there
        assert r["ok"] is True and "code" not in r and r["role"] == "operator" and "key" not in r
        assert r["recv_ns"] <= r["reply_ns"] and m.log_time >= r["reply_ns"]  # published after the reply
        assert sch.encoding == "jsonschema"
        assert json.loads(sch.data)["properties"] == fmt.COMMAND_SCHEMA["properties"]
        assert set(fmt.restore_nulls(r, fmt.COMMAND_SCHEMA)) == set(fmt.COMMAND_SCHEMA["properties"]) | {"id"}
