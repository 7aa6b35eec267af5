"""A simulated base behind an RFC 2217 serial server: the host's modem-line settings reach the base.

A pty has no DTR, so a host that resets its base by asserting DTR cannot be seen through one. RFC 2217
(Telnet Com Port Control Option, the protocol of ser2net and of pyserial's ``rfc2217://``) carries the
host's SET-CONTROL requests (DTR ON = 8, DTR OFF = 9, RTS ON = 11, RTS OFF = 12) to the port, as a
USB-serial chip carries them to its DTR/RTS pins. This server is pyserial's own server side
(``serial.rfc2217.PortManager``) in front of a :class:`~fakes.robot_base.FakeBase`, so a base made with
``Boot(reset_on_dtr=True)`` resets the moment a host's open asserts DTR. A closed connection leaves the
lines low, as a serial server that closes its tty with HUPCL set does (termios(3): "Lower modem control
lines after last process closes the device").

Serves 127.0.0.1 on a free port (``port``) from one thread, one connection at a time, until :meth:`close`.
"""
from __future__ import annotations

import socket
import threading
from typing import Any

from serial.rfc2217 import PortManager  # type: ignore[import-untyped]

from drivers import robot_protocol as rp
from fakes.robot_base import FakeBase

#: how often the base is ticked while nothing arrives (s): its motions and samples advance
TICK_S = 0.005
#: the most one read takes from the connection
RECV_BYTES = 4096


class _Uart:
    """The port settings PortManager reads and writes; DTR and RTS go to the base."""

    def __init__(self, base: FakeBase) -> None:
        self.base = base
        self.baudrate, self.bytesize, self.parity, self.stopbits = 115200, 8, "N", 1
        self.xonxoff = self.rtscts = self.break_condition = False
        self.cts = self.dsr = self.ri = self.cd = False
        self._dtr = self.rts = False
        self.dtr_changes: list[bool] = []

    @property
    def dtr(self) -> bool:
        return self._dtr

    @dtr.setter
    def dtr(self, on: bool) -> None:
        self._dtr = bool(on)
        self.dtr_changes.append(self._dtr)
        self.base.set_dtr(self._dtr)

    def reset_input_buffer(self) -> None:
        """Nothing is buffered between the socket and the base."""

    def reset_output_buffer(self) -> None:
        """Nothing is buffered between the base and the socket."""


class _Connection:
    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock

    def write(self, data: bytes) -> None:
        self.sock.sendall(data)


class Rfc2217Base:
    """``rfc2217://127.0.0.1:<port>`` serving ``base``; ``uart.dtr_changes`` records what hosts set."""

    def __init__(self, base: FakeBase) -> None:
        self.base = base
        self.uart = _Uart(base)
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.listener.settimeout(0.05)
        self.port = self.listener.getsockname()[1]
        self.url = f"rfc2217://127.0.0.1:{self.port}"
        self.connections = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"fake-robot rfc2217 {self.port}", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self.listener.close()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self.listener.accept()
            except (TimeoutError, OSError):
                self.base.tick()  # a powered base runs on without a host
                continue
            self.connections += 1
            with conn:
                self._serve(conn)
            self.uart.dtr = self.uart.rts = False  # the server closed the port: HUPCL drops the lines

    def _serve(self, conn: socket.socket) -> None:
        conn.settimeout(TICK_S)
        manager: Any = PortManager(self.uart, _Connection(conn))
        lines = rp.LineSplitter()
        try:
            while not self._stop.is_set():
                checked = self.base.clock()  # a line that arrived before this is in the recv below
                try:
                    data = conn.recv(RECV_BYTES)
                    if not data:
                        return  # the host closed the connection
                except TimeoutError:
                    data = b""
                except OSError:
                    return
                for line in lines.feed(b"".join(manager.filter(data))):
                    self.base.handle_line(line)
                if len(data) < RECV_BYTES:  # all that waited was read: the watchdog may be judged to then
                    self.base.watchdog.read_until = checked  # (robot_motion.HostWatchdog)
                self.base.tick()
                if not self._send(conn, manager):
                    return
        finally:
            self.base.watchdog.read_until = None  # no host connected: no line can come

    def _send(self, conn: socket.socket, manager: Any) -> bool:
        """The base's replies, events and samples to the host; False once the connection failed."""
        out = b"".join(self.base.drain() + self.base.drain_stream())
        if out:
            try:
                conn.sendall(b"".join(manager.escape(out)))
            except OSError:
                return False
        return True
