"""How a ritad session is laid out in an MCAP file: the one place ``record`` and ``replay`` share.

docs/operations.md ("Record and replay") documents this layout; keep the two in step.

* One channel per telemetry topic, named by :func:`mcap_topic` (``robot.state`` → ``/robot/state``:
  Foxglove's message paths need no quotes), JSON message encoding. Each message is the bus
  message's ``data`` map as JSON, less the nulls its schema has a type for (:func:`drop_typed_nulls`);
  the MCAP ``sequence`` counts the channel's messages from 1 (modulo 2**32), the ``log_time`` is the
  sample's own time (:func:`sample_time`) and the recorder's receive time is the ``publish_time``.
  The channel's schema (``jsonschema``) is inferred from the topic's first message: field names and
  JSON types, so Foxglove's panels can offer the fields; written in the subset of JSON Schema that
  Foxglove's reader accepts (:func:`_json_type`), since it refuses a channel for one field outside it.
  The bus's ``log`` is the exception: it goes in as Foxglove's ``foxglove.Log`` on ``/log``.
* Foxglove's well-known messages beside them (daemon/ctl/foxglove.py): ``/robot/pose`` and
  ``/tracker/pose`` (``foxglove.PoseInFrame``, one message per sample or tracker record).
* Frames: channel ``/camera/frame`` with Foxglove's image schema in its ROS 2 form
  (``foxglove_msgs/msg/RawImage`` by default, ``CompressedImage`` with ``--frames-format jpeg|png``;
  schema encoding ``ros2msg``, messages in CDR): raw pixels go in as they are, where JSON would base64
  them: a third larger, and slow to encode against a copy here (docs/benchmarks.md, "Recording").
  Channel ``/camera/frame/header`` has the bus's frame header as JSON, written just before each
  image so a replay can rebuild the bus frame exactly; both
  are logged at the exposure's mid-time (the header's ``t_ns``).
* Channel ``/daemon/command``: the session's command/reply pairs as ritad reports them (its
  ``daemon.command`` telemetry), with the fixed schema :data:`COMMAND_SCHEMA` instead of an
  inferred one, since ``args`` differs from one command to the next.
* Metadata record ``ritactl.record``: who recorded what (ritad's ``hello``, the options, a
  simulator's time scale); record ``ritactl.record.end``: how the recording ended (``duration``,
  ``interrupted``, ``max_size``, ``min_free`` or ``error`` and the error) and what it lost, written
  just before the summary.

Imports only the standard library (and the bus's names) so the thin client stays thin; the ``mcap``
package is imported by the verbs that write and read.
"""
from __future__ import annotations

import base64
import json
import math
import struct
from typing import Any

from daemon.bus.names import Topic

PROFILE = ""  # no ROS profile: plain JSON channels
END_METADATA_NAME = "ritactl.record.end"
#: the bus's frame topic, and the recording's channels for frames (mcap_topic of the bus names)
FRAME_TOPIC = "camera.frame"
FRAME_HEADER_TOPIC = "camera.frame.header"
FRAME_CHANNEL = "/camera/frame"
FRAME_HEADER_CHANNEL = "/camera/frame/header"
METADATA_NAME = "ritactl.record"
RAW_IMAGE_SCHEMA = "foxglove_msgs/msg/RawImage"
COMPRESSED_IMAGE_SCHEMA = "foxglove_msgs/msg/CompressedImage"
#: the bus topics whose ``data`` holds a batch of samples, each with its own time in ``t_ns``
BATCHED = ("tracker.point", "robot.odometry", "robot.incl")
SEQ_MOD = 1 << 32  # an MCAP sequence is a uint32

#: GenICam pixel formats with a Foxglove RawImage encoding of their own; others fall back on dtype
_ENCODINGS = {"Mono8": "mono8", "Mono10": "mono16", "Mono12": "mono16", "Mono16": "mono16",
              "RGB8": "rgb8", "BGR8": "bgr8", "BayerRG8": "bayer_rggb8", "BayerGR8": "bayer_grbg8",
              "BayerGB8": "bayer_gbrg8", "BayerBG8": "bayer_bggr8"}

#: Foxglove's RawImage in ROS 2 message syntax (fields from Foxglove's schema docs), with the one
#: message it uses appended the way MCAP's ros2msg encoding wants dependencies
RAW_IMAGE_ROS2MSG = """builtin_interfaces/Time timestamp
string frame_id
uint32 width
uint32 height
string encoding
uint32 step
uint8[] data
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
#: Foxglove's CompressedImage in ROS 2 message syntax (schemas/ros2/CompressedImage.msg of foxglove-sdk)
COMPRESSED_IMAGE_ROS2MSG = """builtin_interfaces/Time timestamp
string frame_id
uint8[] data
string format
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
_CDR_LE = b"\x00\x01\x00\x00"  # CDR encapsulation header: plain CDR, little-endian


class UnsupportedFrame(ValueError):
    """A frame whose pixel layout has no RawImage encoding (recorded as its header only)."""


def _finite(obj: Any) -> Any:
    """``obj`` with NaN and infinities as null: JSON has no such numbers and Foxglove rejects them."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


def _json_default(obj: Any) -> Any:
    if isinstance(obj, (bytes, bytearray, memoryview)):
        return base64.b64encode(bytes(obj)).decode("ascii")
    return str(obj)


def to_json(obj: Any) -> bytes:
    """Compact JSON bytes; non-finite numbers become null, binary becomes base64 text."""
    try:
        text = json.dumps(obj, separators=(",", ":"), allow_nan=False, default=_json_default)
    except ValueError:  # a NaN somewhere: the slow path only for such messages
        text = json.dumps(_finite(obj), separators=(",", ":"), allow_nan=False, default=_json_default)
    return text.encode()


def _json_type(value: Any, depth: int) -> dict[str, Any] | None:
    """The schema of one JSON value in the subset Foxglove's JSON-schema reader takes (one type per
    field; arrays of booleans, strings, numbers or objects), None where that subset has no word
    for it: a null (its type is unknown), an empty array, an array of arrays or of nulls. Foxglove
    refuses a whole channel for one such field, so it is left out of ``properties``; the messages
    still carry it and Foxglove's Raw Messages panel shows it."""
    if isinstance(value, bool):
        return {"type": "boolean"}
    if isinstance(value, (int, float)):
        return {"type": "number"}  # an integer now may be a fraction in the next message
    if isinstance(value, str):
        return {"type": "string"}
    if isinstance(value, (list, tuple)):
        items = _json_type(value[0], depth + 1) if value and depth < 3 else None
        return {"type": "array", "items": items} if items is not None and items["type"] != "array" else None
    if isinstance(value, dict):
        if depth >= 3:
            return {"type": "object"}
        props = {str(k): _json_type(v, depth + 1) for k, v in value.items()}
        return {"type": "object", "properties": {k: t for k, t in props.items() if t is not None}}
    return None  # null: any type


#: daemon.command's fields (docs/protocol.md, Telemetry): ``args`` is any command's, so not inferred.
#: ``args``, ``key``, ``code`` and ``message`` are null when they have no value: the recorder leaves
#: such a null out of the message (:func:`drop_typed_nulls`) rather than leave the field out of the
#: schema, as Foxglove's reader takes one type per field and no unions. ``id`` is the caller's, a
#: string or an integer, so it has no type here (a strict reader then takes either).
COMMAND_SCHEMA: dict[str, Any] = {"type": "object", "properties": {
    "cmd": {"type": "string"}, "args": {"type": "object"},
    "key": {"type": "string"}, "role": {"type": "string"}, "ok": {"type": "boolean"},
    "code": {"type": "string"}, "message": {"type": "string"},
    "recv_ns": {"type": "number"}, "reply_ns": {"type": "number"}}}
_FIXED_SCHEMAS = {str(Topic.DAEMON_COMMAND): COMMAND_SCHEMA}


def infer_schema(topic: str, data: Any) -> dict[str, Any]:
    """A JSON schema for a topic from one of its messages: field names and types, nothing required
    (a topic with a fixed schema, daemon.command, gets that one)."""
    fixed = _FIXED_SCHEMAS.get(topic)
    schema = fixed if fixed is not None else _json_type(data, 0) if isinstance(data, dict) else None
    schema = schema if schema is not None else {"type": "object", "properties": {}}
    return {"title": topic, "description": f"ritad telemetry {topic} (docs/protocol.md)", **schema}


def drop_typed_nulls(value: Any, schema: dict[str, Any]) -> Any:
    """``value`` without the nulls where ``schema`` gives the field a type (in objects, nested and
    in arrays): a strict JSON-schema check refuses null for "number" or "string", and Foxglove's
    reader has no way to say "or null". Nothing is lost: the field's absence says null, and a
    replay puts it back (:func:`restore_nulls`). A null the schema has no type for stays."""
    props = schema.get("properties")
    if isinstance(value, dict) and props:
        return {k: drop_typed_nulls(v, props[k]) if k in props else v
                for k, v in value.items() if v is not None or k not in props}
    items = schema.get("items")
    if isinstance(value, list) and isinstance(items, dict) and "properties" in items:
        return [drop_typed_nulls(v, items) for v in value]
    return value


def restore_nulls(value: Any, schema: dict[str, Any]) -> Any:
    """The inverse of :func:`drop_typed_nulls`: a field the schema types and the message lacks is null."""
    props = schema.get("properties")
    if isinstance(value, dict) and props:
        out = {k: restore_nulls(v, props[k]) if k in props else v for k, v in value.items()}
        return {**out, **{k: None for k in props if k not in value}}
    items = schema.get("items")
    if isinstance(value, list) and isinstance(items, dict) and "properties" in items:
        return [restore_nulls(v, items) for v in value]
    return value


def mcap_topic(topic: str) -> str:
    """The channel of a bus topic: ``robot.state`` → ``/robot/state``. Foxglove's message paths take
    a topic with dots only in quotes (``"robot.state".x_mm``); a slash-separated one needs none."""
    return "/" + topic.replace(".", "/")


def bus_topic(channel: str) -> str:
    """The inverse of :func:`mcap_topic`; a channel of an older recording (``robot.state``) is its own."""
    return channel[1:].replace("/", ".") if channel.startswith("/") else channel


def _int(value: Any) -> int | None:
    try:
        return int(value) if value is not None and not isinstance(value, bool) else None
    except (TypeError, ValueError, OverflowError):
        return None


def sample_times(topic: str, data: Any) -> list[int] | None:
    """Each sample's own time (ns, host timeline) in a batched message (:data:`BATCHED`): ``t_ns``
    per sample, else the host's arrival ``host_time_ns`` (per sample, or the packet's for all);
    None when the message has neither."""
    if topic not in BATCHED or not isinstance(data, dict):
        return None
    for key in ("t_ns", "host_time_ns"):
        value = data.get(key)
        if isinstance(value, list) and value and all(_int(v) is not None for v in value):
            return [int(v) for v in value]
        if (one := _int(value)) is not None and isinstance(data.get("x"), list):  # one arrival for a packet
            return [one] * len(data["x"])
    return None


def sample_time(topic: str, data: Any, published_ns: int) -> int:
    """The instant a message describes, its MCAP log time: a frame's exposure mid-time, a STATUS's or
    an event's time, a batch's last sample, a log record's; ``published_ns`` (when ritad sent it) for
    a message with none (health, commands, state changes)."""
    if not isinstance(data, dict):
        return published_ns
    batch = sample_times(topic, data)
    if batch:
        return batch[-1]
    if topic == "log" and isinstance(data.get("t"), (int, float)):
        return int(round(data["t"] * 1e9))
    for key in ("t_ns", "host_time_ns"):  # frames, robot.state, robot.event
        if (t := _int(data.get(key))) is not None:
            return t
    return published_ns


def raw_image_encoding(header: dict[str, Any]) -> str:
    """The RawImage ``encoding`` of a bus frame, from its pixel format, else its dtype and shape."""
    fmt = str(header.get("pixel_format") or "")
    if fmt in _ENCODINGS:
        return _ENCODINGS[fmt]
    dtype, shape = str(header.get("dtype", "")), list(header.get("shape") or [])
    little = dtype[:1] in ("<", "|", "=")
    if dtype.endswith("u1") and len(shape) == 2:
        return "mono8"
    if dtype.endswith("u2") and little and len(shape) == 2:
        return "mono16"
    if dtype.endswith("u1") and len(shape) == 3 and shape[2] == 3:
        return "rgb8"
    raise UnsupportedFrame(f"pixel format {fmt or '?'} (dtype {dtype or '?'}, shape {shape}) has no "
                           f"Foxglove RawImage encoding")


class _Cdr:
    """Just enough little-endian CDR for RawImage: 4-byte words aligned from the end of the header."""

    def __init__(self) -> None:
        self.buf = bytearray(_CDR_LE)

    def u32(self, *values: int) -> None:
        self.buf += b"\x00" * (-(len(self.buf) - 4) % 4)
        self.buf += struct.pack(f"<{len(values)}I", *values)

    def string(self, text: str) -> None:
        raw = text.encode()
        self.u32(len(raw) + 1)  # CDR strings count their terminating NUL
        self.buf += raw + b"\x00"


def raw_image(header: dict[str, Any], pixels: bytes | memoryview) -> bytes:
    """A bus frame (header + row-major pixels) as a CDR ``foxglove_msgs/msg/RawImage``."""
    encoding = raw_image_encoding(header)
    try:
        height, width = (int(n) for n in header["shape"][:2])
    except (KeyError, TypeError, ValueError) as exc:
        raise UnsupportedFrame(f"frame header has no usable shape ({header.get('shape')!r})") from exc
    t = int(header.get("t_ns") or header.get("host_time_ns") or 0)  # the exposure's mid-time
    c = _Cdr()
    c.u32(t // 1_000_000_000, t % 1_000_000_000)  # sec is int32 in the schema: fine until 2038
    c.string("camera")
    c.u32(width, height)
    c.string(encoding)
    c.u32(len(pixels) // height if height else 0)
    c.u32(len(pixels))
    return b"".join((c.buf, pixels))


def compressed_image(header: dict[str, Any], data: bytes, fmt_name: str) -> bytes:
    """An encoded picture (``fmt_name``: jpeg or png) as a CDR ``foxglove_msgs/msg/CompressedImage``."""
    t = int(header.get("t_ns") or header.get("host_time_ns") or 0)
    c = _Cdr()
    c.u32(t // 1_000_000_000, t % 1_000_000_000)
    c.string("camera")
    c.u32(len(data))
    c.buf += data
    c.string(fmt_name)
    return bytes(c.buf)


def compressed_data(raw: bytes | memoryview) -> memoryview:
    """The encoded picture of a CDR CompressedImage made by :func:`compressed_image` (no copy)."""
    view = memoryview(raw)
    off = 4 + 8  # header, timestamp
    n = struct.unpack_from("<I", view, off)[0]  # frame_id
    off += 4 + n
    off += -(off - 4) % 4
    n = struct.unpack_from("<I", view, off)[0]  # data
    return view[off + 4:off + 4 + n]


def pixels_of(raw: bytes | memoryview) -> memoryview:
    """The pixel bytes of a CDR RawImage made by :func:`raw_image` (for a replay; no copy)."""
    view = memoryview(raw)
    off = 4 + 8  # header, timestamp

    def word(at: int) -> tuple[int, int]:
        at += -(at - 4) % 4
        return struct.unpack_from("<I", view, at)[0], at + 4

    n, off = word(off)      # frame_id
    off += n
    _, off = word(off)      # width
    _, off = word(off)      # height
    n, off = word(off)      # encoding
    off += n
    _, off = word(off)      # step
    n, off = word(off)      # data
    return view[off:off + n]
