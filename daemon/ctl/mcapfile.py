"""How a ritad session is laid out in an MCAP file: the one place ``record`` and ``replay`` share.

docs/operations.md ("Record and replay") documents this layout; keep the two in step.

* One channel per telemetry topic, JSON message encoding. Each message is the bus message's
  ``data`` map as JSON; the bus ``seq`` is the MCAP message's ``sequence`` (modulo 2**32), the
  daemon's ``t_ns`` its ``log_time`` and the recorder's receive time its ``publish_time``.
  The channel's schema (``jsonschema``) is inferred from the topic's first message: top-level
  field names and JSON types, so Foxglove's panels can offer the fields.
* Frames: channel ``camera.frame`` with Foxglove's ``foxglove.RawImage`` schema in JSON (pixels
  base64), and channel ``camera.frame.header`` with the bus's frame header as JSON, written just
  before each image so a replay can rebuild the bus frame exactly.
* Metadata record ``ritactl.record``: who recorded what (ritad's ``hello``, the options).

Imports only the standard library so the thin client stays thin; the ``mcap`` package is
imported by the verbs that write and read.
"""
from __future__ import annotations

import base64
import json
import math
from typing import Any

PROFILE = ""  # no ROS profile: plain JSON channels
FRAME_TOPIC = "camera.frame"
FRAME_HEADER_TOPIC = "camera.frame.header"
METADATA_NAME = "ritactl.record"
RAW_IMAGE_SCHEMA = "foxglove.RawImage"
SEQ_MOD = 1 << 32  # an MCAP sequence is a uint32

#: GenICam pixel formats with a Foxglove RawImage encoding of their own; others fall back on dtype
_ENCODINGS = {"Mono8": "mono8", "Mono10": "mono16", "Mono12": "mono16", "Mono16": "mono16",
              "RGB8": "rgb8", "BGR8": "bgr8", "BayerRG8": "bayer_rggb8", "BayerGR8": "bayer_grbg8",
              "BayerGB8": "bayer_gbrg8", "BayerBG8": "bayer_bggr8"}

#: Foxglove's RawImage, as its JSON schema (field names and types from Foxglove's schema docs)
RAW_IMAGE_JSON_SCHEMA: dict[str, Any] = {
    "title": RAW_IMAGE_SCHEMA, "description": "A raw image", "type": "object",
    "properties": {
        "timestamp": {"type": "object", "properties": {"sec": {"type": "integer", "minimum": 0},
                                                       "nsec": {"type": "integer", "minimum": 0,
                                                                "maximum": 999_999_999}}},
        "frame_id": {"type": "string"},
        "width": {"type": "integer", "minimum": 0},
        "height": {"type": "integer", "minimum": 0},
        "encoding": {"type": "string"},
        "step": {"type": "integer", "minimum": 0},
        "data": {"type": "string", "contentEncoding": "base64"},
    },
}


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


def _json_type(value: Any, depth: int) -> dict[str, Any]:
    if isinstance(value, bool):
        return {"type": "boolean"}
    if isinstance(value, (int, float)):
        return {"type": "number"}  # an integer now may be a fraction in the next message
    if isinstance(value, str):
        return {"type": "string"}
    if isinstance(value, (list, tuple)):
        items = _json_type(value[0], depth + 1) if value and depth < 3 else {}
        return {"type": "array", "items": items}
    if isinstance(value, dict):
        if depth >= 3:
            return {"type": "object"}
        return {"type": "object", "properties": {str(k): _json_type(v, depth + 1) for k, v in value.items()}}
    return {}  # null: any type


def infer_schema(topic: str, data: Any) -> dict[str, Any]:
    """A JSON schema for a topic from one of its messages: field names and types, nothing required."""
    schema = _json_type(data, 0) if isinstance(data, dict) else {}
    return {"title": topic, "description": f"ritad telemetry {topic} (docs/protocol.md)", **schema}


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


def raw_image(header: dict[str, Any], pixels: bytes | memoryview) -> bytes:
    """A bus frame (header + row-major pixels) as a ``foxglove.RawImage`` JSON message."""
    encoding = raw_image_encoding(header)
    shape = [int(n) for n in header["shape"]]
    height, width = shape[0], shape[1]
    t = int(header.get("host_time_ns") or 0)
    msg = {"timestamp": {"sec": t // 1_000_000_000, "nsec": t % 1_000_000_000}, "frame_id": "camera",
           "width": width, "height": height, "encoding": encoding,
           "step": len(pixels) // height if height else 0,
           "data": base64.b64encode(pixels).decode("ascii")}
    return json.dumps(msg, separators=(",", ":")).encode()


def pixels_of(raw_image_json: bytes | memoryview) -> bytes:
    """The pixel bytes of a RawImage JSON message (for a replay)."""
    return base64.b64decode(json.loads(bytes(raw_image_json))["data"])


__all__ = ["FRAME_HEADER_TOPIC", "FRAME_TOPIC", "METADATA_NAME", "PROFILE", "RAW_IMAGE_JSON_SCHEMA",
           "RAW_IMAGE_SCHEMA", "SEQ_MOD", "UnsupportedFrame", "infer_schema", "pixels_of", "raw_image",
           "raw_image_encoding", "to_json"]
