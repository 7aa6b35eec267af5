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

Stop rules (the motion gate, drivers/motion_gate.py, is this adapter's ``settings``): a halt the gate
owes goes out ahead of any pending reply (drivers/robot_line.py); while latched, STOP is the first
command after HELLO on every connect and no motion line is written. A version-3 base gets the host
timeout at HELLO and a line at least every third of it while a motion runs; a base found MOVING at
connect with no motion of this adapter's is halted; :meth:`SerialRobot.park` halts a moving base.
"""
from __future__ import annotations

import contextlib
import logging
import threading
import time
from typing import Any
from urllib.parse import urlencode

import serial

from drivers import robot_protocol as rp
from drivers.base import DeviceError, DeviceSettings, DeviceLost, DeviceURL, Emit, Robot
from drivers.base import RobotState, no_emit
from drivers.motion_gate import MotionGate
from drivers.robot_line import READ_SLICE_S, RETRIES, NoReply, RobotLine
from drivers.robot_port import open_error, open_port

log = logging.getLogger(__name__)

#: the STATE stream rate asked by default (Hz of the base's clock): its samples show a move's odometry
DEFAULT_STREAM_HZ = 50.0
#: keep-alive lines per host timeout while a motion runs: two may be late or lost without a false halt
KEEPALIVES_PER_TIMEOUT = 3
#: the shortest host timeout this host asks: a third of it is still a few read slices
MIN_HOST_TIMEOUT_S = 0.15
NO_WATCHDOG = "this base has no host watchdog: a daemon crash lets a move finish"


class SerialRobot(RobotLine, Robot):
    """A differential-drive base speaking the Rita line protocol over pyserial."""

    #: options this adapter reads itself (removed before pyserial sees the URL)
    OPTIONS = frozenset({"baudrate", "timeout", "retries", "state_hz", "protocol", "stream_hz",
                         "host_timeout", "dtr", "rts", "boot"})
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
        self.retries: int = url.option("retries", RETRIES, int)
        self.state_hz: float = url.option("state_hz", 2.0, float)
        self.protocol: int = url.option("protocol", rp.PROTOCOL_VERSION, int)
        self.stream_hz: float = url.option("stream_hz", DEFAULT_STREAM_HZ, float)
        self.host_timeout: float = url.option("host_timeout", rp.DEFAULT_HOST_TIMEOUT_MS / 1000.0, float)
        self.dtr: int = url.option("dtr", 0, int)  # held low: an Arduino-class base resets on DTR
        self.rts: int = url.option("rts", 0, int)
        self.boot_s: float = url.option("boot", rp.BOOT_S, float)  # HELLO retried this long after open
        for name, value, ok in (("baudrate", self.baudrate, self.baudrate > 0),
                                ("timeout", self.reply_timeout, self.reply_timeout > 0),
                                ("retries", self.retries, 0 <= self.retries <= 20),
                                ("state_hz", self.state_hz, 0 <= self.state_hz <= 100),
                                ("protocol", self.protocol, self.protocol in rp.PROTOCOL_VERSIONS),
                                ("stream_hz", self.stream_hz, rp.state_rate_error(self.stream_hz) is None),
                                ("host_timeout", self.host_timeout,  # kept alive at a third of it
                                 MIN_HOST_TIMEOUT_S <= self.host_timeout <= rp.MAX_HOST_TIMEOUT_MS / 1000),
                                ("dtr", self.dtr, self.dtr in (0, 1)), ("rts", self.rts, self.rts in (0, 1)),
                                ("boot", self.boot_s, 0 <= self.boot_s <= 60)):
            if not ok:
                raise ValueError(f"robot URL {url.raw!r}: option {name}={value!r} is out of range")
        if url.scheme == "serial" and not url.path:
            raise ValueError(f"robot URL {url.raw!r} names no device path (serial:///dev/ttyUSB0)")
        self._init_line(settings if isinstance(settings, MotionGate) else MotionGate())
        self.gate.bind(self.wake)
        self._port_lock = threading.Lock()  # wake() (any thread) against close()
        self._starting = False  # a MOVE/TURN written, its ACK not yet read
        self._target = ""
        self._last_state_emit = 0.0
        self._version: dict[str, Any] = {}
        self._opened_at = 0.0
        self._last_t_us = -1  # the base's clock at its last STATUS: a step back means it restarted

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
        """Open the port, drop stale input, shake hands (HELLO/VERSION), STOP first while latched, halt a
        motion that is not ours, start the streams and read STATUS."""
        self.close()
        self._version = {}
        target = self._target = self.port_target()
        try:
            self._port = open_port(target, self.url.scheme, baudrate=self.baudrate, timeout=READ_SLICE_S,
                                   write_timeout=self.reply_timeout, dtr=bool(self.dtr), rts=bool(self.rts))
            self._port.reset_input_buffer()
        except (serial.SerialException, OSError) as exc:
            self._port = None
            raise DeviceLost(open_error(target, exc)) from exc
        self._opened_at = time.monotonic()
        self._last_t_us = -1
        self._splitter.clear()
        self._batcher.clear()
        self._streaming = False
        if self._halt is not None:  # a new connection: an owed STOP goes out at once, before the HELLO
            self._halt.resend_at = 0.0
        # _moving_seq survives a reconnect on purpose: if that motion ended meanwhile,
        # the first STATUS below publishes the DONE/FAULT that was lost with the port
        self._hello()
        self._halt_first()
        state = self.status()
        if state.state == "MOVING" and self._moving_seq is None:
            self._halt_unowned(state)
        if self.stream_hz > 0 and rp.CAP_STATE in self._version["capabilities"]:
            self._streaming = True  # before the ACK: samples may follow it in the same read
            try:
                self._transact("STATE", rp.num(self.stream_hz), expect="ACK")
            except DeviceLost:
                raise
            except DeviceError:  # refused: the base is driven without its streams, as a version-1 one
                self._streaming = False

    def _halt_unowned(self, state: RobotState) -> None:
        """A base MOVING at connect with no motion of ours (a previous daemon's, or a crashed one's) is
        driving unowned: halt it, and say so in the journal and on the bus."""
        why = ("robot base was MOVING at connect with no motion of this daemon's (a previous daemon's "
               "move?): halted")
        log.warning("%s at odometry (%.1f, %.1f) mm", why, state.x_mm, state.y_mm)
        self._moving_seq = -1  # its DONE STOPPED (or a recovered one) ends it
        self.emit("robot.event", {"event": "HALTED", "reason": "unowned_motion", "text": why,
                                  "host_time_ns": time.time_ns()})  # before the DONE the STOP brings
        self._transact("STOP", expect="ACK")

    def _hello(self) -> None:
        """HELLO with the newest protocol offered; a base that refuses it (NAK VERSION) is asked for the
        next older one. Version 3 also agrees the host timeout; an older base is warned about."""
        reply: rp.Message | None = None
        for protocol in range(self.protocol, 0, -1):
            extra = (rp.num(self.host_timeout * 1000.0, 0),) if protocol >= 3 else ()
            try:
                reply = self._first_reply(protocol, *extra)
                break
            except DeviceError as exc:
                if exc.code != "robot_version" or protocol == 1:
                    self.close()
                    raise
        assert reply is not None  # the loop ends on a reply or raises
        try:
            self._version = {"protocol": int(reply.field(1, "protocol")), "model": reply.field(2, "model"),
                             "firmware": reply.field(3, "firmware"), "serial": reply.field(4, "serial"),
                             "capabilities": rp.capabilities(reply.field(5, "capabilities")),
                             "host_timeout_ms": reply.optional_number(6, "host_timeout_ms")}
        except (rp.ProtocolError, ValueError) as exc:
            self.close()
            raise DeviceError(f"robot base sent a malformed VERSION: {exc}", code="robot_protocol") from exc
        if self._version["protocol"] not in rp.PROTOCOL_VERSIONS or self._version["protocol"] > self.protocol:
            self.close()
            raise DeviceError(f"robot base speaks protocol {self._version['protocol']}, "
                              f"driver speaks {'/'.join(map(str, rp.PROTOCOL_VERSIONS))}",
                              code="robot_version")
        if self._version["protocol"] < 2:  # what a version-1 base may say of clock and streams is not ours
            self._version["capabilities"] = [c for c in self._version["capabilities"] if c == rp.CAP_INCL]
        if self._watchdog_s is None:
            self._version["host_timeout_ms"] = None
            log.warning("%s (protocol %s, %s)", NO_WATCHDOG, self._version["protocol"],
                        self._version["model"])

    def _first_reply(self, protocol: int, *extra: object) -> rp.Message:
        """HELLO's VERSION; a base that says nothing is asked again until the boot window after the open is
        over (a base reset by the open, or powered on with the host, is silent while it boots)."""
        while True:
            try:
                return self._transact("HELLO", protocol, *extra, expect="VERSION")
            except NoReply:
                if self._port is None or time.monotonic() - self._opened_at >= self.boot_s:
                    raise
                self.counters["boot_waits"] += 1

    def _keepalive_period(self) -> float | None:
        watchdog = self._watchdog_s
        if watchdog is None or self._moving_seq is None and not self._starting:
            return None
        return watchdog / KEEPALIVES_PER_TIMEOUT

    @property
    def _watchdog_s(self) -> float | None:
        """The host timeout the base halts a motion after (s), None for a base without the watchdog."""
        ms = self._version.get("host_timeout_ms")
        caps = self._version.get("capabilities", ())
        if self._version.get("protocol", 0) < 3 or rp.CAP_WATCHDOG not in caps:
            return None
        return self.host_timeout if ms is None else ms / 1000.0

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
                "host_watchdog": self._watchdog_s is not None,
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
        self._finished_seq = None  # a DONE read from now on is this motion's (seqs wrap at 9999)
        self._starting = True  # the base may be moving before its ACK arrives: keep it alive meanwhile
        try:
            reply = self._transact(kind, rp.num(value), rp.num(speed), expect="ACK")
        finally:
            self._starting = False
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
        self._check_session(state, reply.fields)
        if state.state not in ("IDLE", "MOVING", "FAULT"):
            raise DeviceError(f"robot base reports unknown state {state.state!r}", code="robot_protocol")
        if state.state != "MOVING" and self._moving_seq is not None:
            self._recover_event(state)
        now = time.monotonic()
        if self.state_hz > 0 and now - self._last_state_emit >= 1.0 / self.state_hz:
            self._last_state_emit = now
            self.emit("robot.state", state.to_dict())
        return state

    def _check_session(self, state: RobotState, fields: tuple[str, ...]) -> None:
        """A base that restarted (power, brown-out, a reset line) forgot the session: its STATUS is a
        version-1 one (no ``t_us``) in a session with CLOCK, or its clock went back. Then the session is
        over: DeviceLost, and the reconnect shakes hands again (streams, host watchdog)."""
        if self._clock and state.t_us is None and len(fields) == rp.STATUS_V1_FIELDS or \
                state.t_us is not None and state.t_us < self._last_t_us:
            self._version = {}
            raise DeviceLost(f"robot base restarted (STATUS t_us {state.t_us} after {self._last_t_us}): "
                             "its session is gone; reconnecting")
        self._last_t_us = -1 if state.t_us is None else state.t_us

    def _recover_event(self, state: RobotState) -> None:
        """The motion is over but its DONE/FAULT never arrived (lost on the line, or
        sent while we were reconnecting): publish one from STATUS so that nobody
        waiting for it hangs. ``recovered`` marks it; the result is not known."""
        seq = self._moving_seq if self._moving_seq and self._moving_seq > 0 else None
        self._moving_seq = None
        self.counters["recovered_events"] += 1
        payload: dict[str, Any] = {"event": "DONE", "seq": seq, "host_time_ns": time.time_ns(),
                                   "recovered": True}
        if state.state == "FAULT":
            payload.update(event="FAULT", reason=state.fault, text="event lost; state read from STATUS")
        else:
            payload.update(result="UNKNOWN", x_mm=state.x_mm, y_mm=state.y_mm, heading_deg=state.heading_deg)
        self.emit("robot.event", payload)

    @property
    def _clock(self) -> bool:
        return rp.CAP_CLOCK in self._version.get("capabilities", ())

    def park(self) -> None:
        """Before the daemon exits: a base that may be moving is halted (STOP; the gate's owed halt too)."""
        if self._port is None or self._moving_seq is None and not self.gate.pending:
            return
        log.warning("robot halted: the daemon is exiting with a motion under way")
        self._transact("STOP", expect="ACK")

    def pump(self, timeout: float) -> None:
        """Read events for ``timeout`` s, polling STATUS when a ``state_hz`` slot is due (each read slice
        also keeps a version-3 base's host watchdog fed while a motion runs: robot_line.py)."""
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


def _check(name: str, value: float, low: float, high: float) -> None:
    """Refuse a motion argument outside the protocol limits before it is sent."""
    if (why := rp.range_error(name, value, low, high)) is not None:
        raise DeviceError(f"robot: {why}", code="robot_range")
