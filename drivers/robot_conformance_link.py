"""The conformance kit's line to a base: raw lines out, every line in recorded, and one check's verdict.

The kit must see what a driver hides (a wrong checksum, a reply with another seq, a late reply), so it
does not speak through :class:`~drivers.robot.SerialRobot`: :class:`Link` writes lines as given and
records each line the base sends with the host time it was read. It shares only the codec
(drivers/robot_protocol.py) and the port opening (drivers/robot_port.py, DTR/RTS held low).

STOP means stop during the kit too. Given a motion gate (drivers/motion_gate.py: ritad's, engaged by any
operator's STOP while the kit runs on the robot's owner thread; the command line's own, engaged by Ctrl-C
or SIGTERM), the link follows the driver's rule (drivers/robot_line.py): at every read slice and before
every write, a halt the gate owes is written first, resent until the base acknowledges it (bounded), the
gate told, and the kit's run ended with :class:`KitStopped`. While the gate is latched, or once the run was
stopped, no motion line is written. A halt left unacknowledged stays owed: the driver's next connect
writes it first.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Callable

from drivers import robot_protocol as rp
from drivers.motion_gate import MotionGate
from drivers.robot_line import HALT_RESEND_S, RETRIES

#: longest blocking read (s): every wait is a loop of these (and so the longest an owed STOP waits)
SLICE_S = 0.005
VERDICTS = ("pass", "fail", "warn", "skip")
#: the value of each check a STOP kept from running (or cut short)
STOPPED = "STOP during the kit: not run"
#: tries of the reply timeout the kit waits for a STOP's ACK: the driver's default
HALT_TRIES = RETRIES + 1


class KitStopped(Exception):
    """A STOP ended the kit's run; the message says who asked and whether the base acknowledged it."""


@dataclass(frozen=True)
class Check:
    """One check's outcome: ``verdict`` (pass, fail, warn, skip), the measured ``value``, and why."""

    name: str
    verdict: str
    value: str
    detail: str = ""

    def line(self) -> str:
        return f"{self.verdict.upper():4}  {self.name:18} {self.value}" + (
            f"  ({self.detail})" if self.detail else ""
        )

    def to_dict(self) -> dict[str, str]:
        return {"name": self.name, "verdict": self.verdict, "value": self.value, "detail": self.detail}


def verdict(name: str, ok: bool, value: str, detail: str = "") -> Check:
    return Check(name, "pass" if ok else "fail", value, detail)


def not_run(done: list[Check], names: tuple[str, ...], why: str) -> list[Check]:
    """Each check of ``names`` a STOP kept from its end, failed (a stopped kit passed nothing), saying why."""
    ran = {c.name for c in done}
    return [Check(n, "fail", STOPPED, f"{why}; release the stop and run the kit again") for n in names
            if n not in ran]


@dataclass
class Received:
    """A line from the base: its bytes, the host's monotonic time it was read, and its message (None: bad)."""

    raw: bytes
    t: float
    msg: rp.Message | None
    error: str = ""
    taken: bool = False  # handed out by a wait already


@dataclass
class Link:
    """One port to a base (anything with pyserial's ``read``/``write``/``in_waiting``)."""

    port: Any
    timeout: float = 0.5
    seq: int = 0
    log: list[Received] = field(default_factory=list)
    splitter: rp.LineSplitter = field(default_factory=rp.LineSplitter)
    last_write: float = 0.0
    #: while set, a STATUS goes out whenever no line did for this long (s): a version-3 base's host
    #: watchdog must not halt the kit's own motions; the answers to those are not replies to anything
    keepalive_s: float | None = None
    _keepalive_seqs: set[int] = field(default_factory=set)
    _from: int = 0  # log entries before this one are not handed out (skip)
    #: the robot's motion gate (None: nothing but the kit's own STOPs stops the base)
    gate: MotionGate | None = None
    #: another halt request than the gate's: ritad exiting (SIGTERM) while the kit runs
    exiting: Callable[[], bool] = lambda: False
    #: who engages the gate, as the stop's reason names it
    stop_by: str = "an operator's STOP"
    #: how many reply timeouts a STOP's ACK is awaited (ritad: its driver's ``retries`` + 1)
    halt_tries: int = HALT_TRIES
    #: why the run was stopped ("" while it was not): from then on no motion line is written
    stopped: str = ""

    def next_seq(self) -> int:
        self.seq = rp.next_seq(self.seq)
        return self.seq

    def write(self, line: bytes) -> float:
        self._gate_check(line)
        self.port.write(line)
        self.last_write = time.monotonic()
        return self.last_write

    def send(self, kind: str, *fields: object) -> tuple[int, bytes, float]:
        """A command with a new seq; its seq, line and write time."""
        seq = self.next_seq()
        line = rp.encode(kind, seq, *fields)
        return seq, line, self.write(line)

    def pump(self) -> None:
        """Read what has arrived (at most one slice's wait) into the log, after any STOP the gate owes."""
        self._gate_check(None)
        self._read()

    def _read(self) -> list[Received]:
        """One read slice into the log; the entries it added."""
        start = len(self.log)
        data = self.port.read(max(1, self.port.in_waiting))
        now = time.monotonic()
        for raw in self.splitter.feed(data):
            if not raw.strip():
                continue
            try:
                self.log.append(Received(raw, now, rp.decode(raw)))
            except rp.ProtocolError as exc:
                self.log.append(Received(raw, now, None, f"{exc.kind}: {exc}"))
        return self.log[start:]

    def _gate_check(self, line: bytes | None) -> None:
        """Before a read slice or the write of ``line``: the halt owed goes out first and ends the run; a
        motion line is refused while the gate is latched or after the run was stopped (a STOP never is)."""
        gate = self.gate
        if gate is None:
            return
        if not self.stopped and (due := self._halt_due(gate)) is not None:
            self.stopped = self._halt(gate, *due)
            raise KitStopped(self.stopped)
        kind = line.split(b",", 1)[0].lstrip(b"$").decode(errors="replace") if line is not None else ""
        if kind in rp.MOTIONS and (self.stopped or gate.latched):
            raise KitStopped(self.stopped or f"{kind} refused: the stop is latched (no motion line written)")

    def _halt_due(self, gate: MotionGate) -> tuple[int, str] | None:
        """The gate's newest request to halt for, and who asked (ritad's exit owes the base a halt too)."""
        if (due := gate.halt_due()) is not None:
            return due, self.stop_by
        if not self.exiting():
            return None
        gate.owe()  # nobody waits for it: the gate counts it, the ACK settles it
        due = gate.halt_due()
        return (due, "ritad exiting") if due is not None else None

    def _halt(self, gate: MotionGate, upto: int, who: str) -> str:
        """STOP written (again every HALT_RESEND_S) until the base acknowledges it, at most ``halt_tries``
        reply timeouts; the ACK tells the gate. What happened, for the checks' detail."""
        seq = self.next_seq()
        line = rp.encode("STOP", seq)
        t0 = resend = time.monotonic()
        limit = self.halt_tries * self.timeout
        while (now := time.monotonic()) < t0 + limit:
            if now >= resend:
                self.port.write(line)
                self.last_write, resend = now, now + HALT_RESEND_S
            for got in self._read():
                if got.msg is not None and got.msg.kind == "ACK" and got.msg.fields[1:2] == ("STOP",) \
                        and seq_of(got.msg) == seq:
                    got.taken = True
                    gate.halted(upto)
                    return f"{who}: STOP (seq {seq}) acknowledged by the base in {ms(got.t - t0)}; " \
                        "kit aborted"
        return (f"{who}: STOP (seq {seq}) NOT acknowledged in {limit:.3g} s (still owed: the driver's "
                "connect writes it first); kit aborted")

    def wait_for(
        self, pred: Callable[[rp.Message], bool], timeout: float, after: float = 0.0
    ) -> Received | None:
        """The first line read at or after ``after``, not handed out yet, whose message satisfies ``pred``,
        within ``timeout`` s."""
        deadline = time.monotonic() + timeout
        while True:
            for got in self.log[self._from :]:
                if not got.taken and got.t >= after and got.msg is not None and pred(got.msg):
                    got.taken = True
                    return got
            if time.monotonic() >= deadline:
                return None
            self._keep_alive()
            self.pump()

    def _keep_alive(self) -> None:
        if self.keepalive_s is not None and time.monotonic() - self.last_write >= self.keepalive_s:
            self._keepalive_seqs.add(self.send("STATUS")[0])

    def reply(self, after: float, timeout: float | None = None) -> Received | None:
        """The first reply (ACK, NAK, VERSION, STATUS) read after ``after``, whatever its seq (a keep-alive's
        excepted)."""

        def wanted(m: rp.Message) -> bool:
            return m.kind in rp.REPLIES and not (m.kind == "STATUS" and seq_of(m) in self._keepalive_seqs)

        return self.wait_for(wanted, self.timeout if timeout is None else timeout, after)

    def ask(self, kind: str, *fields: object) -> tuple[int, Received | None, float]:
        """A command and its reply: seq, the reply (None if none came in time), round trip (s)."""
        seq, _, t0 = self.send(kind, *fields)
        got = self.reply(t0)
        return seq, got, (got.t - t0) if got else float("inf")

    def ask_line(self, line: bytes, timeout: float | None = None) -> Received | None:
        """The first reply to ``line`` written as given."""
        return self.reply(self.write(line), timeout)

    def event(self, timeout: float) -> Received | None:
        return self.wait_for(lambda m: m.kind in rp.EVENTS, timeout)

    def quiet(self, seconds: float) -> None:
        """Read (and log) for ``seconds`` without writing."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.pump()

    def skip(self) -> None:
        """Hand out nothing read so far: what comes next answers what is sent next."""
        self.pump()
        self._from = len(self.log)

    def bad_lines(self, since: int = 0) -> list[Received]:
        return [r for r in self.log[since:] if r.msg is None]


def seq_of(msg: rp.Message) -> int | None:
    """A reply's seq, None when empty or unreadable."""
    try:
        return msg.seq()
    except rp.ProtocolError:
        return None


def ms(seconds: float) -> str:
    return f"{seconds * 1000:.1f} ms"
