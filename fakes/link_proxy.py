"""A serial cable that can be cut: a pty proxy between a robot base's port and its host.

``LinkProxy(base_port)`` opens the base's port (a pty path, as ``python -m fakes.robot`` prints it, or
``PtyServer.path``) and offers a fresh pty of its own (``path``) for the host to open in its place.
Bytes flow both ways as they arrive until :meth:`cut`: from then on everything either side writes is
read and thrown away, as on an unplugged cable (neither end gets an error: the host notices only
through missing replies). :meth:`restore` lets bytes through again; what was sent meanwhile is lost.
Both directions are also recorded with their arrival times (``log``), for tests that ask what crossed.
A byte is judged by the cable's state when the proxy reads it; :meth:`restore` first throws away what
waits unread, so a line written while the cable was cut never crosses, however late the proxy's thread.

The proxy is a thread: on a loaded machine it can be late, and then lines cross late. It wakes at least
every ``POLL_S`` and records each gap between its wake-ups longer than ``STALL_S`` (``stalls``): a test
that measures a latency through the cable can tell its own instrument's lateness from the host's.

``python -m fakes.link_proxy /dev/pts/N`` prints the proxy's path and serves until killed; SIGUSR1 cuts
the link and SIGUSR2 restores it.
"""
from __future__ import annotations

import argparse
import collections
import errno
import os
import select
import signal
import sys
import threading
import time
import tty

#: directions in the log
TO_HOST, TO_BASE = "base->host", "host->base"
#: the longest the proxy's thread sleeps when nothing crosses (s): a longer gap is its own lateness
POLL_S = 0.01
#: a gap between two wake-ups longer than this is recorded as a stall (s)
STALL_S = 0.03
#: stalls kept (the oldest are forgotten: a proxy may serve for days)
MAX_STALLS = 1000


class StallLog:
    """The gaps between a server thread's wake-ups longer than its longest sleep + STALL_S: how late the
    thread was (a loaded machine), kept so that a latency measured through it can be told from its own."""

    def __init__(self) -> None:
        self.gaps: collections.deque[tuple[float, float]] = collections.deque(maxlen=MAX_STALLS)
        self._last: float | None = None

    def woke(self, now: float, slept_max: float) -> None:
        """The thread woke at ``now`` from a wait of at most ``slept_max`` s."""
        if self._last is not None and now - self._last > slept_max + STALL_S:
            self.gaps.append((self._last, now))
        self._last = now

    def longest(self, start: float, end: float) -> float:
        """The longest stall overlapping ``start``..``end`` (monotonic s), 0 if none: a line that came
        meanwhile may have been taken up to this late."""
        return max((min(b, end) - max(a, start) for a, b in list(self.gaps) if b > start and a < end),
                   default=0.0)


class LinkProxy:
    """Forwards a base's pty to a new pty for the host; ``cut``/``restore`` switch the cable."""

    def __init__(self, base_port: str) -> None:
        self.base_fd = os.open(base_port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        tty.setraw(self.base_fd)
        self.master, self._slave = os.openpty()
        tty.setraw(self._slave)  # no echo, no CR/LF translation: a clean 8-bit line
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self._slave)
        self.connected = True
        #: (monotonic time, direction, bytes) of everything that crossed, and what a cut swallowed
        self.log: list[tuple[float, str, bytes]] = []
        self.dropped = {TO_HOST: 0, TO_BASE: 0}
        self.stalls = StallLog()  # the thread's own lateness
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._wake_r, self._wake_w = os.pipe()
        self._thread = threading.Thread(target=self._run, name=f"link-proxy {self.path}", daemon=True)
        self._thread.start()

    def cut(self) -> None:
        """Unplug: from now on nothing crosses, either way."""
        with self._lock:
            self.connected = False

    def restore(self) -> None:
        """Plug back in: bytes written from now on cross again (what waits unread was sent while cut)."""
        with self._lock:
            for fd, (_, direction) in self._peers().items():
                while data := self._read(fd):
                    self.dropped[direction] += len(data)
            self.connected = True

    def lines(self, direction: str) -> list[tuple[float, bytes]]:
        """The lines that crossed in ``direction``, each with the time its last byte arrived."""
        out, buf = [], b""
        with self._lock:
            chunks = [(t, data) for t, d, data in self.log if d == direction]
        for t, data in chunks:
            buf += data
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                out.append((t, line.rstrip(b"\r")))
        return out

    def close(self) -> None:
        """Stop forwarding and close both ptys (idempotent)."""
        if self._stop.is_set():
            return
        self._stop.set()
        os.write(self._wake_w, b"x")
        self._thread.join(timeout=2.0)
        for fd in (self.base_fd, self.master, self._slave, self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass

    def _peers(self) -> dict[int, tuple[int, str]]:
        return {self.base_fd: (self.master, TO_HOST), self.master: (self.base_fd, TO_BASE)}

    def _run(self) -> None:
        peer = self._peers()
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self.base_fd, self.master, self._wake_r], [], [], POLL_S)
                self.stalls.woke(time.monotonic(), POLL_S)
                with self._lock:  # read and judged in one step: restore() cannot come between
                    for fd in ready:
                        if fd != self._wake_r and (data := self._read(fd)):
                            self._forward(data, *peer[fd])
            except (OSError, ValueError):
                return

    @staticmethod
    def _read(fd: int) -> bytes:
        """What waits on ``fd``; b"" when nothing does (EIO: the other end is not open yet)."""
        try:
            return os.read(fd, 4096)
        except OSError as exc:
            if exc.errno in (errno.EAGAIN, errno.EINTR, errno.EIO):
                return b""
            raise

    def _forward(self, data: bytes, to_fd: int, direction: str) -> None:
        """Cross ``data`` (the caller holds the lock), or drop it while the cable is cut."""
        if not self.connected:
            self.dropped[direction] += len(data)
            return
        self.log.append((time.monotonic(), direction, data))
        try:
            os.write(to_fd, data)
        except OSError:  # nobody reads the other end: lost, as on a cable
            self.dropped[direction] += len(data)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m fakes.link_proxy", description=__doc__.split("\n\n")[0])
    ap.add_argument("base_port", help="the base's pty path (e.g. what python -m fakes.robot printed)")
    args = ap.parse_args(argv)
    proxy = LinkProxy(args.base_port)
    signal.signal(signal.SIGUSR1, lambda *_: proxy.cut())
    signal.signal(signal.SIGUSR2, lambda *_: proxy.restore())
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    print(proxy.path, flush=True)
    try:
        while not done.wait(0.5):
            pass
    except KeyboardInterrupt:
        pass
    proxy.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
