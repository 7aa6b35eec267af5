"""The Rita line protocol's line level: transactions, reads, events, and the STOP that goes first.

:class:`RobotLine` is what :class:`~drivers.robot.SerialRobot` speaks through: one command at a time
with its reply awaited, resent with the same seq when it does not come; events dispatched as they
are read; samples batched. One rule sits above them all: a halt the motion gate owes the base
(drivers/motion_gate.py) is written at the next read slice, ahead of the reply a transaction is
waiting for, and resent until the base acknowledges it. A lost connection keeps it owed, so the
next connect sends it first. Everything here runs in the owner thread, except ``wake``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import serial

from drivers import robot_protocol as rp
from drivers.base import DeviceError, DeviceLost, Emit
from drivers.motion_gate import MotionGate
from drivers.robot_stream import StreamBatcher

#: longest single blocking read; keeps every loop responsive to its deadline (and to a STOP)
READ_SLICE_S = 0.02
#: how often an owed STOP is written again while its ACK is missing: a link that comes back carries it
#: within this (STOP is safe to execute any number of times, and is accepted before a HELLO too)
HALT_RESEND_S = 0.05
#: a request's retries after its first reply timeout (URL ``retries``): a STOP's ACK is awaited retries + 1
#: timeouts
RETRIES = 2

COUNTER_NAMES = ("rx_lines", "bad_checksum", "garbage", "syntax", "stale", "unexpected",
                 "retries", "naks", "events", "recovered_events", "overflows", "halts", "boot_waits")


class NoReply(DeviceLost):
    """A command's every try went unanswered (the port itself is fine: a silent or booting base)."""


@dataclass
class _Halt:
    """A STOP line written for the gate's request ``request``, waiting for its ACK."""

    seq: int
    line: bytes
    request: int
    first_at: float
    tries: int = 0
    resend_at: float = 0.0


class RobotLine:
    """Line-level state and I/O of a robot adapter (a mixin: :meth:`_init_line` sets it up)."""

    emit: Emit
    reply_timeout: float
    retries: int
    _version: dict[str, Any]

    def _init_line(self, gate: MotionGate) -> None:
        self.gate = gate
        self._port: Any = None
        self._woken = False
        self._splitter = rp.LineSplitter()
        self._seq = 0
        self._moving_seq: int | None = None
        self._finished_seq: int | None = None
        self._streaming = False
        self._halt: _Halt | None = None
        self._keepalive_seq: int | None = None  # the last keep-alive STATUS: its reply is not a stray
        self._last_tx = 0.0  # monotonic time of the last line written (the host watchdog's keep-alive)
        self.counters: dict[str, int] = dict.fromkeys(COUNTER_NAMES, 0)
        self._batcher = StreamBatcher(self.emit)

    # ------------------------------------------------------------------ the halt the gate owes

    def _service_halt(self) -> None:
        """Write the STOP the gate owes, ahead of any awaited reply (also before a HELLO: while connecting);
        resend it every HALT_RESEND_S while its ACK is missing."""
        due = self.gate.halt_due()
        if due is None:
            return
        halt, now = self._halt, time.monotonic()
        if halt is not None and halt.request >= due and now < halt.resend_at:
            return
        if halt is None or halt.request < due:  # a newer request: a new STOP line
            self._seq = rp.next_seq(self._seq)
            halt = self._halt = _Halt(self._seq, rp.encode("STOP", self._seq), due, now)
        elif now - halt.first_at > (self.retries + 1) * self.reply_timeout and self._version:
            raise DeviceLost(f"robot base did not acknowledge STOP (seq {halt.seq}) in "
                             f"{(self.retries + 1) * self.reply_timeout:.3g} s")
        halt.tries += 1
        halt.resend_at = now + HALT_RESEND_S
        self.counters["halts" if halt.tries == 1 else "retries"] += 1
        self._write(halt.line)

    def _halt_reply(self, msg: rp.Message) -> bool:
        """Whether ``msg`` answers the STOP in flight (an ACK tells the gate the base has halted)."""
        halt = self._halt
        if halt is None or msg.kind not in rp.REPLIES or msg.seq() != halt.seq:
            return False
        if msg.kind == "ACK" and msg.fields[1:2] == ("STOP",):
            self._halt = None
            self.gate.halted(halt.request)
        else:  # STOP is always accepted: a NAK is a line fault; it is resent on time
            self.counters["naks"] += 1
        return True

    def _halt_first(self) -> None:
        """At connect, while latched: STOP before anything else, and its ACK awaited (one may have gone out
        before the HELLO already: that one is written blind, to reach a base the moment the link is back)."""
        if self.gate.latched:
            self.gate.owe()
        self._halt = None  # a STOP written on the old connection is not known to have arrived
        deadline = time.monotonic() + (self.retries + 1) * self.reply_timeout + READ_SLICE_S
        while self.gate.pending:
            if time.monotonic() >= deadline:
                raise DeviceLost("robot base did not acknowledge STOP at connect")
            for msg in self._receive(min(deadline, time.monotonic() + READ_SLICE_S)):
                self._count_stray(msg)

    # ------------------------------------------------------------------ the host watchdog's keep-alive

    def _keepalive_period(self) -> float | None:
        """How often a line must go out now (s), None when nothing needs keeping alive (the adapter's)."""
        return None

    def _keepalive(self) -> None:
        """While a motion of ours runs on a base with the host watchdog, a line at least every period, also
        while a transaction waits for a late reply: a STATUS with its own seq, its answer dropped unread."""
        period = self._keepalive_period()
        if period is None or time.monotonic() - self._last_tx < period or self._port is None:
            return
        self._seq = rp.next_seq(self._seq)
        self._keepalive_seq = self._seq
        self._write(rp.encode("STATUS", self._seq))

    # ------------------------------------------------------------------ transactions

    def _transact(self, kind: str, *fields: object, expect: str) -> rp.Message:
        """Send one command and return its positive reply; NAK → DeviceError. A motion line is checked
        against the gate before *every* write, its resends included, after any owed STOP went out: a
        STOP requested after that check is written after the line (the owner writes both)."""
        self._seq = rp.next_seq(self._seq)
        seq = self._seq
        line = rp.encode(kind, seq, *fields)
        for attempt in range(self.retries + 1):
            if attempt:
                self.counters["retries"] += 1
            if self._port is not None:
                self._service_halt()  # an owed STOP goes out before this command's line too
            if kind in rp.MOTIONS and self.gate.latched:
                raise DeviceError(f"robot: {kind} refused: the stop is latched", code="stopped")
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
                        refused = f"robot base refused {line.decode().strip()}: {reason} {text}"
                        raise DeviceError(refused.strip(), code=f"robot_{reason.lower()}")
                    elif msg.kind != expect:
                        self.counters["unexpected"] += 1
                    else:
                        for rest in got[i + 1:]:  # read in the same chunk after our reply: strays, counted
                            self._count_stray(rest)
                        return msg
        raise NoReply(f"robot base did not answer {kind} (seq {seq}) in "
                         f"{self.retries + 1} tries of {self.reply_timeout:.3g} s")

    def _write(self, line: bytes) -> None:
        if self._port is None:
            raise DeviceLost("robot port is not open")
        try:
            self._port.write(line)
        except (serial.SerialException, OSError) as exc:
            raise DeviceLost(f"robot port write failed: {exc}") from exc
        self._last_tx = time.monotonic()

    def _receive(self, deadline: float, wakeable: bool = False) -> list[rp.Message]:
        """Replies read before ``deadline`` (events are dispatched here, not returned); returns as soon as
        a reply arrived, an owed STOP was acknowledged or (``wakeable``) :meth:`wake` was called. Each read
        slice first writes the STOP the gate owes. Bad lines are counted, not raised."""
        if self._port is None:
            raise DeviceLost("robot port is not open")
        replies: list[rp.Message] = []
        while True:
            self._service_halt()
            self._keepalive()
            halting = self._halt is not None
            try:
                data = self._port.read(max(1, self._port.in_waiting))
            except (serial.SerialException, OSError) as exc:
                raise DeviceLost(f"robot port read failed: {exc}") from exc
            rx_ns = time.time_ns()
            for raw in self._splitter.feed(data):
                msg = self._decode(raw, rx_ns)
                if msg is None or self._dispatch_event(msg, rx_ns) is None or self._halt_reply(msg):
                    continue  # a bad line, an event or sample, or the owed STOP's answer: not a reply
                if msg.kind == "STATUS" and msg.seq() == self._keepalive_seq:
                    continue  # a keep-alive's answer: only the line mattered
                replies.append(msg)
            self.counters["overflows"] = self._splitter.overflows
            self._batcher.flush()
            if (replies or time.monotonic() >= deadline or wakeable and self._woken
                    or halting and self._halt is None):
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
        except rp.ProtocolError as exc:
            if (framed := self._after_noise(raw, exc)) is not None:
                return framed
            self.counters[{"checksum": "bad_checksum", "garbage": "garbage"}.get(exc.kind, "syntax")] += 1
            return None
        return self._checked(msg)

    def _after_noise(self, raw: bytes, exc: rp.ProtocolError) -> rp.Message | None:
        """A valid frame after noise on one line (a boot banner's prompt without a line end, bootloader
        bytes): the noise counted as garbage, the frame read. None when there is none (one count then)."""
        start = raw.rfind(b"$")
        if exc.kind != "garbage" or start <= 0:
            return None
        try:
            msg = rp.decode(raw[start:])
        except rp.ProtocolError:
            return None
        self.counters["garbage"] += 1
        return self._checked(msg)

    def _checked(self, msg: rp.Message) -> rp.Message | None:
        """``msg``, its seq validated early for a reply or event, so that callers can rely on it."""
        try:
            if msg.kind in rp.REPLIES or msg.kind in rp.EVENTS:
                msg.seq()
        except rp.ProtocolError:
            self.counters["syntax"] += 1
            return None
        return msg

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
