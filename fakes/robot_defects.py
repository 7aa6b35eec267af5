"""Protocol defects a base's firmware might have, injectable one by one into the simulated base.

The conformance kit (``python -m drivers.robot_conformance``) must fail a base with any of these, on
the check that names it; the tests (tests/drivers/test_robot_conformance.py) serve a
:class:`DefectiveBase` on a pty and run the kit against it. Each defect breaks one rule of
docs/robot-protocol.md and nothing else.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Iterable

from drivers import robot_protocol as rp
from fakes.robot_base import FakeBase
from fakes.robot_motion import HostWatchdog
from fakes.robot_stream import BaseClock

#: defect -> the rule it breaks (docs/robot-protocol.md)
DEFECTS = {
    "bad_checksum": "its lines carry a wrong checksum (Framing)",
    "no_nak": "a command with a bad checksum is dropped without NAK CHECKSUM (NAK reasons)",
    "wrong_seq": "replies carry a seq other than their command's (Sequence numbers)",
    "t_us_32bit": "t_us is a 32-bit counter: it wraps every 71.6 minutes (t_us)",
    "no_watchdog": "offers WATCHDOG but never halts a motion for a silent host (Host watchdog)",
    "slow_replies": "replies and events leave SLOW_S late (Timing)",
    "stop_no_ack": "STOP halts but is never acknowledged (Commands)",
    "retry_moves_again": "a resent MOVE (same seq and arguments) is taken as new: NAK BUSY (Sequences)",
    "v1_with_clock": "a version-1 session's STATUS carries t_us (Versions)",
    "no_version_nak": "a HELLO for a protocol it does not speak is answered as its own (Versions)",
}
#: how late a ``slow_replies`` base answers (s): three times the reply budget
SLOW_S = 0.15
#: a ``t_us_32bit`` base's counter wraps this long after its clock is first read in a session (s): a
#: base up for 71.6 minutes less that when the host connects, so that a short run sees the wrap
WRAP_IN_S = 0.5


@dataclass(frozen=True)
class WrappingClock(BaseClock):
    """A 32-bit microsecond counter: the base's clock modulo 2³² µs."""

    def device_us(self, t: float) -> int:
        return super().device_us(t) % 2**32


class _DeafWatchdog(HostWatchdog):
    def expiry(self) -> float | None:
        return None


class DefectiveBase(FakeBase):
    """A FakeBase with the named ``defects`` (keys of DEFECTS)."""

    def __init__(self, world: Any, *, defects: Iterable[str], **kwargs: Any) -> None:
        self.defects = frozenset(defects)
        if unknown := sorted(self.defects - set(DEFECTS)):
            raise ValueError(f"unknown base defect(s) {', '.join(unknown)} (known: {', '.join(DEFECTS)})")
        super().__init__(world, **kwargs)
        self._wraps_from: float | None = None  # when a t_us_32bit base's clock was first read
        if "no_watchdog" in self.defects:
            self.watchdog = _DeafWatchdog()
        self._late: list[tuple[float, bytes]] = []

    def handle_line(self, line: bytes) -> None:
        if "no_nak" in self.defects:
            try:
                rp.decode(line)
            except rp.ProtocolError as exc:
                if exc.kind == "checksum":
                    return
        super().handle_line(line)

    def _send(self, kind: str, *fields: object) -> bytes:
        if "wrong_seq" in self.defects and kind in rp.REPLIES and fields and fields[0] not in (None, ""):
            fields = (rp.next_seq(int(str(fields[0]))), *fields[1:])
        line = rp.encode(kind, *fields)
        if "stop_no_ack" in self.defects and kind == "ACK" and fields[1:2] == ("STOP",):
            return line
        if "bad_checksum" in self.defects:
            line = line[:-4] + (b"00" if line[-4:-2] != b"00" else b"11") + b"\r\n"
        self._out.append(line)
        return line

    def drain(self) -> list[bytes]:
        if "slow_replies" not in self.defects:
            return super().drain()
        with self._lock:
            now = self.clock()
            self._late += [(now + SLOW_S, line) for line in super().drain()]
            due = [line for t, line in self._late if t <= now]
            self._late = [(t, line) for t, line in self._late if t > now]
            return due

    def _motion_precheck(self, seq: int, msg: rp.Message) -> bool:
        if "retry_moves_again" in self.defects:
            self._last_motion_cmd = None
        return super()._motion_precheck(seq, msg)

    def _status(self, seq: int, msg: rp.Message) -> None:
        if "t_us_32bit" in self.defects and self.session >= 2 and self._wraps_from is None:
            self._wraps_from = now = self.clock()
            drift = self.base_clock.drift_ppm
            self.base_clock = self.streams.clock = WrappingClock(now, 2**32 / 1e6 - WRAP_IN_S, drift)
        if "v1_with_clock" not in self.defects or self.session != 1:
            return super()._status(seq, msg)
        self.session = 2
        try:
            super()._status(seq, msg)
        finally:
            self.session = 1

    def _hello(self, seq: int, msg: rp.Message) -> None:
        spoken = [str(v) for v in rp.PROTOCOL_VERSIONS if v <= self.max_protocol]
        if "no_version_nak" in self.defects and msg.fields[1:2] and msg.fields[1] not in spoken:
            msg = rp.Message(msg.kind, (msg.fields[0], str(self.max_protocol), *msg.fields[2:]))
        super()._hello(seq, msg)
