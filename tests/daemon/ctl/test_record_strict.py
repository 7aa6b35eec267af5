"""A live recording read by strict, independent tools (issue 35, Acceptance).

ritad --sim runs in-process; ``ritactl record`` records 20 s of it with frames (tracker at 1 kHz,
camera at 10 fps, a motion, commands accepted and refused). The file is read with the ``mcap``
library's reader (``make_reader``, CRCs on) and nothing of the project's reading code:

* every JSON message validates with ``jsonschema`` against its channel's schema, and every
  ``foxglove.*`` channel carries Foxglove's published schema byte for byte (the vendored copy,
  daemon/ctl/foxglove_schemas, from foxglove-sdk) and its messages validate against it;
* every image is decoded by the ROS 2 CDR decoder of ``mcap-ros2-support`` and validates against
  Foxglove's published RawImage.json (its bytes as the base64 string the JSON form has);
* each channel's sequences run 1, 2, 3 … with no gap;
* each message's log time is its sample's own time, within 1 ms: the exposure's mid-time for a
  frame (``t_ns`` of its header), the STATUS's time for ``/robot/state``, the last sample's for a
  batch, the ``timestamp`` of a Foxglove message;
* the metadata states the simulator's time scale.
"""
from __future__ import annotations

import base64
import contextlib
import json
import logging
import threading
import time
from pathlib import Path
from typing import Any, Iterator

import jsonschema
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from daemon.bus.protocol import CommandError
from daemon.ctl import main as ctl
from daemon.ctl.exitcodes import Exit
from daemon.ctl.foxglove_schemas import schema, schema_bytes
from daemon.ritad.logs import BusLogHandler
from fakes.operator import lock_on_robot
from tests.ritad_up import SMALL_CAMERA, ritad_in_process
from tools.harness.load import hang_s

pytestmark = pytest.mark.timeout(180)
SECONDS = 20
TOLERANCE_NS = 1_000_000


@contextlib.contextmanager
def _journal_on_the_bus(d: Any) -> Iterator[None]:
    """ritad's warnings on the bus's ``log`` topic, as its main() sets up (in-process: for this test only)."""
    handler = BusLogHandler(d.telemetry.publish)
    logging.getLogger().addHandler(handler)
    try:
        yield
    finally:
        logging.getLogger().removeHandler(handler)


def _record(tmp_path: Path, out: Path) -> None:
    camera = SMALL_CAMERA + "&fps=10"
    with ritad_in_process(tmp_path / "rt", tmp_path / "data", timeout=30, camera=camera) as (d, c), \
            _journal_on_the_bus(d):
        lock_on_robot(c)
        result: list[int] = []
        rec = threading.Thread(target=lambda: result.append(ctl.main(
            ["--endpoint", d.server.endpoints[0], "record", "--out", str(out), "--duration", str(SECONDS),
             "--frames", "every", "1"])), daemon=True)
        rec.start()
        end = time.monotonic() + hang_s(20)
        while not (out.parent / f".{out.name}.partial").exists() and time.monotonic() < end:
            time.sleep(0.02)
        time.sleep(0.3)  # subscribed
        # accepted (key, code and message null), at the fake's max_data_rate 1000 Hz: ritad's journal
        # warns that 2000 Hz was asked for, which the recording has as a foxglove.Log
        assert c.call("tracker.stream.start", rate_hz=2000.0)["rate_hz"] == 1000.0  # the rate streamed
        c.call("camera.stream.start")
        with pytest.raises(CommandError):
            c.call("robot.move", distance_mm="far")  # refused: code and message filled
        c.call("robot.move", distance_mm=100.0, confirm=True, timeout=30)  # the pose changes
        rec.join(hang_s(SECONDS + 30))
        c.call("tracker.stream.stop")
        c.call("camera.stream.stop")
    assert result == [Exit.OK]


def _sample_ns(topic: str, data: Any) -> int | None:
    """The sample time a message states, read from its own fields (None: a message without one)."""
    if "timestamp" in data:  # Foxglove's messages
        return int(data["timestamp"]["sec"]) * 1_000_000_000 + int(data["timestamp"]["nsec"])
    t = data.get("t_ns", data.get("host_time_ns"))
    if isinstance(t, list):  # a batch: logged at its last sample
        return int(t[-1])
    return int(t) if t is not None else None


def _image_as_json(msg: Any) -> dict[str, Any]:
    """A decoded ROS 2 RawImage in Foxglove's JSON form (timestamp sec/nsec, data base64)."""
    return {"timestamp": {"sec": msg.timestamp.sec, "nsec": msg.timestamp.nanosec}, "frame_id": msg.frame_id,
            "width": msg.width, "height": msg.height, "encoding": msg.encoding, "step": msg.step,
            "data": base64.b64encode(bytes(msg.data)).decode()}


def _check(out: Path) -> tuple[dict[str, list[Any]], dict[str, dict[str, str]]]:
    """Every message checked (module docstring); the messages per channel and the metadata."""
    validators: dict[int, Any] = {}
    by_topic: dict[str, list[Any]] = {}
    decoders = DecoderFactory()
    with open(out, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
        for sch, ch, m in reader.iter_messages(log_time_order=False):
            assert sch is not None
            if ch.message_encoding == "cdr":
                assert sch.name == "foxglove_msgs/msg/RawImage" and sch.encoding == "ros2msg"
                decode = decoders.decoder_for("cdr", sch)
                assert decode is not None
                data = _image_as_json(decode(m.data))
                jsonschema.validate(data, schema("RawImage"))
            else:
                assert ch.message_encoding == "json" and sch.encoding == "jsonschema"
                if sch.name.startswith("foxglove."):
                    assert sch.data == schema_bytes(sch.name.removeprefix("foxglove."))  # the published one
                if sch.id not in validators:
                    parsed = json.loads(sch.data)
                    jsonschema.validators.validator_for(parsed).check_schema(parsed)
                    validators[sch.id] = jsonschema.validators.validator_for(parsed)(parsed)
                data = json.loads(m.data)
                errors = [f"{e.json_path}: {e.message}" for e in validators[sch.id].iter_errors(data)]
                assert not errors, (ch.topic, m.sequence, errors[:3])
            assert " " not in ch.topic and "." not in ch.topic and ch.topic.startswith("/")  # no quoting
            by_topic.setdefault(ch.topic, []).append((m, data))
    return by_topic, meta


def test_a_20_s_sim_recording_with_frames_passes_the_independent_check(tmp_path: Path) -> None:
    out = tmp_path / "strict.mcap"
    _record(tmp_path, out)
    by_topic, meta = _check(out)
    for topic, msgs in by_topic.items():
        assert [m.sequence for m, _ in msgs] == list(range(1, len(msgs) + 1)), topic
    timed = ("/camera/frame", "/camera/frame/header", "/robot/state", "/robot/odometry", "/robot/incl",
             "/robot/event", "/tracker/point",
             "/tracker/pose", "/robot/pose", "/log")
    for topic in timed:
        for m, data in by_topic.get(topic, []):
            t = _sample_ns(topic, data)
            assert t is not None and abs(m.log_time - t) <= TOLERANCE_NS, (topic, m.sequence, m.log_time, t)
    headers = [d for _, d in by_topic["/camera/frame/header"]]
    assert len(headers) >= 5 * SECONDS // 2 and len(by_topic["/camera/frame"]) == len(headers)
    # a frame is logged at its exposure, not its arrival (ritad's header says both)
    assert all(h["t_ns"] < h["host_time_ns"] for h in headers)
    records = sum(sum(1 for s in d["status"] if s == 0) for _, d in by_topic["/tracker/point"])
    assert records >= 1000 * SECONDS // 4
    assert len(by_topic["/tracker/pose"]) == records  # one message a record
    warnings = [d for _, d in by_topic["/log"] if "max_data_rate" in d["message"]]
    assert warnings and warnings[0]["level"] == 3 and warnings[0]["name"].startswith("drivers.emscon")
    xs = {round(d["pose"]["position"]["x"], 4) for _, d in by_topic["/robot/pose"]}
    assert len(xs) >= 2  # the robot moved, and its pose says so
    commands = [d for _, d in by_topic["/daemon/command"]]
    refused = [r for r in commands if r["cmd"] == "robot.move" and not r["ok"]]
    assert refused and isinstance(refused[0]["code"], str)
    accepted = [r for r in commands if r["cmd"] == "tracker.stream.start"]
    assert accepted and accepted[0]["ok"] is True and "code" not in accepted[0]  # its null left out
    info = meta["ritactl.record"]
    assert info["sim"] == "true" and info["sim_time_scale_robot"] == "0.02"
    assert info["sim_speedup_robot"] == "50" and info["sim_speedup_tracker"] == "20"
    assert info["frames_format"] == "raw" and meta["ritactl.record.end"]["ended"] == "duration"
