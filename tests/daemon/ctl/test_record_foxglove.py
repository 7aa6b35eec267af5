"""The recorder's JSON schemas stay in the subset Foxglove's JSON-schema reader accepts.

``foxglove_refusal`` transcribes the rules of that reader (``parseJsonSchema`` in the open-source
Foxglove Studio's ``packages/mcap-support``, unchanged in its fork Lichtblick 1.10.8): a schema it
refuses makes Foxglove refuse the whole channel ("Error in topic robot.state (channel 1):
Unsupported type undefined for roll_deg"), so its panels show nothing of that topic.
"""
from __future__ import annotations

import io
import json
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
            elif item.get("type") not in _SCALARS or (item.get("type") == "string" and "contentEncoding" in item):
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
    assert len(schemas) == len(SAMPLES) + 1
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
