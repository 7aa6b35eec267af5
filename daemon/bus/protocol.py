"""Bus message formats shared by ritad, the worker and ritactl (msgpack only, never pickle).

Command channel (ROUTER on the daemon, DEALER in clients), each message one
msgpack map in one frame, optionally followed by raw binary attachments:

* request ``{"v": 1, "id": <str|int>, "cmd": "<name>", "args": {...}}``
* reply   ``{"v": 1, "id": <same>, "ok": true, "result": ...}`` or
  ``{"v": 1, "id": <same>, "ok": false, "error": {"code": "<stable>", "message": "<human>"}}``

Telemetry (PUB): ``[topic, msgpack {"v", "seq", "t_ns", "data"}]``.
Frames (separate PUB): ``[b"camera.frame", msgpack header, raw pixels]``.
This module imports nothing heavier than msgpack so the laptop client stays thin.
See docs/protocol.md.
"""
from __future__ import annotations

from typing import Any

import msgpack

SCHEMA_VERSION = 1


class ErrorCode:
    """Stable error codes of command replies (never renamed; add new ones only)."""

    BAD_REQUEST = "bad_request"  # not msgpack / not a map / missing fields / wrong types
    TOO_LARGE = "too_large"
    UNKNOWN_COMMAND = "unknown_command"
    BAD_ARGS = "bad_args"
    UNSUPPORTED_VERSION = "unsupported_version"
    NOT_READY = "not_ready"  # device not connected
    DEVICE_ERROR = "device_error"
    DEVICE_LOST = "device_lost"
    TIMEOUT = "timeout"
    CONFIRM_REQUIRED = "confirm_required"
    BUSY = "busy"
    NOT_FOUND = "not_found"
    INTERNAL = "internal"
    UNAUTHORIZED = "unauthorized"  # the CURVE key was revoked while connected
    FORBIDDEN = "forbidden"  # the caller's role may not send this command; the message names both roles
    STOPPED = "stopped"  # the robot's stop is latched: no motion until an operator's robot.release


class ProtocolError(Exception):
    """A message that does not follow the bus protocol."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


class CommandError(Exception):
    """Raised by command handlers (and by the client for error replies)."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code

    def __str__(self) -> str:
        return f"{self.args[0]} [{self.code}]"


def pack(obj: Any) -> bytes:
    return msgpack.packb(obj, use_bin_type=True)


def unpack(data: bytes | memoryview) -> Any:
    return msgpack.unpackb(data, raw=False, strict_map_key=False)


def make_request(req_id: str | int, cmd: str, args: dict[str, Any] | None = None) -> bytes:
    return pack({"v": SCHEMA_VERSION, "id": req_id, "cmd": cmd, "args": args or {}})


def parse_request(data: bytes | memoryview) -> dict[str, Any]:
    """Decode and validate a request; raise ProtocolError with a stable code."""
    try:
        msg = unpack(data)
    except Exception as exc:  # msgpack raises several types for garbage
        raise ProtocolError(ErrorCode.BAD_REQUEST,
                            f"request is not valid msgpack ({type(exc).__name__})") from None
    if not isinstance(msg, dict):
        raise ProtocolError(ErrorCode.BAD_REQUEST, f"request must be a msgpack map, got {type(msg).__name__}")
    v = msg.get("v", SCHEMA_VERSION)
    if v != SCHEMA_VERSION or isinstance(v, bool):  # True == 1 in Python: not a version
        raise ProtocolError(ErrorCode.UNSUPPORTED_VERSION,
                            f"schema version {v!r} is not supported (this daemon speaks {SCHEMA_VERSION})")
    if not isinstance(msg.get("cmd"), str) or not msg["cmd"]:
        raise ProtocolError(ErrorCode.BAD_REQUEST, "request needs a non-empty string 'cmd'")
    if "id" not in msg or not isinstance(msg["id"], (str, int)) or isinstance(msg["id"], bool):
        raise ProtocolError(ErrorCode.BAD_REQUEST, "request needs an 'id' (string or integer)")
    args = msg.get("args", {})
    if args is None:
        args = {}
    if not isinstance(args, dict):
        raise ProtocolError(ErrorCode.BAD_ARGS, f"'args' must be a map, got {type(args).__name__}")
    msg["args"] = args
    return msg


def ok_reply(req_id: Any, result: Any) -> bytes:
    return pack({"v": SCHEMA_VERSION, "id": req_id, "ok": True, "result": result})


def error_reply(req_id: Any, code: str, message: str) -> bytes:
    return pack({"v": SCHEMA_VERSION, "id": req_id, "ok": False, "error": {"code": code, "message": message}})


def telemetry(seq: int, t_ns: int, data: Any) -> bytes:
    return pack({"v": SCHEMA_VERSION, "seq": seq, "t_ns": t_ns, "data": data})
