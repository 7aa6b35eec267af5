"""Line codec for the Rita base protocol (see docs/robot-protocol.md).

A message is one ASCII line ``$KIND,field,field*CS\\r\\n``: ``CS`` is the XOR of every
byte between ``$`` and ``*`` as two hex digits, as in NMEA 0183. This module only
turns lines into :class:`Message` objects and back; it knows the command names and
limits so that both the driver and the fake base share one definition of them.
Nothing here touches a port.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

PROTOCOL_VERSION = 1
#: longest line accepted, terminator included; longer input is garbage
MAX_LINE = 160
#: sequence numbers run 1..SEQ_MAX and wrap back to 1 (0 is never used)
SEQ_MAX = 9999

#: host → base commands
COMMANDS = ("HELLO", "MOVE", "TURN", "STOP", "STATUS")
#: base → host replies (each carries the seq of the command it answers)
REPLIES = ("ACK", "NAK", "VERSION", "STATUS")
#: base → host asynchronous events
EVENTS = ("DONE", "FAULT")

#: NAK reasons
NAK_REASONS = ("CHECKSUM", "SYNTAX", "UNKNOWN", "RANGE", "BUSY", "FAULT", "VERSION")

# Motion limits the base enforces (and the driver checks before sending).
MAX_DISTANCE_MM = 5000.0
MIN_SPEED_MM_S = 1.0
MAX_SPEED_MM_S = 300.0
MAX_ANGLE_DEG = 720.0
MIN_TURN_SPEED_DEG_S = 1.0
MAX_TURN_SPEED_DEG_S = 90.0

_FIELD_FORBIDDEN = set("$*,\r\n")


class ProtocolError(ValueError):
    """A line that is not a well-formed message; ``kind`` says how it failed.

    ``kind`` is ``"garbage"`` (no frame, not ASCII, too long), ``"checksum"`` (framed
    but the checksum does not match) or ``"syntax"`` (valid frame, bad content).
    """

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


@dataclass(frozen=True)
class Message:
    """A decoded line: its kind (first field) and the remaining fields as text."""

    kind: str
    fields: tuple[str, ...] = ()

    def field(self, index: int, name: str) -> str:
        """Field ``index`` (0 = first after the kind); a missing one raises ProtocolError."""
        if index >= len(self.fields):
            raise ProtocolError("syntax", f"{self.kind}: missing field {index + 1} ({name}) in {self.body()!r}")
        return self.fields[index]

    def number(self, index: int, name: str) -> float:
        """Field ``index`` as a finite float, or ProtocolError naming the bad value."""
        text = self.field(index, name)
        try:
            value = float(text)
        except ValueError:
            raise ProtocolError("syntax", f"{self.kind}: {name}={text!r} is not a number") from None
        if not math.isfinite(value):
            raise ProtocolError("syntax", f"{self.kind}: {name}={text!r} is not finite")
        return value

    def optional_number(self, index: int, name: str) -> float | None:
        """Like :meth:`number`, but an empty or absent field is ``None``."""
        if index >= len(self.fields) or self.fields[index] == "":
            return None
        return self.number(index, name)

    def seq(self) -> int | None:
        """The sequence number (first field); ``None`` when empty (e.g. NAK CHECKSUM)."""
        text = self.field(0, "seq")
        if text == "":
            return None
        if not text.isdigit() or not 1 <= int(text) <= SEQ_MAX:
            raise ProtocolError("syntax", f"{self.kind}: seq={text!r} is not an integer 1..{SEQ_MAX}")
        return int(text)

    def body(self) -> str:
        return ",".join((self.kind, *self.fields))


def checksum(body: str | bytes) -> str:
    """NMEA-style checksum of ``body`` (the text between ``$`` and ``*``): two hex digits."""
    data = body.encode("ascii") if isinstance(body, str) else body
    value = 0
    for byte in data:
        value ^= byte
    return f"{value:02X}"


def num(value: float, decimals: int = 6) -> str:
    """Compact decimal text for a number: fixed point, trailing zeros removed."""
    if not math.isfinite(value):
        raise ValueError(f"cannot send non-finite number {value!r}")
    text = f"{value:.{decimals}f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def encode(kind: str, *fields: object) -> bytes:
    """One framed line for ``kind`` and ``fields``; floats are written with :func:`num`.

    ``None`` becomes an empty field. A field containing a framing character raises
    ValueError naming it, so a caller can never produce a line that would misparse.
    """
    parts = [kind]
    for f in fields:
        if f is None:
            text = ""
        elif isinstance(f, float):
            text = num(f)
        else:
            text = str(f)
        bad = _FIELD_FORBIDDEN.intersection(text)
        if bad or not text.isascii():
            raise ValueError(f"{kind}: field {text!r} contains a framing or non-ASCII character")
        parts.append(text)
    body = ",".join(parts)
    line = f"${body}*{checksum(body)}\r\n".encode("ascii")
    if len(line) > MAX_LINE:
        raise ValueError(f"{kind}: line of {len(line)} bytes exceeds the {MAX_LINE}-byte limit")
    return line


def decode(line: bytes) -> Message:
    """Parse one line (with or without its terminator) into a Message.

    Raises ProtocolError: ``garbage`` when there is no ``$…*HH`` frame, ``checksum``
    when the checksum does not match, ``syntax`` when the kind is not an upper-case
    word. Whether the kind is a *known* message is for the caller to decide.
    """
    if len(line) > MAX_LINE:
        raise ProtocolError("garbage", f"line of {len(line)} bytes exceeds {MAX_LINE}: {line[:40]!r}…")
    stripped = line.rstrip(b"\r\n")
    try:
        text = stripped.decode("ascii")
    except UnicodeDecodeError:
        raise ProtocolError("garbage", f"non-ASCII bytes in line {stripped[:60]!r}") from None
    if not text.isprintable():
        raise ProtocolError("garbage", f"control characters in line {stripped[:60]!r}")
    star = text.rfind("*")
    if not text.startswith("$") or star < 0 or len(text) - star != 3:
        raise ProtocolError("garbage", f"not a '$BODY*HH' frame: {text[:60]!r}")
    body, given = text[1:star], text[star + 1:].upper()
    if any(c not in "0123456789ABCDEF" for c in given):
        raise ProtocolError("garbage", f"checksum {given!r} is not two hex digits in {text[:60]!r}")
    if "$" in body or "*" in body:
        raise ProtocolError("garbage", f"framing character inside the body of {text[:60]!r}")
    expected = checksum(body)
    if given != expected:
        raise ProtocolError("checksum", f"checksum {given} != computed {expected} for {body[:60]!r}")
    kind, *fields = body.split(",")
    if not kind.isalpha() or not kind.isupper():
        raise ProtocolError("syntax", f"message kind {kind!r} is not an upper-case word in {body[:60]!r}")
    return Message(kind, tuple(fields))


class LineSplitter:
    """Reassembles lines from a byte stream; over-long runs are dropped as garbage.

    ``feed`` returns complete lines (terminator removed, ``\\r`` stripped) and
    ``overflows`` counts the runs discarded because no newline came within
    :data:`MAX_LINE` bytes — a hung or noisy line must not grow memory.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._skipping = False
        self.overflows = 0

    def feed(self, data: bytes) -> list[bytes]:
        out: list[bytes] = []
        self._buf.extend(data)
        while True:
            nl = self._buf.find(b"\n")
            if nl < 0:
                if len(self._buf) > MAX_LINE:
                    if not self._skipping:
                        self.overflows += 1
                    self._skipping = True
                    self._buf.clear()
                return out
            line = bytes(self._buf[:nl]).rstrip(b"\r")
            del self._buf[:nl + 1]
            if self._skipping:  # tail of an over-long run: already counted
                self._skipping = False
                continue
            out.append(line)

    def clear(self) -> None:
        self._buf.clear()
        self._skipping = False


def text_field(text: str, limit: int = 60) -> str:
    """Free text made safe for one field: framing characters become spaces, cut to ``limit``."""
    clean = "".join(" " if c in _FIELD_FORBIDDEN or not c.isprintable() or not c.isascii() else c
                    for c in text)
    return clean[:limit]


def next_seq(seq: int) -> int:
    """The sequence number after ``seq`` (wraps SEQ_MAX → 1)."""
    return seq + 1 if seq < SEQ_MAX else 1
