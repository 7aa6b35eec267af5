"""Robot base adapter: the Rita line protocol over a serial port (pyserial).

URLs: ``serial:///dev/ttyUSB0?baudrate=115200`` (a local port, opened by path) and the
pyserial URL schemes ``socket://host:port``, ``rfc2217://host:port`` and ``loop://``
(passed to ``serial.serial_for_url`` as given, minus our own options). Our options (``baudrate``,
``timeout``, ``retries``, ``state_hz``, ``protocol``, ``stream_hz``: STATE/INCL samples published as
``robot.odometry``/``robot.incl``, drivers/robot_stream.py) and their defaults: docs/robot-protocol.md.

Robustness rules: every wait is bounded; a line with a bad checksum or no frame is counted and dropped,
never raised; a command whose reply does not come is resent with the *same* sequence number (the base
repeats, not re-executes, a duplicate MOVE/TURN), and when all tries fail the base is declared lost
(:class:`DeviceLost`), as it is when the port reports an error. See docs/robot-protocol.md.
"""
from __future__ import annotations

import contextlib
import threading
import time
from typing import Any
from urllib.parse import urlencode

import serial

from drivers import robot_protocol as rp
from drivers.robot_stream import StreamBatcher
from drivers.base import DeviceError, DeviceSettings, DeviceLost, DeviceTimeout, DeviceURL, Emit, Robot, RobotState, no_emit

#: longest single blocking read; keeps every loop responsive to its deadline
READ_SLICE_S = 0.02
#: the STATE stream rate asked by default (Hz of the base's clock): its samples show a move's odometry
DEFAULT_STREAM_HZ = 50.0

COUNTER_NAMES = ("rx_lines", "bad_checksum", "garbage", "syntax", "stale", "unexpected",
                 "retries", "naks", "events", "recovered_events", "overflows")


class SerialRobot(Robot):
    """A differential-drive base speaking the Rita line protocol over pyserial."""

    #: options this adapter reads itself (removed before pyserial sees the URL)
    OPTIONS = frozenset({"baudrate", "timeout", "retries", "state_hz", "protocol", "stream_hz"})
    #: pyserial's own URL options per scheme (pyserial/urlhandler), passed on to it as given
    PYSERIAL_OPTIONS: dict[str, frozenset[str]] = {
        "socket": frozenset({"logging"}), "loop": frozenset({"logging"}),
        "rfc2217": frozenset({"logging", "ign_set_control", "poll_modem"})}

    @classmethod
    def url_options(cls, url: DeviceURL) -> frozenset[str]:
        return cls.OPTIONS | cls.PYSERIAL_OPTIONS.get(url.scheme, frozenset())

    def __init__(self, url: DeviceURL, *, emit: Emit = no_emit,
                 settings: DeviceSettings = None) -> None:
        super().__init__(url, emit=emit, settings=settings)
        self.baudrate: int = url.option("baudrate", 115200, int)
        self.reply_timeout: float = url.option("timeout", 0.5, float)
        self.retries: int = url.option("retries", 2, int)
        self.state_hz: float = url.option("state_hz", 2.0, float)
        self.protocol: int = url.option("protocol", rp.PROTOCOL_VERSION, int)
        self.stream_hz: float = url.option("stream_hz", DEFAULT_STREAM_HZ, float)
        for name, value, ok in (("baudrate", self.baudrate, self.baudrate > 0),
                                ("timeout", self.reply_timeout, self.reply_timeout > 0),
                                ("retries", self.retries, 0 <= self.retries <= 20),
                                ("state_hz", self.state_hz, 0 <= self.state_hz <= 100),
                                ("protocol", self.protocol, self.protocol in rp.PROTOCOL_VERSIONS),
                                ("stream_hz", self.stream_hz, rp.state_rate_error(self.stream_hz) is None)):
            if not ok:
                raise ValueError(f"robot URL {url.raw!r}: option {name}={value!r} is out of range")
        if url.scheme == "serial" and not url.path:
            raise ValueError(f"robot URL {url.raw!r} names no device path (serial:///dev/ttyUSB0)")
        self._port: Any = None
        self._port_lock = threading.Lock()  # wake() (any thread) against close()
        self._woken = False
        self._target = ""
        self._splitter = rp.LineSplitter()
        self._seq = 0
        self._moving_seq: int | None = None
        self._finished_seq: int | None = None
        self._last_state: RobotState | None = None
        self._last_state_emit = 0.0
        self._version: dict[str, Any] = {}
        self._streaming = False
        self.counters: dict[str, int] = dict.fromkeys(COUNTER_NAMES, 0)
        self._batcher = StreamBatcher(self.emit)

    # ------------------------------------------------------------------ connection

    def port_target(self) -> str:
        """What to hand to ``serial.serial_for_url``: a device path or a pyserial URL."""
        if self.url.scheme == "serial":
            return self.url.path
        # cut the query off by hand: urlunsplit would turn "loop://" into "loop:"
        base = self.url.raw.split("?", 1)[0].split("#", 1)[0]
        rest = {k: v for k, v in self.url.query.items() if k not in self.OPTIONS}
        return f"{base}?{urlencode(rest)}" if rest else base

    def open(self) -> None:
        """Open the port, drop stale input, shake hands (HELLO/VERSION) and read STATUS."""
        self.close()
        target = self._target = self.port_target()
        try:
            self._port = serial.serial_for_url(target, baudrate=self.baudrate, timeout=READ_SLICE_S,
                                               write_timeout=self.reply_timeout)
            self._port.reset_input_buffer()
        except (serial.SerialException, OSError) as exc:
            self._port = None
            raise DeviceLost(f"cannot open robot port {target!r}: {exc}") from exc
        self._splitter.clear()
        self._batcher.clear()
        self._streaming = False
        # _moving_seq survives a reconnect on purpose: if that motion ended meanwhile,
        # the first STATUS below publishes the DONE/FAULT that was lost with the port
        self._hello()
        if self.stream_hz > 0 and rp.CAP_STATE in self._version["capabilities"]:
            self._streaming = True  # before the ACK: samples may follow it in the same read
            try:
                self._transact("STATE", rp.num(self.stream_hz), expect="ACK")
            except DeviceLost:
                raise
            except DeviceError:  # refused: the base is driven without its streams, as a version-1 one
                self._streaming = False
        state = self.status()
        if state.state == "MOVING" and self._moving_seq is None:
            self._moving_seq = -1  # a motion from before we connected: wait_idle polls it out

    def _hello(self) -> None:
        """HELLO with the newest protocol offered; a base that refuses it (NAK VERSION) is asked for 1."""
        try:
            reply = self._transact("HELLO", self.protocol, expect="VERSION")
        except DeviceError as exc:
            if exc.code != "robot_version" or self.protocol == 1:
                self.close()
                raise
            reply = self._transact("HELLO", 1, expect="VERSION")  # a version-1 base
        try:
            self._version = {"protocol": int(reply.field(1, "protocol")), "model": reply.field(2, "model"),
                             "firmware": reply.field(3, "firmware"), "serial": reply.field(4, "serial"),
                             "capabilities": rp.capabilities(reply.field(5, "capabilities"))}
        except (rp.ProtocolError, ValueError) as exc:
            self.close()
            raise DeviceError(f"robot base sent a malformed VERSION: {exc}", code="robot_protocol") from exc
        if self._version["protocol"] not in rp.PROTOCOL_VERSIONS or self._version["protocol"] > self.protocol:
            self.close()
            raise DeviceError(f"robot base speaks protocol {self._version['protocol']}, "
                              f"driver speaks {'/'.join(map(str, rp.PROTOCOL_VERSIONS))}", code="robot_version")
        if self._version["protocol"] < 2:  # what a version-1 base may say of clock and streams is not ours
            self._version["capabilities"] = [c for c in self._version["capabilities"] if c == rp.CAP_INCL]

    def streams(self) -> list[str]:
        """The telemetry topics of the sample streams this base sends (empty without STATE)."""
        if not self._streaming:
            return []
        return ["robot.odometry"] + (["robot.incl"] if rp.CAP_INCL in self._version["capabilities"] else [])

    def close(self) -> None:
        with self._port_lock:
            port, self._port = self._port, None
        with contextlib.suppress(Exception):  # close must never raise; the port may be gone
            if port is not None:
                port.close()

    def wake(self) -> None:
        """A job is queued: pump returns now, its read cut short by pyserial's ``cancel_read``, not up to a
        read slice past its timeout (a command's wait for the owner thread)."""
        self._woken = True
        with self._port_lock, contextlib.suppress(Exception):  # no port, or no cancel_read: pump's timeout
            self._port.cancel_read()

    def info(self) -> dict[str, Any]:
        return {"url": self.url.raw, "port": self._target, **self._version, "streams": self.streams(),
                "counters": {**self.counters, **self._batcher.counters}}

    # ------------------------------------------------------------------ commands

    def move(self, distance_mm: float, speed_mm_s: float) -> None:
        """Start a straight move; returns once the base ACKed it (DONE comes later)."""
        _check("distance_mm", distance_mm, -rp.MAX_DISTANCE_MM, rp.MAX_DISTANCE_MM)
        _check("speed_mm_s", speed_mm_s, rp.MIN_SPEED_MM_S, rp.MAX_SPEED_MM_S)
        self._start_motion("MOVE", float(distance_mm), float(speed_mm_s))

    def turn(self, angle_deg: float, speed_deg_s: float) -> None:
        """Start a turn on the spot (positive = counter-clockwise); returns on ACK."""
        _check("angle_deg", angle_deg, -rp.MAX_ANGLE_DEG, rp.MAX_ANGLE_DEG)
        _check("speed_deg_s", speed_deg_s, rp.MIN_TURN_SPEED_DEG_S, rp.MAX_TURN_SPEED_DEG_S)
        self._start_motion("TURN", float(angle_deg), float(speed_deg_s))

    def _start_motion(self, kind: str, value: float, speed: float) -> None:
        reply = self._transact(kind, rp.num(value), rp.num(speed), expect="ACK")
        seq = reply.seq()
        # with an instant base the DONE may already have been read while waiting
        self._moving_seq = None if self._finished_seq == seq else seq

    def stop(self) -> None:
        """Send STOP at once (the base always accepts it); DONE STOPPED follows."""
        self._transact("STOP", expect="ACK")

    def status(self) -> RobotState:
        """Poll STATUS; also publishes ``robot.state`` at most ``state_hz`` times a second."""
        reply = self._transact("STATUS", expect="STATUS")
        try:
            state = RobotState(state=reply.field(1, "state"), x_mm=reply.number(2, "x_mm"),
                               y_mm=reply.number(3, "y_mm"), heading_deg=reply.number(4, "heading_deg"),
                               roll_deg=reply.optional_number(5, "roll_deg"),
                               pitch_deg=reply.optional_number(6, "pitch_deg"),
                               battery_v=reply.optional_number(7, "battery_v"),
                               fault=reply.fields[8] if len(reply.fields) > 8 else "",
                               t_us=rp.device_us(reply, 9) if self._clock and len(reply.fields) > 9 else None)
        except rp.ProtocolError as exc:
            raise DeviceError(f"robot base sent a malformed STATUS: {exc}", code="robot_protocol") from exc
        if state.state not in ("IDLE", "MOVING", "FAULT"):
            raise DeviceError(f"robot base reports unknown state {state.state!r}", code="robot_protocol")
        if state.state != "MOVING" and self._moving_seq is not None:
            self._recover_event(state)
        self._last_state = state
        now = time.monotonic()
        if self.state_hz > 0 and now - self._last_state_emit >= 1.0 / self.state_hz:
            self._last_state_emit = now
            self.emit("robot.state", state.to_dict())
        return state

    def _recover_event(self, state: RobotState) -> None:
        """The motion is over but its DONE/FAULT never arrived (lost on the line, or
        sent while we were reconnecting): publish one from STATUS so that nobody
        waiting for it hangs. ``recovered`` marks it; the result is not known."""
        seq = self._moving_seq if self._moving_seq and self._moving_seq > 0 else None
        self._moving_seq = None
        self.counters["recovered_events"] += 1
        payload: dict[str, Any] = {"event": "DONE", "seq": seq, "host_time_ns": time.time_ns(), "recovered": True}
        if state.state == "FAULT":
            payload.update(event="FAULT", reason=state.fault, text="event lost; state read from STATUS")
        else:
            payload.update(result="UNKNOWN", x_mm=state.x_mm, y_mm=state.y_mm, heading_deg=state.heading_deg)
        self.emit("robot.event", payload)

    @property
    def _clock(self) -> bool:
        return rp.CAP_CLOCK in self._version.get("capabilities", ())

    @property
    def last_state(self) -> RobotState | None:
        """The most recent STATUS reply (no I/O)."""
        return self._last_state

    def pump(self, timeout: float) -> None:
        """Read events for ``timeout`` s, polling STATUS when a ``state_hz`` slot is due."""
        deadline = time.monotonic() + max(0.0, timeout)
        while True:
            now = time.monotonic()
            if self.state_hz > 0 and now - self._last_state_emit >= 1.0 / self.state_hz:
                self.status()
                now = time.monotonic()
            if now >= deadline or self._woken:
                self._woken = False
                self._batcher.flush(force=True)
                return
            for msg in self._receive(min(deadline, now + READ_SLICE_S), wakeable=True):
                self._count_stray(msg)

    def wait_idle(self, timeout: float) -> RobotState:
        """Pump until the current motion is over; returns the final state.

        Raises DeviceTimeout when the base is still moving after ``timeout`` s, and
        DeviceError (code ``robot_fault``) when the motion ended in a FAULT.
        """
        deadline = time.monotonic() + timeout
        next_check = 0.0
        while True:
            now = time.monotonic()
            if self._moving_seq is None or now >= next_check:
                state = self.status()
                if state.state == "FAULT":
                    raise DeviceError(f"robot base FAULT: {state.fault or 'no reason given'}",
                                      code="robot_fault")
                if state.state == "IDLE":
                    return state
                next_check = time.monotonic() + 0.1
            if time.monotonic() >= deadline:
                raise DeviceTimeout(f"robot base still moving after {timeout:.3g} s")
            for msg in self._receive(min(deadline, next_check, time.monotonic() + 0.05)):
                self._count_stray(msg)

    # ------------------------------------------------------------------ line level

    def _transact(self, kind: str, *fields: object, expect: str) -> rp.Message:
        """Send one command and return its positive reply; NAK → DeviceError."""
        self._seq = rp.next_seq(self._seq)
        seq = self._seq
        line = rp.encode(kind, seq, *fields)
        for attempt in range(self.retries + 1):
            if attempt:
                self.counters["retries"] += 1
            self._write(line)
            deadline = time.monotonic() + self.reply_timeout
            resend = False
            while not resend and time.monotonic() < deadline:
                got = self._receive(deadline)
                for i, msg in enumerate(got):
                    reply_seq = msg.seq() if msg.kind in rp.REPLIES else -1
                    if reply_seq is None and msg.fields[1:2] == ("CHECKSUM",):
                        resend = True  # the base got a corrupted line, most likely ours
                    elif reply_seq != seq:
                        self._count_stray(msg)
                    elif msg.kind == "NAK":
                        self.counters["naks"] += 1
                        reason = msg.fields[1] if len(msg.fields) > 1 else "?"
                        text = msg.fields[2] if len(msg.fields) > 2 else ""
                        raise DeviceError(f"robot base refused {line.decode().strip()}: {reason} {text}".strip(),
                                          code=f"robot_{reason.lower()}")
                    elif msg.kind != expect:
                        self.counters["unexpected"] += 1
                    else:
                        for rest in got[i + 1:]:  # read in the same chunk after our reply: strays, counted
                            self._count_stray(rest)
                        return msg
        raise DeviceLost(f"robot base did not answer {kind} (seq {seq}) in "
                         f"{self.retries + 1} tries of {self.reply_timeout:.3g} s")

    def _write(self, line: bytes) -> None:
        if self._port is None:
            raise DeviceLost("robot port is not open")
        try:
            self._port.write(line)
        except (serial.SerialException, OSError) as exc:
            raise DeviceLost(f"robot port write failed: {exc}") from exc

    def _receive(self, deadline: float, wakeable: bool = False) -> list[rp.Message]:
        """Replies read before ``deadline`` (events are dispatched here, not returned); returns as soon as
        a reply arrived (or, ``wakeable``, :meth:`wake` was called). Bad lines are counted, not raised."""
        if self._port is None:
            raise DeviceLost("robot port is not open")
        replies: list[rp.Message] = []
        while True:
            try:
                data = self._port.read(max(1, self._port.in_waiting))
            except (serial.SerialException, OSError) as exc:
                raise DeviceLost(f"robot port read failed: {exc}") from exc
            rx_ns = time.time_ns()
            for raw in self._splitter.feed(data):
                msg = self._decode(raw, rx_ns)
                if msg is not None and self._dispatch_event(msg, rx_ns) is not None:
                    replies.append(msg)
            self.counters["overflows"] = self._splitter.overflows
            self._batcher.flush()
            if replies or time.monotonic() >= deadline or wakeable and self._woken:
                return replies

    def _decode(self, raw: bytes, rx_ns: int) -> rp.Message | None:
        """The line's message; None for a blank or a bad line (counted) and for a sample (batched)."""
        if not raw.strip():
            return None
        self.counters["rx_lines"] += 1
        if self._streaming and self._batcher.take(raw, rx_ns):  # most lines: no Message made for them
            return None
        try:
            msg = rp.decode(raw)
            if msg.kind in rp.REPLIES or msg.kind in rp.EVENTS:
                msg.seq()  # validate early so callers can rely on it
            return msg
        except rp.ProtocolError as exc:
            self.counters[{"checksum": "bad_checksum", "garbage": "garbage"}.get(exc.kind, "syntax")] += 1
            return None

    def _dispatch_event(self, msg: rp.Message, rx_ns: int) -> rp.Message | None:
        """Publish DONE/FAULT events and batch samples; returns the message back when it is neither."""
        if msg.kind in rp.STREAMS and self._streaming:
            try:
                self._batcher.add(msg, rx_ns)
            except rp.ProtocolError:
                self.counters["syntax"] += 1
            return None
        if msg.kind not in rp.EVENTS:
            return msg
        seq = msg.seq()
        payload: dict[str, Any] = {"event": msg.kind, "seq": seq, "host_time_ns": time.time_ns()}
        try:
            if msg.kind == "DONE":
                payload.update(result=msg.field(1, "result"), x_mm=msg.number(2, "x_mm"),
                               y_mm=msg.number(3, "y_mm"), heading_deg=msg.number(4, "heading_deg"))
            else:
                payload.update(reason=msg.field(1, "reason"),
                               text=msg.fields[2] if len(msg.fields) > 2 else "")
        except rp.ProtocolError:
            self.counters["syntax"] += 1
            return None
        self.counters["events"] += 1
        self._finished_seq = seq
        if seq is None or seq == self._moving_seq or self._moving_seq == -1:
            self._moving_seq = None  # (-1: a motion started before we connected)
        self.emit("robot.event", payload)
        return None

    def _count_stray(self, msg: rp.Message) -> None:
        # a late reply to a command we already gave up on, or something not for us
        self.counters["stale" if msg.kind in rp.REPLIES else "unexpected"] += 1


def _check(name: str, value: float, low: float, high: float) -> None:
    """Refuse a motion argument outside the protocol limits before it is sent."""
    if (why := rp.range_error(name, value, low, high)) is not None:
        raise DeviceError(f"robot: {why}", code="robot_range")
