"""The recorder's JSON schemas stay in the subset Foxglove's JSON-schema reader accepts.

``foxglove_refusal`` transcribes the rules of that reader (``parseJsonSchema`` in the open-source
Foxglove Studio's ``packages/mcap-support``, unchanged in its fork Lichtblick 1.10.8): a schema it
refuses makes Foxglove refuse the whole channel ("Error in topic robot.state (channel 1):
Unsupported type undefined for roll_deg"), so its panels show nothing of that topic.
"""
from __future__ import annotations

import io
import json
from pathlib import Path
from typing import Any

from mcap.reader import make_reader

from daemon.bus.names import Topic
from daemon.ctl import mcapfile as fmt
from daemon.ctl.record import Recorder

_SCALARS = ("boolean", "string", "number", "integer")


def foxglove_refusal(schema: dict[str, Any], path: str = "") -> str | None:
    """Foxglove's complaint about ``schema`` (an object schema), None when it reads it."""
    if schema.get("type") != "object":
        return f"Expected \"type\": \"object\" for {path or 'the root'}, got {schema.get('type')!r}"
    for name, field in (schema.get("properties") or {}).items():
        where = f"{path}.{name}" if path else name
        kind = field.get("type")
        if "oneOf" in field:
            if not all(isinstance(alt.get("const"), (int, float)) for alt in field["oneOf"]):
                return f"Unsupported type for {where}: oneOf alternatives must have number values"
        elif kind == "object":
            nested = foxglove_refusal(field, where)
            if nested:
                return nested
        elif kind == "array":
            item = field.get("items") or {}
            if item.get("type") == "object":
                nested = foxglove_refusal(item, where)
                if nested:
                    return nested
            elif (item.get("type") not in _SCALARS
                  or (item.get("type") == "string" and "contentEncoding" in item)):
                return f"Unsupported type {item.get('type')!r} for array item {where}"
        elif kind not in _SCALARS or field.get("contentEncoding", "base64") != "base64":
            return f"Unsupported type {kind!r} for {where}"
    return None


#: first messages as ritad --sim sends them (trimmed), with the fields Foxglove refused before:
#: nulls (no IMU: roll/pitch), arrays of arrays (device times, a pose matrix), an empty array
SAMPLES: dict[str, dict[str, Any]] = {
    "robot.state": {"state": "IDLE", "x_mm": 0.0, "y_mm": 0.0, "heading_deg": 0.0, "roll_deg": None,
                    "pitch_deg": None, "battery_v": 25.2, "fault": "", "host_time_ns": 1795802312082961761},
    "tracker.point": {"n": 2, "x": [2819.3, 2819.4], "y": [-2509.1, -2509.2], "z": [-830.9, -830.9],
                      "status": [0, 0], "device_time": [[34, 34], [5, 6]], "mode": "stream"},
    "camera.frame.header": {"v": 1, "frame_id": 1, "shape": [750, 1000], "sim": True,
                            "sim_abs_H_cam": [[1.0, 0.0], [0.0, 1.0]], "warnings": []},
    "daemon.health": {"uptime_s": 35.5, "latch": {"latched": False, "since_ns": None},
                      "devices": {"camera": {"state": "READY", "info": {"size": [1000, 750], "ids": [[1]]}}},
                      "jobs": [{"id": "a", "done_ns": None, "steps": [["s", 1]]}]},
}


def test_inferred_schemas_are_read_by_foxglove_and_keep_every_typed_field() -> None:
    for topic, data in SAMPLES.items():
        schema = fmt.infer_schema(topic, data)
        assert foxglove_refusal(schema) is None, (topic, foxglove_refusal(schema))
        assert schema["title"] == topic
    robot = fmt.infer_schema("robot.state", SAMPLES["robot.state"])["properties"]
    assert robot["x_mm"] == {"type": "number"} and robot["state"] == {"type": "string"}
    assert "roll_deg" not in robot and "pitch_deg" not in robot  # null: type unknown, left out
    point = fmt.infer_schema("tracker.point", SAMPLES["tracker.point"])["properties"]
    assert point["x"] == {"type": "array", "items": {"type": "number"}} and "device_time" not in point
    header = fmt.infer_schema("camera.frame.header", SAMPLES["camera.frame.header"])["properties"]
    assert "sim_abs_H_cam" not in header and "warnings" not in header and header["sim"] == {"type": "boolean"}
    health = fmt.infer_schema("daemon.health", SAMPLES["daemon.health"])["properties"]
    assert health["latch"]["properties"] == {"latched": {"type": "boolean"}}
    assert health["jobs"]["items"]["properties"] == {"id": {"type": "string"}}
    assert foxglove_refusal(fmt.infer_schema("odd", [1, 2])) is None  # not a map: an empty object


def test_command_schema_is_read_by_foxglove() -> None:
    assert foxglove_refusal(fmt.COMMAND_SCHEMA) is None
    schema = fmt.infer_schema(str(Topic.DAEMON_COMMAND), {"cmd": "robot.move", "key": None})
    assert schema["properties"] == fmt.COMMAND_SCHEMA["properties"]  # fixed, not inferred


def test_a_recording_has_only_channels_foxglove_reads() -> None:
    buf = io.BytesIO()
    rec = Recorder(buf, {"test": "1"}, "none")
    for seq, (topic, data) in enumerate(SAMPLES.items(), start=1):
        rec.telemetry(topic, {"seq": seq, "t_ns": 1000 + seq, "data": data}, 2000 + seq)
    rec.telemetry(str(Topic.DAEMON_COMMAND), {"seq": 9, "t_ns": 1009, "data": {
        "cmd": "robot.move", "id": "x-1", "args": {"distance_mm": 1.0}, "key": None, "role": "operator",
        "ok": True, "code": None, "message": None, "recv_ns": 1, "reply_ns": 2}}, 2009)
    rec.finish()
    summary = make_reader(io.BytesIO(buf.getvalue())).get_summary()
    assert summary is not None
    schemas = [s for s in summary.schemas.values() if s.encoding == "jsonschema"]
    ours = [s for s in schemas if not s.name.startswith("foxglove.")]  # Foxglove's own: the robot's pose
    assert len(ours) == len(SAMPLES) + 1 and {s.name for s in schemas} - {s.name for s in ours} == \
        {"foxglove.PoseInFrame"}
    for s in schemas:
        assert foxglove_refusal(json.loads(s.data)) is None, (s.name, foxglove_refusal(json.loads(s.data)))


def test_typed_nulls_are_left_out_of_messages_and_a_replay_puts_them_back() -> None:
    import jsonschema  # the strict check an independent consumer makes

    buf = io.BytesIO()
    rec = Recorder(buf, {"test": "1"}, "none")
    first = {"x_mm": 1.0, "roll_deg": None, "latch": {"since_ns": 5, "latched": True}}
    later = {"x_mm": None, "roll_deg": 0.5, "latch": {"since_ns": None, "latched": False}}  # NaN became null
    command = {"cmd": "robot.move", "id": 7, "args": None, "key": None, "role": "operator", "ok": False,
               "code": "bad_args", "message": None, "recv_ns": 1, "reply_ns": 2}
    rec.telemetry("robot.state", {"seq": 1, "t_ns": 1, "data": first}, 1)
    rec.telemetry("robot.state", {"seq": 2, "t_ns": 2, "data": later}, 2)
    rec.telemetry(str(Topic.DAEMON_COMMAND), {"seq": 3, "t_ns": 3, "data": command}, 3)
    rec.finish()
    reader = make_reader(io.BytesIO(buf.getvalue()))
    got = [(json.loads(s.data), json.loads(m.data)) for s, _, m in reader.iter_messages()]
    for schema, data in got:
        assert foxglove_refusal(schema) is None
        jsonschema.validate(data, schema)
    assert got[0][1] == first  # roll_deg: null in the first message, so untyped, so kept
    assert got[1][1] == {"roll_deg": 0.5, "latch": {"latched": False}}
    assert got[2][1] == {"cmd": "robot.move", "id": 7, "role": "operator", "ok": False, "code": "bad_args",
                         "recv_ns": 1, "reply_ns": 2}
    assert [fmt.restore_nulls(d, s) for s, d in got] == [first, later, command]


def _decoded_images(buf: bytes) -> list[tuple[Any, Any, Any]]:
    """(schema, channel, decoded CDR message) of each image, by mcap-ros2-support's decoder."""
    from mcap_ros2.decoder import DecoderFactory

    out = []
    for sch, ch, m in make_reader(io.BytesIO(buf)).iter_messages(log_time_order=False):
        if ch.message_encoding == "cdr":
            decode = DecoderFactory().decoder_for("cdr", sch)
            assert decode is not None
            out.append((sch, m, decode(m.data)))
    return out


def test_compressed_frames_are_foxglove_compressed_images_that_decode_to_the_pixels() -> None:
    import base64

    import cv2
    import jsonschema
    import numpy as np

    from daemon.ctl.foxglove_schemas import schema
    from daemon.ctl.replay import _image

    pixels = (np.arange(48 * 64, dtype=np.uint32) % 251).astype(np.uint8).reshape(48, 64)
    header = {"seq": 1, "pixel_format": "Mono8", "shape": [48, 64], "dtype": "|u1",
              "host_time_ns": 5_007_000_000, "t_ns": 5_000_000_123}
    for ff in ("png", "jpeg"):
        buf = io.BytesIO()
        rec = Recorder(buf, {}, "none", frames_format=ff)
        rec.frame(header, pixels.tobytes(), 6_000_000_000)
        rec.finish()
        [(sch, m, img)] = _decoded_images(buf.getvalue())
        assert sch.name == fmt.COMPRESSED_IMAGE_SCHEMA and img.format == ff and m.log_time == header["t_ns"]
        as_json = {"timestamp": {"sec": img.timestamp.sec, "nsec": img.timestamp.nanosec},
                   "frame_id": img.frame_id, "format": img.format,
                   "data": base64.b64encode(bytes(img.data)).decode()}
        jsonschema.validate(as_json, schema("CompressedImage"))  # Foxglove's published schema
        assert (img.timestamp.sec, img.timestamp.nanosec) == (5, 123)  # the exposure's mid-time
        back = cv2.imdecode(np.frombuffer(bytes(img.data), np.uint8), cv2.IMREAD_UNCHANGED)
        err = np.abs(back.astype(int) - pixels.astype(int)).max()
        assert err == 0 if ff == "png" else err < 40  # png lossless; jpeg close
        assert bytes(_image(sch.name, m.data) or b"") == back.tobytes()  # what a replay publishes


def test_the_journal_is_a_foxglove_log_and_a_replay_gets_the_record_back() -> None:
    import jsonschema

    from daemon.ctl import foxglove as fox
    from daemon.ctl.foxglove_schemas import schema, schema_bytes

    buf = io.BytesIO()
    rec = Recorder(buf, {}, "none")
    record = {"level": "ERROR", "logger": "ritad.robot", "message": "base lost", "t": 1795838574.5}
    rec.telemetry("log", {"seq": 1, "t_ns": 1795838574_600_000_000, "data": record}, 1795838574_700_000_000)
    rec.finish()
    [(sch, ch, m)] = list(make_reader(io.BytesIO(buf.getvalue())).iter_messages())
    entry = json.loads(m.data)
    jsonschema.validate(entry, schema("Log"))
    assert (ch.topic, sch.name, sch.data) == ("/log", "foxglove.Log", schema_bytes("Log"))
    assert entry["level"] == 4 and entry["name"] == "ritad.robot"
    assert m.log_time == 1795838574_500_000_000  # the record's own time, not its publishing
    assert fox.log_record(entry) == record


def test_robot_pose_and_tracker_records_are_pose_in_frame_at_their_sample_times() -> None:
    import jsonschema

    from daemon.ctl.foxglove_schemas import schema

    buf = io.BytesIO()
    rec = Recorder(buf, {}, "none")
    rec.telemetry("robot.state", {"seq": 1, "t_ns": 90, "data": {"x_mm": 1000.0, "y_mm": -500.0,
                                                                 "heading_deg": 90.0, "t_ns": 70}}, 95)
    rec.telemetry("tracker.point", {"seq": 2, "t_ns": 99, "data": {
        "n": 3, "x": [1.0, 2.0, 3.0], "y": [0.0] * 3, "z": [0.0] * 3, "status": [0, 1, 0],
        "t_ns": [80, 81, 82],
        "host_time_ns": 98}}, 100)
    rec.finish()
    got = [(ch.topic, m.log_time, m.sequence, json.loads(m.data))
           for _, ch, m in make_reader(io.BytesIO(buf.getvalue())).iter_messages(log_time_order=False)]
    assert [(t, lt, s) for t, lt, s, _ in got] == [("/robot/state", 70, 1), ("/robot/pose", 70, 1),
                                                   ("/tracker/point", 82, 1), ("/tracker/pose", 80, 1),
                                                   ("/tracker/pose", 82, 2)]  # status 1: no pose
    for topic, _, _, data in got:
        if topic.endswith("/pose"):
            jsonschema.validate(data, schema("PoseInFrame"))
    robot = got[1][3]
    assert robot["frame_id"] == "odom" and robot["pose"]["position"] == {"x": 1.0, "y": -0.5, "z": 0.0}
    assert abs(robot["pose"]["orientation"]["z"] - 0.5 ** 0.5) < 1e-12  # 90° about z
    assert got[4][3]["frame_id"] == "tracker" and got[4][3]["pose"]["position"]["x"] == 0.003


def test_the_layout_file_opens_channels_a_recording_has() -> None:
    """docs/foxglove-layout.json names only channels the recorder writes, each by its unquoted name."""
    layout = json.loads((Path(__file__).resolve().parents[3] / "docs" / "foxglove-layout.json").read_text())
    panels = layout["configById"]
    named = {panels["Image!rita"]["imageMode"]["imageTopic"], panels["RosOut!rita"]["topicToRender"],
             panels["RawMessages!rita"]["topicPath"]}
    named |= {p["value"].split(".")[0] for k in ("Plot!rita", "Plot!tracker") for p in panels[k]["paths"]}
    buf = io.BytesIO()
    rec = Recorder(buf, {}, "none")
    rec.telemetry("robot.state", {"seq": 1, "t_ns": 1, "data": SAMPLES["robot.state"]}, 1)
    points = {**SAMPLES["tracker.point"], "t_ns": [1, 2]}
    rec.telemetry("tracker.point", {"seq": 2, "t_ns": 2, "data": points}, 2)
    journal = {"level": "WARNING", "logger": "x", "message": "m", "t": 0.1}
    rec.telemetry("log", {"seq": 3, "t_ns": 3, "data": journal}, 3)
    rec.telemetry("daemon.command", {"seq": 4, "t_ns": 4, "data": {"cmd": "ping", "ok": True}}, 4)
    rec.frame({"seq": 1, "pixel_format": "Mono8", "shape": [2, 2], "dtype": "|u1", "t_ns": 5}, b"\0" * 4, 6)
    rec.finish()
    summary = make_reader(io.BytesIO(buf.getvalue())).get_summary()
    assert summary is not None
    assert named <= {c.topic for c in summary.channels.values()}, named
    assert all('"' not in p["value"] for k in ("Plot!rita", "Plot!tracker") for p in panels[k]["paths"])


def test_replay_reads_an_older_recording_with_dotted_channels(tmp_path: Path) -> None:
    """A file of the layout before issue 35 (channels named as bus topics, ``log`` as ritad sent it)."""
    from mcap.writer import Writer

    from daemon.ctl.replay import ReplayServer, play

    path = tmp_path / "old.mcap"
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        old = (("robot.state", {"x_mm": 3.0}),
               ("log", {"level": "WARNING", "logger": "r", "message": "m", "t": 1.5}),
               (fmt.FRAME_HEADER_TOPIC, {"seq": 1, "shape": [1, 2], "dtype": "|u1"}))
        for n, (topic, data) in enumerate(old, start=1):
            sch = w.register_schema(topic, "jsonschema", fmt.to_json(fmt.infer_schema(topic, data)))
            w.add_message(w.register_channel(topic, "json", sch), log_time=n, data=fmt.to_json(data),
                          publish_time=n, sequence=n)
        image = w.register_schema(fmt.RAW_IMAGE_SCHEMA, "ros2msg", fmt.RAW_IMAGE_ROS2MSG.encode())
        header = {"seq": 1, "pixel_format": "Mono8", "shape": [1, 2], "dtype": "|u1", "host_time_ns": 4}
        w.add_message(w.register_channel(fmt.FRAME_TOPIC, "cdr", image), log_time=4,
                      data=fmt.raw_image(header, b"\x01\x02"), publish_time=4, sequence=4)
        w.finish()
    server = ReplayServer(f"ipc://{tmp_path}/cmd", str(path))
    try:
        with open(path, "rb") as f:
            assert play(server, f, None) == (4, 0)
        assert server.latest["robot.state"]["data"] == {"x_mm": 3.0}
        assert server.latest["log"]["data"]["message"] == "m"
    finally:
        server.close()
