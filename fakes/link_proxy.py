"""A serial cable that can be cut: a pty proxy between a robot base's port and its host.

``LinkProxy(base_port)`` opens the base's port (a pty path, as ``python -m fakes.robot`` prints it, or
``PtyServer.path``) and offers a fresh pty of its own (``path``) for the host to open in its place.
Bytes flow both ways as they arrive until :meth:`cut`: from then on everything either side writes is
read and thrown away, as on an unplugged cable (neither end gets an error: the host notices only
through missing replies). :meth:`restore` lets bytes through again; what was sent meanwhile is lost.
Both directions are also recorded with their arrival times (``log``), for tests that ask what crossed.

``python -m fakes.link_proxy /dev/pts/N`` prints the proxy's path and serves until killed; SIGUSR1 cuts
the link and SIGUSR2 restores it.
"""
from __future__ import annotations

import argparse
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
        """Plug back in: bytes written from now on cross again."""
        with self._lock:
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

    def _run(self) -> None:
        peer = {self.base_fd: (self.master, TO_HOST), self.master: (self.base_fd, TO_BASE)}
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self.base_fd, self.master, self._wake_r], [], [], 0.5)
            except (OSError, ValueError):
                return
            for fd in ready:
                if fd == self._wake_r:
                    continue
                try:
                    data = os.read(fd, 4096)
                except OSError as exc:
                    if exc.errno in (errno.EAGAIN, errno.EINTR, errno.EIO):
                        continue  # EIO: the other end is not open (yet): nothing to forward
                    return
                self._forward(data, *peer[fd])

    def _forward(self, data: bytes, to_fd: int, direction: str) -> None:
        with self._lock:
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
