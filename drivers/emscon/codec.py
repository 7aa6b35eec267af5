"""emScon TPI binary codec: packet layouts, encode/decode and a streaming framer.

Every packet is a little-endian C struct packed to 4 bytes, so Python ``struct``
with ``'<'`` (no alignment) describes it exactly. ``lPacketSize`` is the whole
packet length including the 8-byte header. Requests (CT) and answers (RT) of the
same command share ``type = 0`` and can even share a size, so decoding needs the
direction: :data:`TO_SERVER` (requests) or :data:`TO_CLIENT` (answers, results,
errors, events).

Anything malformed — a size below 8 or above 1 MiB, a size that does not fit its
type/command, a record count that disagrees with the size, a data type this codec
does not know — raises :class:`ProtocolError` and nothing else.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from drivers.emscon.commands import COMMANDS, ENV_FIELDS, XYZ_FIELDS, Fields, parse_fields
from drivers.emscon.enums import (
    ES_ADMStatus, ES_Command, ES_CoordinateSystemType, ES_DataType, ES_LaserProcessorStatus,
    ES_LTSensorType, ES_MeasMode, ES_ResultStatus, ES_SystemStatusChange, ES_TargetType,
    ES_TrackerProcessorStatus, ES_TrackerStatus, ES_WeatherMonitorStatus, as_enum, enum_name)

TO_SERVER = "to_server"
TO_CLIENT = "to_client"
MIN_PACKET = 8
MAX_PACKET = 1 << 20
STRING_UNITS = 32  # unsigned short[32]

class ProtocolError(Exception):
    """The byte stream broke the emScon framing or layout rules; the connection is unusable."""

    #: set by the framer: the whole packets decoded before the bad one (they are good)
    packets: list[Packet]


#: result packets: data type -> fields after the 12-byte ReturnDataT prefix
_STD = parse_fields("std1:d std2:d std3:d std_total:d")
_APRIORI = parse_fields("apriori_std1:d apriori_std2:d apriori_std3:d apriori_std_total:d")
RESULTS: dict[ES_DataType, Fields] = {
    ES_DataType.SingleMeasResult: parse_fields("meas_mode:i is_try_mode:i") + XYZ_FIELDS + _STD
    + parse_fields("pointing_error1:d pointing_error2:d pointing_error3:d") + _APRIORI + ENV_FIELDS,
    ES_DataType.SingleMeasResult2: parse_fields("meas_mode:i is_try_mode:i") + XYZ_FIELDS + _STD
    + parse_fields("covar12:d covar13:d covar23:d pointing_error_h:d pointing_error_v:d pointing_error_d:d")
    + _APRIORI + parse_fields("apriori_covar12:d apriori_covar13:d apriori_covar23:d") + ENV_FIELDS,
    ES_DataType.MultiMeasResult: parse_fields("number_of_results:i meas_mode:i is_try_mode:i") + ENV_FIELDS,
    ES_DataType.MultiMeasResult2: parse_fields("number_of_results:i meas_mode:i is_try_mode:i") + ENV_FIELDS,
    ES_DataType.ReflectorPosResult: XYZ_FIELDS,
    ES_DataType.NivelResult: parse_fields("nivel_status:i x_tilt:d y_tilt:d nivel_temperature:d"),
}
MULTI_HEAD = 48

#: per-record layouts of the continuous results (packed: numpy adds no padding here)
MEAS_VALUE = np.dtype([("status", "<i4"), ("time1", "<i4"), ("time2", "<i4"),
                       ("val1", "<f8"), ("val2", "<f8"), ("val3", "<f8")])
MEAS_VALUE2 = np.dtype(MEAS_VALUE.descr + [
    (n, "<f8") for n in ("apriori_std1", "apriori_std2", "apriori_std3", "apriori_std_total",
                         "apriori_covar12", "apriori_covar13", "apriori_covar23")])
RECORDS = {ES_DataType.MultiMeasResult: MEAS_VALUE, ES_DataType.MultiMeasResult2: MEAS_VALUE2}

#: fields shown as enums after decoding (unknown values stay ints)
FIELD_ENUMS: dict[str, Any] = {
    "last_result_status": ES_ResultStatus, "tracker_processor_status": ES_TrackerProcessorStatus,
    "laser_status": ES_LaserProcessorStatus, "adm_status": ES_ADMStatus,
    "weather_monitor_status": ES_WeatherMonitorStatus, "tracker_status": ES_TrackerStatus,
    "meas_mode": ES_MeasMode, "coord_sys_type": ES_CoordinateSystemType,
    "target_type": ES_TargetType, "tracker_type": ES_LTSensorType,
}

_CODES = {"i": "i", "d": "d", "s": f"{2 * STRING_UNITS}s"}


def fields_struct(prefix: str, fields: Fields) -> struct.Struct:
    """The ``struct.Struct`` of a whole packet: prefix format plus the fields."""
    return struct.Struct("<" + prefix + "".join(_CODES[code] for _, code in fields))


# prefixes: CT = size,type,command; RT/error = size,type,command,status;
# results = size,type,status; status change = size,type,change
_CT = {c: fields_struct("iii", ct) for c, (ct, _) in COMMANDS.items()}
_RT = {c: fields_struct("iiii", rt) for c, (_, rt) in COMMANDS.items()}
_RES = {t: fields_struct("iii", f) for t, f in RESULTS.items()}
_PREFIX3 = struct.Struct("<iii")
_PREFIX4 = struct.Struct("<iiii")
_HEADER = struct.Struct("<ii")


@dataclass(eq=False)
class Packet:
    """One decoded packet.

    ``kind`` is one of ``request`` (CT), ``answer`` (RT), ``error`` (ErrorResponseT),
    ``status_change``, ``single``, ``single2``, ``multi``, ``multi2``, ``reflector_pos``,
    ``nivel``. ``values`` holds the named fields beyond the prefix (empty for an error
    answer sent as a bare 16-byte prefix); ``records`` the continuous records.
    """

    kind: str
    data_type: int
    command: int | None = None
    status: int = 0
    change: int | None = None
    values: dict[str, Any] = field(default_factory=dict)
    records: np.ndarray | None = None

    def __getitem__(self, key: str) -> Any:
        return self.values[key]

    def describe(self) -> str:
        """Short human text, for logs and error messages."""
        parts = [self.kind]
        if self.command is not None:
            parts.append(enum_name(ES_Command, self.command))
        if self.kind in ("answer", "error") or self.status:
            parts.append(f"status={enum_name(ES_ResultStatus, self.status)}({int(self.status)})")
        if self.change is not None:
            parts.append(enum_name(ES_SystemStatusChange, self.change))
        if self.records is not None:
            parts.append(f"n={len(self.records)}")
        return " ".join(parts)


_KINDS = {ES_DataType.SingleMeasResult: "single", ES_DataType.SingleMeasResult2: "single2",
          ES_DataType.MultiMeasResult: "multi", ES_DataType.MultiMeasResult2: "multi2",
          ES_DataType.ReflectorPosResult: "reflector_pos", ES_DataType.NivelResult: "nivel"}
_TYPES = {v: k for k, v in _KINDS.items()}


# --------------------------------------------------------------------------- encoding


def _pack_values(fields: Fields, values: dict[str, Any], what: str) -> list[Any]:
    unknown = set(values) - {n for n, _ in fields}
    if unknown:
        raise ValueError(f"{what}: unknown field(s) {sorted(unknown)} (known: {[n for n, _ in fields]})")
    out: list[Any] = []
    for name, code in fields:
        v = values.get(name, "" if code == "s" else 0)
        if code == "s":
            raw = str(v).encode("utf-16-le")
            if len(raw) > 2 * STRING_UNITS:
                raise ValueError(f"{what}: {name}={v!r} is longer than {STRING_UNITS} UTF-16 units")
            out.append(raw)
        elif code == "i":
            iv = int(v)
            if not -(1 << 31) <= iv < (1 << 31):
                raise ValueError(f"{what}: {name}={v!r} does not fit a signed 32-bit int")
            out.append(iv)
        else:
            out.append(float(v))
    return out


def encode_request(command: int, **values: Any) -> bytes:
    """A command request (CT) with its parameters (missing ones are 0)."""
    cmd = ES_Command(command)
    s = _CT[cmd]
    return s.pack(s.size, ES_DataType.Command, cmd, *_pack_values(COMMANDS[cmd][0], values, cmd.name))


def encode_answer(command: int, status: int = 0, **values: Any) -> bytes:
    """A command answer (RT). A failed answer without values is the bare 16-byte prefix."""
    cmd = ES_Command(command)
    if status != 0 and not values:
        return _PREFIX4.pack(16, ES_DataType.Command, cmd, status)
    s = _RT[cmd]
    return s.pack(s.size, ES_DataType.Command, cmd, status,
                  *_pack_values(COMMANDS[cmd][1], values, cmd.name + " answer"))


def encode_error(command: int, status: int) -> bytes:
    """An asynchronous ErrorResponseT."""
    return _PREFIX4.pack(16, ES_DataType.Error, command, status)


def encode_status_change(change: int) -> bytes:
    """A SystemStatusChangeT event."""
    return _PREFIX3.pack(12, ES_DataType.SystemStatusChange, change)


def encode_result(kind: str, status: int = 0, records: np.ndarray | None = None,
                  **values: Any) -> bytes:
    """A result packet (``single``, ``single2``, ``multi``, ``multi2``, ``reflector_pos``, ``nivel``).

    For the multi kinds, ``records`` is an array of :data:`MEAS_VALUE`/:data:`MEAS_VALUE2`
    and ``number_of_results`` is taken from it.
    """
    if kind not in _TYPES:
        raise ValueError(f"unknown result kind {kind!r} (known: {sorted(_TYPES)})")
    dtype = _TYPES[kind]
    s = _RES[dtype]
    if dtype in RECORDS:
        rec = np.asarray(records if records is not None else np.zeros(0, RECORDS[dtype]))
        if rec.dtype != RECORDS[dtype]:
            rec = rec.astype(RECORDS[dtype])
        values = {**values, "number_of_results": len(rec)}
        body = rec.tobytes()
        size = s.size + len(body)
        return s.pack(size, dtype, status, *_pack_values(RESULTS[dtype], values, kind)) + body
    return s.pack(s.size, dtype, status, *_pack_values(RESULTS[dtype], values, kind))


def encode(packet: Packet) -> bytes:
    """Encode any :class:`Packet` (the inverse of :func:`decode`)."""
    k = packet.kind
    if k == "request":
        return encode_request(packet.command or 0, **packet.values)
    if k == "answer":
        if packet.command not in COMMANDS:
            return _PREFIX4.pack(16, ES_DataType.Command, packet.command or 0, packet.status)
        return encode_answer(packet.command, packet.status, **packet.values)
    if k == "error":
        return encode_error(packet.command or 0, packet.status)
    if k == "status_change":
        return encode_status_change(packet.change or 0)
    return encode_result(k, packet.status, packet.records, **packet.values)


# --------------------------------------------------------------------------- decoding


def _unpack(s: struct.Struct, fields: Fields, buf: bytes, skip: int) -> dict[str, Any]:
    raw = s.unpack_from(buf)
    out: dict[str, Any] = {}
    for (name, code), v in zip(fields, raw[skip:]):
        if code == "s":
            v = v.decode("utf-16-le", errors="replace").split("\x00", 1)[0]
        elif name in FIELD_ENUMS:
            v = as_enum(FIELD_ENUMS[name], v)
        out[name] = v
    return out


def _bad(msg: str) -> ProtocolError:
    return ProtocolError(msg)


def decode(buf: bytes, direction: str) -> Packet:
    """Decode exactly one whole packet (``len(buf)`` must equal its ``lPacketSize``)."""
    n = len(buf)
    if n < MIN_PACKET:
        raise _bad(f"packet of {n} bytes is shorter than the 8-byte header")
    size, dtype = _HEADER.unpack_from(buf)
    if size != n:
        raise _bad(f"lPacketSize {size} does not match the {n} bytes given")
    if size > MAX_PACKET:
        raise _bad(f"lPacketSize {size} exceeds the {MAX_PACKET}-byte limit")
    if direction == TO_SERVER:
        return _decode_request(buf, dtype)
    if direction != TO_CLIENT:
        raise ValueError(f"direction must be {TO_SERVER!r} or {TO_CLIENT!r}, not {direction!r}")
    if dtype == ES_DataType.Command:
        return _decode_answer(buf, dtype)
    if dtype == ES_DataType.Error:
        if n != 16:
            raise _bad(f"ErrorResponse: lPacketSize {n}, expected 16")
        _, _, cmd, status = _PREFIX4.unpack_from(buf)
        return Packet("error", dtype, command=as_enum(ES_Command, cmd),
                      status=as_enum(ES_ResultStatus, status))
    if dtype == ES_DataType.SystemStatusChange:
        if n != 12:
            raise _bad(f"SystemStatusChange: lPacketSize {n}, expected 12")
        (_, _, change) = _PREFIX3.unpack_from(buf)
        return Packet("status_change", dtype, change=as_enum(ES_SystemStatusChange, change))
    if dtype in RECORDS:
        return _decode_multi(buf, ES_DataType(dtype))
    if dtype in _RES:
        s = _RES[dtype]
        if n != s.size:
            raise _bad(f"{ES_DataType(dtype).name}: lPacketSize {n}, expected {s.size}")
        values = _unpack(s, RESULTS[dtype], buf, 3)
        status = as_enum(ES_ResultStatus, struct.unpack_from("<i", buf, 8)[0])
        return Packet(_KINDS[ES_DataType(dtype)], dtype, status=status, values=values)
    raise _bad(f"unsupported data type {enum_name(ES_DataType, dtype)} (lPacketSize {n})")


def _decode_request(buf: bytes, dtype: int) -> Packet:
    """A CT packet (client → server): only data type Command is valid."""
    n = len(buf)
    if dtype != ES_DataType.Command:
        raise _bad(f"request with data type {enum_name(ES_DataType, dtype)} (only Command is valid)")
    if n < 12:
        raise _bad(f"request of {n} bytes is shorter than BasicCommandCT (12)")
    (cmd,) = struct.unpack_from("<i", buf, 8)
    if cmd not in COMMANDS:
        if n != 12:
            raise _bad(f"request for unknown command {cmd} with lPacketSize {n} (expected 12)")
        return Packet("request", dtype, command=cmd)
    s = _CT[cmd]
    if n != s.size:
        raise _bad(f"{ES_Command(cmd).name} request: lPacketSize {n}, expected {s.size}")
    return Packet("request", dtype, command=ES_Command(cmd), values=_unpack(s, COMMANDS[cmd][0], buf, 3))


def _decode_answer(buf: bytes, dtype: int) -> Packet:
    """An RT packet (server → client) of data type Command: the answer to a request."""
    n = len(buf)
    if n < 16:
        raise _bad(f"answer of {n} bytes is shorter than BasicCommandRT (16)")
    _, _, cmd, status = _PREFIX4.unpack_from(buf)
    status = as_enum(ES_ResultStatus, status)
    if cmd not in COMMANDS:
        if n != 16:
            raise _bad(f"answer to unknown command {cmd} with lPacketSize {n} (expected 16)")
        return Packet("answer", dtype, command=cmd, status=status)
    s = _RT[cmd]
    cmd = ES_Command(cmd)
    if n == s.size:
        return Packet("answer", dtype, command=cmd, status=status,
                      values=_unpack(s, COMMANDS[cmd][1], buf, 4))
    if n == 16 and status != 0:  # a failed answer may be just the prefix (CPP-H reads only that)
        return Packet("answer", dtype, command=cmd, status=status)
    raise _bad(f"{cmd.name} answer (status {int(status)}): lPacketSize {n}, expected {s.size}")


def _decode_multi(buf: bytes, dtype: ES_DataType) -> Packet:
    n = len(buf)
    rec = RECORDS[dtype]
    if n < MULTI_HEAD or (n - MULTI_HEAD) % rec.itemsize:
        raise _bad(f"{dtype.name}: lPacketSize {n} is not {MULTI_HEAD} + {rec.itemsize}·n")
    count = (n - MULTI_HEAD) // rec.itemsize
    s = _RES[dtype]
    values = _unpack(s, RESULTS[dtype], buf, 3)
    if values["number_of_results"] != count:
        raise _bad(f"{dtype.name}: lNumberOfResults {values['number_of_results']} but lPacketSize {n} "
                   f"holds {count} records")
    status = as_enum(ES_ResultStatus, struct.unpack_from("<i", buf, 8)[0])
    records = np.frombuffer(buf, dtype=rec, count=count, offset=MULTI_HEAD)
    return Packet(_KINDS[dtype], dtype, status=status, values=values, records=records)
