"""Fake robot base on a pseudo-terminal, and the ``sim:`` robot adapter.

``python -m fakes.robot [--seed N] [--time-scale S] [--max-protocol 1|2] [--param key=value ...]`` starts a
simulated base on a fresh pty, prints the device path (one line) and serves until
killed; connect with ``serial:///dev/pts/N``. ``--boot-s S``: it boots (silent, then a banner) at start
and after a reset; ``--rfc2217``: served over RFC 2217 instead (prints ``rfc2217://127.0.0.1:PORT``),
resetting when a host asserts DTR. :class:`SimRobot` (URL ``sim:``) does
the same in a background thread on its first ``open()`` and then talks to it as a
plain :class:`~drivers.robot.SerialRobot`, so the sim exercises the real driver,
codec and pyserial.

How it differs from the real base:

* motion is at constant speed with instant start and stop (no ramps), and takes
  distance / speed × ``time_scale`` of wall time (0 = instant);
* drive errors and floor tilt follow the simple model of :mod:`fakes.robot_base`
  (no slip, no wheel-specific errors, the lateral error is spread linearly along the path);
  the inclinometer reads the true tilt with the error model's noise and bias (none in the ideal profile);
* the battery voltage only drops with the distance driven;
* its clock (protocol 2) is the host's monotonic clock with an offset and 50 ppm of drift, and
  its inclinometer outputs 10 samples per *simulated* second (fakes/robot_stream.py);
* the pty has no baud rate: bytes arrive at once, and output that nobody reads is
  dropped instead of blocking the controller;
* line faults are injected on purpose: ``garbage_rate`` (noise bursts between
  lines), ``corrupt_rate`` (one byte flipped in a line, so its checksum fails),
  ``fault_rate`` (a motion stalls part-way), ``silent`` (the link goes quiet) and
  :meth:`SimRobot.drop_port` (the port vanishes; the next ``open()`` makes a new pty).
"""
from __future__ import annotations

import argparse
import dataclasses
import errno
import logging
import os
import select
import signal
import sys
import threading
import tty
from typing import Any, Callable

import numpy as np

from drivers import robot_protocol as rp
from drivers.base import DeviceURL, Emit, no_emit
from drivers.robot import SerialRobot
from fakes.link_proxy import StallLog
from fakes.robot_base import FakeBase, unit_interval
from fakes.robot_boot import Boot
from fakes.robot_defects import DefectiveBase
from fakes.robot_rfc2217 import Rfc2217Base
from fakes import worlds
from fakes.world import World, WorldParams

log = logging.getLogger(__name__)

IDLE_TICK_S = 0.05
MOVING_TICK_S = 0.005  # how often the pose is interpolated while moving
MAX_HELD = 64  # replies/events kept while the pty is full; older ones are lost as on a real cable


class PtyServer:
    """Serves one :class:`FakeBase` on a pty from a background thread."""

    def __init__(self, base: FakeBase, *, garbage_rate: float = 0.0, corrupt_rate: float = 0.0,
                 rng: np.random.Generator | None = None) -> None:
        self.base = base
        self.garbage_rate = unit_interval("garbage_rate", garbage_rate)
        self.corrupt_rate = unit_interval("corrupt_rate", corrupt_rate)
        self.silent = False
        self.rng = rng or base.world.rng("robot.line")
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no CR/LF translation: a clean 8-bit line
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self._slave)
        self._wake_r, self._wake_w = os.pipe()
        self._held: list[bytes] = []  # replies and events the full pty could not take yet
        self._pending: list[int] = []  # sizes of injected noise bursts (the rng is the thread's)
        self._injected = b""  # bytes given to inject(), not yet written
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.stalls = StallLog()  # the server thread's own lateness (on the base's clock)
        self.alive = True
        self.counters = {"tx_lines": 0, "tx_dropped": 0, "samples_dropped": 0, "garbage_bursts": 0,
                         "corrupted": 0}
        # what the base said while no port was attached is lost, as on a real cable
        base.tick()
        self.counters["tx_dropped"] += len(base.drain()) + len(base.drain_stream())
        self._thread = threading.Thread(target=self._run, name=f"fake-robot {self.path}", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ knobs

    def inject_garbage(self, nbytes: int = 32) -> None:
        """Send ``nbytes`` random bytes followed by a newline, between two lines."""
        if not self.alive:
            return
        with self._lock:
            self._pending.append(nbytes)
        try:
            os.write(self._wake_w, b"x")
        except OSError:
            pass  # shut down meanwhile

    def inject(self, data: bytes) -> None:
        """``data`` sent to the host as if from the base: written whole by the server's own thread, in order,
        before any line the base sends after this call and never interleaved with one (fuzz tests' lines)."""
        with self._lock:
            self._injected += data
        try:
            os.write(self._wake_w, b"x")
        except OSError:
            pass  # shut down meanwhile

    def drop_port(self) -> None:
        """The port vanishes: close both pty ends so the host sees an I/O error."""
        self.shutdown()

    def shutdown(self) -> None:
        """Stop the thread and close the pty (idempotent)."""
        if not self.alive:
            return
        self._stop.set()
        try:
            os.write(self._wake_w, b"x")
        except OSError:
            pass
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout=2.0)
        self.base.watchdog.read_until = None  # no port: no line can come, the timer runs on the clock
        self.alive = False
        for fd in (self.master, self._slave, self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass

    # ------------------------------------------------------------------ loop

    def _noise(self, nbytes: int) -> bytes:
        # random bytes, but never a newline inside: the burst is one garbage line
        raw = self.rng.integers(0, 256, size=max(1, nbytes), dtype=np.uint8).tobytes()
        return raw.replace(b"\n", b"?") + b"\r\n"

    def _run(self) -> None:
        splitter = rp.LineSplitter()
        while not self._stop.is_set():
            tick = MOVING_TICK_S if self.base.moving else IDLE_TICK_S
            # STATE samples leave when taken, as from a real base, so the host's clock map sees them on
            # time; the INCL samples taken since go with the next STATE sample or moving tick (at most
            # a few ms late: the host times them by their t_us). At the sim's 50x speed the 10 Hz
            # inclinometer is 500 samples a second: a wake-up for each cost ritad a quarter of a core
            due = self.base.streams.next_due(state_only=True)
            if due is not None:
                tick = min(tick, max(0.0, due - self.base.clock()))
            checked = self.base.clock()  # a line that arrived before this is read below, before the tick
            try:
                writable = [self.master] if self._injected else []  # (only this thread empties it)
                ready, _, _ = select.select([self.master, self._wake_r], writable, [], tick)
            except (OSError, ValueError):
                return
            if self._stop.is_set():
                return
            self.stalls.woke(self.base.clock(), tick)
            if self._wake_r in ready:
                os.read(self._wake_r, 256)
            try:
                data = self._read_all() if self.master in ready else b""
            except OSError:
                return
            if not self.silent:  # a quiet link loses input too
                for line in splitter.feed(data):
                    self._guarded(self.base.handle_line, line)
            # the host watchdog is judged up to ``checked`` only: a line that came while this thread was
            # late after its select (a loaded machine) is read next time, as a UART would have on time
            self.base.watchdog.read_until = checked
            self._guarded(self.base.tick)
            out, samples = self.base.drain(), self.base.drain_stream()
            with self._lock:
                pending, self._pending = self._pending, []
            if not self._write_injected():  # the base's lines wait behind injected bytes the pty did not take
                self._held += out
                self.counters["samples_dropped"] += len(samples)
            elif not self.silent:
                self._send([self._noise(n) for n in pending] + [self._impair(line) for line in out])
                self._send([self._impair(line) for line in samples], samples=True)

    def _read_all(self) -> bytes:
        """Everything the host wrote that waits in the pty (several reads when more than one's worth)."""
        data = b""
        while True:
            try:
                chunk = os.read(self.master, 4096)
            except OSError as exc:
                if exc.errno in (errno.EAGAIN, errno.EINTR):
                    return data
                raise
            data += chunk
            if len(chunk) < 4096:
                return data

    def _write_injected(self) -> bool:
        """Write what the pty takes of the injected bytes; True once none are left."""
        with self._lock:
            data = self._injected
        sent = 0
        while sent < len(data):
            try:
                sent += os.write(self.master, data[sent:])
            except OSError:
                break  # full: the rest at the next wake-up (select waits for room)
        with self._lock:
            self._injected = self._injected[sent:]
            return not self._injected

    def _guarded(self, fn: Callable[..., None], *args: Any) -> None:
        # a bug in the simulated controller must show up in the log, not as a silent
        # dead thread that the driver can only report as a lost port
        try:
            fn(*args)
        except Exception:
            log.exception("fake robot base failed on %r", args)

    def _impair(self, line: bytes) -> bytes:
        """Apply the configured line faults to one outgoing line."""
        if self.corrupt_rate and self.rng.random() < self.corrupt_rate:
            i = int(self.rng.integers(1, len(line) - 5))  # a body byte: the checksum must fail
            flipped = line[i] ^ 0x01 if line[i] not in b"$*,\r\n\x01\x2b\x2d" else line[i]
            if flipped != line[i]:
                line = line[:i] + bytes([flipped]) + line[i + 1:]
                self.counters["corrupted"] += 1
        if self.garbage_rate and self.rng.random() < self.garbage_rate:
            self.counters["garbage_bursts"] += 1
            line = self._noise(int(self.rng.integers(1, 24))) + line
        return line

    def _send(self, chunks: list[bytes], samples: bool = False) -> None:
        """Write lines; when the pty is full (nobody reads) samples are dropped, like a real line's
        overrun, but replies and events wait for room (at most MAX_HELD of them): a sample stream
        the host reads late must never cost it the answer to a command."""
        if not samples:
            chunks, self._held = self._held + chunks, []
        elif len(chunks) > 1:
            chunks = chunks[self._send_joined(chunks):]
        for i, chunk in enumerate(chunks):
            try:
                os.write(self.master, chunk)
                self.counters["tx_lines"] += 1
            except OSError:
                if samples:
                    self.counters["samples_dropped"] += 1
                    continue
                self._held = chunks[i:][-MAX_HELD:]
                self.counters["tx_dropped"] += len(chunks) - i - len(self._held)
                return


    def _send_joined(self, chunks: list[bytes]) -> int:
        """Samples in one write (the host then wakes once for them, not once a line); how many went
        out. A write the full pty cut short counts the line it cut as sent, as one write a line does;
        the caller writes the rest a line at a time (dropping what does not fit)."""
        try:
            n = os.write(self.master, b"".join(chunks))
        except OSError:
            return 0
        sent = 0
        while sent < len(chunks) and n > 0:
            n -= len(chunks[sent])
            sent += 1
        self.counters["tx_lines"] += sent
        return sent


class SimRobot(SerialRobot):
    """``sim:`` robot: a :class:`FakeBase` on a private pty, driven by the real driver.

    Options (besides the SerialRobot ones): ``time_scale`` (0.02), ``garbage_rate``,
    ``corrupt_rate``, ``fault_rate`` (all 0), ``clock_offset_s`` (the base's clock at the fake's start: how
    long it has been on; default seeded, 10-10 000 s), ``defects`` (a comma list of fakes/robot_defects.py's
    protocol defects, e.g. ``t_us_32bit,no_watchdog``), ``max_protocol`` (the newest version it speaks,
    default 3). The fake keeps running across
    ``close()``/``open()`` like a powered base; :meth:`shutdown` stops it.
    """

    OPTIONS = SerialRobot.OPTIONS | {"time_scale", "garbage_rate", "corrupt_rate", "fault_rate",
                                     "clock_offset_s", "defects", "max_protocol", worlds.OPTION}

    def __init__(self, url: DeviceURL, *, emit: Emit = no_emit, settings: Any = None) -> None:
        super().__init__(url, emit=emit, settings=settings)
        self.world = worlds.world_for(url)
        kwargs = {"time_scale": url.option("time_scale", 0.02, float),
                  "fault_rate": url.option("fault_rate", 0.0, float),
                  "clock_offset_s": url.option("clock_offset_s", None, float),
                  "max_protocol": url.option("max_protocol", rp.PROTOCOL_VERSION, int)}
        defects = [d for d in url.option("defects", "", str).split(",") if d]
        self.fake = (DefectiveBase(self.world, defects=defects, **kwargs) if defects
                     else FakeBase(self.world, **kwargs))
        self.garbage_rate: float = url.option("garbage_rate", 0.0, float)
        self.corrupt_rate: float = url.option("corrupt_rate", 0.0, float)
        self.server: PtyServer | None = None

    def port_target(self) -> str:
        if self.server is None or not self.server.alive:
            self.server = PtyServer(self.fake, garbage_rate=self.garbage_rate, corrupt_rate=self.corrupt_rate)
        return self.server.path

    def set_line_faults(self, *, garbage_rate: float | None = None, corrupt_rate: float | None = None,
                        silent: bool | None = None) -> None:
        """Change line fault knobs now (and for any pty made later)."""
        if garbage_rate is not None:
            self.garbage_rate = garbage_rate
        if corrupt_rate is not None:
            self.corrupt_rate = corrupt_rate
        if self.server is not None:
            self.server.garbage_rate, self.server.corrupt_rate = self.garbage_rate, self.corrupt_rate
            if silent is not None:
                self.server.silent = silent

    def inject_garbage(self, nbytes: int = 32) -> None:
        if self.server is not None:
            self.server.inject_garbage(nbytes)

    def drop_port(self) -> None:
        """Make the port vanish (the driver sees DeviceLost; ``open()`` gets a new pty)."""
        if self.server is not None:
            self.server.drop_port()

    def shutdown(self) -> None:
        """Close the driver and stop the fake base's thread."""
        self.close()
        if self.server is not None:
            self.server.shutdown()

    def info(self) -> dict[str, Any]:
        out = super().info()
        out["simulated"] = True
        out["time_scale"] = self.fake.time_scale  # wall seconds per simulated second (a recording states it)
        if self.server is not None:
            out["fake_counters"] = {**self.fake.counters, **self.server.counters}
        return out


def _param(text: str) -> tuple[str, Any]:
    """Parse ``key=value`` for a WorldParams field (numbers and booleans)."""
    key, sep, value = text.partition("=")
    fields = {f.name: f for f in dataclasses.fields(WorldParams)}
    if not sep or key not in fields:
        raise argparse.ArgumentTypeError(f"{text!r}: expected key=value with a WorldParams field as key")
    if value.lower() in ("true", "false"):
        return key, value.lower() == "true"
    try:
        return key, int(value) if value.lstrip("-").isdigit() else float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: value {value!r} is not a number or true/false") from None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m fakes.robot", description="Fake Rita robot base on a pty.")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--time-scale", type=float, default=0.02)
    ap.add_argument("--garbage-rate", type=float, default=0.0)
    ap.add_argument("--corrupt-rate", type=float, default=0.0)
    ap.add_argument("--fault-rate", type=float, default=0.0)
    ap.add_argument("--max-protocol", type=int, choices=rp.PROTOCOL_VERSIONS, default=rp.PROTOCOL_VERSION,
                    help="the newest protocol the base speaks (1: a version-1 base)")
    ap.add_argument("--boot-s", type=float, default=0.0,
                    help="boot time after power-on or a reset (silent, then a banner): fakes/robot_boot.py")
    ap.add_argument("--rfc2217", action="store_true",
                    help="serve over RFC 2217 on 127.0.0.1 (prints its URL), resetting on DTR, not on a pty")
    ap.add_argument("--param", type=_param, action="append", default=[], metavar="KEY=VALUE",
                    help="set a WorldParams field, e.g. drive_lateral_sigma_mm=0.05")
    args = ap.parse_args(argv)
    world = World(WorldParams(seed=args.seed).with_(**dict(args.param)))
    base = FakeBase(world, time_scale=args.time_scale, fault_rate=args.fault_rate,
                    max_protocol=args.max_protocol, boot=Boot(boot_s=args.boot_s, reset_on_dtr=args.rfc2217))
    server: Any = Rfc2217Base(base) if args.rfc2217 else \
        PtyServer(base, garbage_rate=args.garbage_rate, corrupt_rate=args.corrupt_rate)
    print(server.url if args.rfc2217 else server.path, flush=True)
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    try:
        while not done.wait(0.5) and getattr(server, "alive", True):
            pass
    except KeyboardInterrupt:
        pass
    (server.close if args.rfc2217 else server.shutdown)()
    return 0


if __name__ == "__main__":
    sys.exit(main())
