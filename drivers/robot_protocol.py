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

#: the newest protocol this codec speaks; a host or base of version 1 or 2 is served as before
PROTOCOL_VERSION = 3
PROTOCOL_VERSIONS = (1, 2, 3)
#: longest line accepted, terminator included; longer input is garbage
MAX_LINE = 160
#: sequence numbers run 1..SEQ_MAX and wrap back to 1 (0 is never used)
SEQ_MAX = 9999

#: host → base commands (STATE since version 2)
COMMANDS = ("HELLO", "MOVE", "TURN", "STOP", "STATUS", "STATE")
#: the commands that start a motion (refused by the host while its stop is latched)
MOTIONS = ("MOVE", "TURN")
#: base → host replies (each carries the seq of the command it answers)
REPLIES = ("ACK", "NAK", "VERSION", "STATUS")
#: base → host asynchronous events (their first field is the motion's seq)
EVENTS = ("DONE", "FAULT")
#: base → host periodic samples (version 2, after a STATE command): no seq, the base's time first
STREAMS = ("STATE", "INCL")

#: VERSION capabilities: an inclinometer (STATUS roll/pitch; v1 too), the base's clock in STATUS
#: (v2), the STATE command and its sample streams (v2)
CAP_INCL, CAP_CLOCK, CAP_STATE = "INCL", "CLOCK", "STATE"
#: VERSION capability (v3): the host watchdog; a motion halts with FAULT HOST_LOST when no valid host
#: line came within the host timeout agreed at HELLO
CAP_WATCHDOG = "WATCHDOG"
#: the host timeout (ms) a version-3 HELLO asks when it names none, and the range a base accepts.
#: 300 ms: a host that keeps the link alive every 100 ms may miss two of them under load without a
#: false halt, and a base whose host died drives at most 0.3 s on (15 mm at the procedures' 50 mm/s,
#: 90 mm at the protocol's 300 mm/s limit) before it halts itself
DEFAULT_HOST_TIMEOUT_MS = 300
MIN_HOST_TIMEOUT_MS, MAX_HOST_TIMEOUT_MS = 50, 5000
#: the FAULT reason of a motion the host watchdog halted
FAULT_HOST_LOST = "HOST_LOST"
#: every FAULT reason a base may report (docs/robot-protocol.md, "Fault reasons")
FAULT_REASONS = ("STALL", FAULT_HOST_LOST, "ESTOP", "DRIVER", "BATTERY")
#: STATE stream rates (Hz) a base accepts besides 0 (off): 100 Hz of ~80-byte STATE lines is
#: 8 kB/s, under 70 % of a 115200-baud line, with room left for INCL, replies and events
MIN_STATE_HZ = 1.0
MAX_STATE_HZ = 100.0

#: the boot window (s): a base answers HELLO at most this long after its power-on or reset (its
#: bootloader's wait and its own start-up); the host asks again until it is over
BOOT_S = 3.0

#: timing the host relies on (docs/robot-protocol.md, "Timing"): a base starts its reply within
#: REPLY_BUDGET_S of the command's last byte; a USB-serial adapter may hold received bytes up to its
#: latency timer (FTDI's default: 16 ms, FTDI application note AN232B-04) before the host sees them
REPLY_BUDGET_S = 0.020
USB_LATENCY_S = 0.016
#: STOP (and a watchdog halt, a FAULT) brakes at least this hard: at 300 mm/s the wheels stand within 90 mm
STOP_DECEL_MM_S2 = 500.0
STOP_DECEL_DEG_S2 = 180.0
#: a base's receive buffer holds at least this many bytes: a command, an owed STOP and a keep-alive STATUS
RX_BUFFER_BYTES = 3 * MAX_LINE

#: a version-1 STATUS reply's fields after its kind (seq, state, x, y, heading, roll, pitch, battery, fault);
#: a version-2 or 3 one adds t_us
STATUS_V1_FIELDS = 9

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
            raise ProtocolError("syntax",
                                f"{self.kind}: missing field {index + 1} ({name}) in {self.body()!r}")
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


@dataclass(frozen=True)
class StateSample:
    """A ``$STATE`` event: odometry pose and wheel speeds at the base's time ``t_us``."""

    t_us: int
    x_mm: float
    y_mm: float
    heading_deg: float
    v_left_mm_s: float
    v_right_mm_s: float

    def encode(self) -> bytes:
        return encode("STATE", self.t_us, num(self.x_mm, 4), num(self.y_mm, 4), num(self.heading_deg, 6),
                      num(self.v_left_mm_s, 3), num(self.v_right_mm_s, 3))

    @classmethod
    def decode(cls, msg: Message) -> "StateSample":
        return cls(device_us(msg, 0),
                   msg.number(1, "x_mm"), msg.number(2, "y_mm"), msg.number(3, "heading_deg"),
                   msg.number(4, "v_left_mm_s"), msg.number(5, "v_right_mm_s"))


@dataclass(frozen=True)
class InclSample:
    """An ``$INCL`` event: the inclinometer's roll and pitch (deg) at the base's time ``t_us``."""

    t_us: int
    roll_deg: float
    pitch_deg: float

    def encode(self) -> bytes:
        return encode("INCL", self.t_us, num(self.roll_deg, 6), num(self.pitch_deg, 6))

    @classmethod
    def decode(cls, msg: Message) -> "InclSample":
        return cls(device_us(msg, 0), msg.number(1, "roll_deg"), msg.number(2, "pitch_deg"))


def device_us(msg: Message, index: int, name: str = "t_us") -> int:
    """Field ``index`` as the base's clock (µs): a non-negative integer, or ProtocolError."""
    text = msg.field(index, name)
    if not text.isdigit() or len(text) > 19:
        raise ProtocolError("syntax", f"{msg.kind}: {name}={text!r} is not a non-negative integer (µs)")
    return int(text)


def state_rate_error(rate_hz: float) -> str | None:
    """Why a STATE rate is refused (the text names the value), or None when it is 0 or in range."""
    if rate_hz == 0 or MIN_STATE_HZ <= rate_hz <= MAX_STATE_HZ:
        return None
    return f"STATE rate_hz={num(rate_hz)} outside 0 (off) or {num(MIN_STATE_HZ)}..{num(MAX_STATE_HZ)}"


def host_timeout_error(timeout_ms: float) -> str | None:
    """Why a HELLO's host timeout is refused (the text names the value), or None when in range."""
    if MIN_HOST_TIMEOUT_MS <= timeout_ms <= MAX_HOST_TIMEOUT_MS:
        return None
    return f"HELLO host_timeout_ms={num(timeout_ms)} outside {MIN_HOST_TIMEOUT_MS}..{MAX_HOST_TIMEOUT_MS}"


def range_error(name: str, value: float, low: float, high: float) -> str | None:
    """Why a motion argument is refused (the text names it), None when it is within ``low..high``."""
    try:
        if low <= float(value) <= high:
            return None
    except (TypeError, ValueError):
        pass
    return f"{name}={value!r} is outside {low:g}..{high:g}"


def capabilities(field: str) -> list[str]:
    """The ``+``-separated capability flags of a VERSION reply (empty field: none)."""
    return [c for c in field.split("+") if c]


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
