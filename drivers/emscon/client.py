"""Synchronous emScon client: one TCP socket, one thread, one command in flight.

The tracker answers every request with a BasicCommandRT carrying the same command
number; some commands add result packets (a SingleMeasResult for a stationary
StartMeasurement, one GetReflectorsRT per reflector). Those may arrive in either
order and interleaved with unsolicited packets (ErrorResponse, SystemStatusChange,
continuous MultiMeasResult batches), so every wait reads the socket and dispatches
whatever comes: answers/results to the waiting command, stream batches to
``on_stream``, everything else to ``on_event``.

Errors: a non-zero ES_ResultStatus raises :class:`EmsconStatusError`, except the
``Parameter<k>OutOfRangeOK`` statuses (:data:`OK_STATUSES`), which the header names as accepted
(each paired with a refused ``…OutOfRangeNOK``): those count as success with a WARNING; EOF, a socket
error or a :class:`ProtocolError` closes the socket and raises ``DeviceLost``. An
expired wait raises ``DeviceTimeout`` and also closes the socket: the late answer
cannot be told apart from the next command's, so the next call raises ``DeviceLost``
and the owner reconnects (``open()`` re-applies every setting).
"""
from __future__ import annotations

import logging
import socket
import time
from typing import Any, Callable

from drivers.base import DeviceError, DeviceLost, DeviceTimeout
from drivers.emscon.codec import Packet, ProtocolError, encode_request
from drivers.emscon.enums import ES_Command, ES_ResultStatus, enum_name
from drivers.emscon.framer import TO_CLIENT, Framer

log = logging.getLogger(__name__)
PacketSink = Callable[[Packet], None]
#: statuses meaning "a parameter was out of range but the command was accepted": ES_RS_Parameter1..6
#: OutOfRangeOK (11, 13, ..., 21) in Leica's ES_C_API_Def.h (beckjac/emscon_ros,
#: include/emscon_ros/ES_C_API_Def.h, enum ES_ResultStatus); the NOK twins stay failures
OK_STATUSES = frozenset({ES_ResultStatus.Parameter1OutOfRangeOK, ES_ResultStatus.Parameter2OutOfRangeOK,
                         ES_ResultStatus.Parameter3OutOfRangeOK, ES_ResultStatus.Parameter4OutOfRangeOK,
                         ES_ResultStatus.Parameter5OutOfRangeOK, ES_ResultStatus.Parameter6OutOfRangeOK})


def accepted(status: int) -> bool:
    """Whether a command's status means it took effect: AllOK or an OutOfRangeOK."""
    return status == 0 or status in OK_STATUSES
RECV_SIZE = 1 << 18
HEAD_BYTES = 7  # enough to recognise "HTTP/1." or "SSH-2.0"


def _ignore(packet: Packet) -> None:
    """Default sink: drop the packet."""


class EmsconStatusError(DeviceError):
    """The tracker answered a command with a non-zero ES_ResultStatus.

    ``code`` is ``tracker_<StatusName>``, e.g. ``tracker_TrackerNotInitialized``.
    """

    def __init__(self, command: int, status: int, how: str = "answered") -> None:
        self.command = int(command)
        self.status = int(status)
        self.status_name = enum_name(ES_ResultStatus, status)
        self.command_name = enum_name(ES_Command, command)
        super().__init__(f"tracker {how} {self.command_name} with {self.status_name} ({self.status})",
                         code=f"tracker_{self.status_name}")


class EmsconClient:
    """A connection to one emScon server; use from one thread only."""

    def __init__(self, host: str, port: int = 700, *, connect_timeout: float = 5.0,
                 timeout: float = 30.0, on_event: PacketSink = _ignore,
                 on_stream: PacketSink = _ignore) -> None:
        self.host, self.port = host, port
        self.connect_timeout = connect_timeout
        self.timeout = timeout
        self.on_event = on_event
        self.on_stream = on_stream
        self._sock: socket.socket | None = None
        self._framer = Framer(TO_CLIENT)
        self._waiting: int | None = None
        self._answers: list[Packet] = []
        self._results: list[Packet] = []
        self._async_error: Packet | None = None
        self.counters = {"packets": 0, "bytes": 0, "protocol_errors": 0, "unexpected": 0}
        self.lost_reason = ""
        self._head = b""  # first bytes of this connection: names a peer that is not an emScon server
        self._conn_packets = 0

    # ------------------------------------------------------------------ connection

    @property
    def connected(self) -> bool:
        return self._sock is not None

    def connect(self) -> None:
        """Open the TCP connection (no greeting is exchanged in emScon)."""
        self.close()
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.connect_timeout)
        except OSError as exc:
            raise DeviceLost(f"emScon server {self.host}:{self.port} unreachable: {exc}") from exc
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._sock = sock
        self._framer = Framer(TO_CLIENT)
        self.lost_reason = ""
        self._head, self._conn_packets = b"", 0

    def close(self) -> None:
        """Close the socket; safe to call twice."""
        sock, self._sock = self._sock, None
        if sock is not None:
            try:
                sock.close()
            except OSError:
                pass

    def _lost(self, reason: str, exc: BaseException | None = None) -> DeviceLost:
        self.close()
        self.lost_reason = reason
        err = DeviceLost(f"emScon connection to {self.host}:{self.port} lost: {reason}")
        err.__cause__ = exc
        return err

    # ------------------------------------------------------------------ reading

    def _read_once(self, timeout: float) -> int:
        """One ``recv`` (waiting at most ``timeout`` s); dispatch every whole packet."""
        sock = self._sock
        if sock is None:
            raise DeviceLost(f"emScon connection to {self.host}:{self.port} is closed"
                             + (f" ({self.lost_reason})" if self.lost_reason else ""))
        try:
            sock.settimeout(max(timeout, 1e-4))
            data = sock.recv(RECV_SIZE)
        except (socket.timeout, BlockingIOError):
            return 0
        except OSError as exc:
            raise self._lost(f"socket error: {exc}", exc) from exc
        if not data:
            raise self._lost("server closed the connection (EOF)")
        self.counters["bytes"] += len(data)
        if len(self._head) < HEAD_BYTES:
            self._head += data[:HEAD_BYTES - len(self._head)]
        try:
            packets = self._framer.feed(data)
        except ProtocolError as exc:
            self.counters["protocol_errors"] += 1
            if not self._conn_packets and not getattr(exc, "packets", None):
                raise self._foreign_peer(exc) from exc
            for p in getattr(exc, "packets", []):  # deliver what was good before the bad bytes
                self._dispatch(p)
            raise self._lost(f"protocol error: {exc}", exc) from exc
        for p in packets:
            self._dispatch(p)
        return len(packets)

    def _foreign_peer(self, exc: ProtocolError) -> DeviceLost:
        """Bad bytes before any good packet: the port speaks something else (HTTP, SSH, ...)."""
        self.close()
        shown = "".join(chr(b) if 32 <= b < 127 else f"\\x{b:02x}" for b in self._head)
        self.lost_reason = (f"the peer at {self.host}:{self.port} does not speak emScon (it sent '{shown}'); "
                            f"check the tracker URL's host and port (protocol error: {exc})")
        return DeviceLost(self.lost_reason)

    def _dispatch(self, p: Packet) -> None:
        self.counters["packets"] += 1
        self._conn_packets += 1
        kind = p.kind
        if kind in ("multi", "multi2"):
            self.on_stream(p)
        elif kind == "answer" and self._waiting is not None and p.command == self._waiting:
            self._answers.append(p)
        elif kind in ("single", "single2") and self._waiting == ES_Command.StartMeasurement:
            self._results.append(p)
        elif kind == "error":
            if self._waiting is not None and p.command == self._waiting:
                self._async_error = p
            self.on_event(p)
        elif kind in ("status_change", "reflector_pos", "nivel"):
            self.on_event(p)
        else:  # a late answer after a timeout, or a result nobody asked for
            self.counters["unexpected"] += 1
            self.on_event(p)

    def poll(self, timeout: float) -> int:
        """Read and dispatch for at most ``timeout`` s; return early once data came."""
        deadline = time.monotonic() + timeout
        n = self._read_once(timeout)
        while n and time.monotonic() < deadline:  # drain what is already buffered
            got = self._read_once(0.0)
            if not got:
                break
            n += got
        return n

    # ------------------------------------------------------------------ commands

    def _send(self, data: bytes, deadline: float) -> None:
        sock = self._sock
        if sock is None:
            raise DeviceLost(f"emScon connection to {self.host}:{self.port} is closed"
                             + (f" ({self.lost_reason})" if self.lost_reason else ""))
        try:
            sock.settimeout(max(deadline - time.monotonic(), 1e-3))
            sock.sendall(data)
        except socket.timeout as exc:
            raise self._lost("send timed out", exc) from exc
        except OSError as exc:
            raise self._lost(f"socket error on send: {exc}", exc) from exc

    def request(self, command: int, *, timeout: float | None = None, **params: Any) -> Packet:
        """Send one command and return its answer (raises on non-zero status)."""
        return self._transact(command, params, timeout, want="answer")[0]

    def measure(self, *, timeout: float | None = None) -> Packet:
        """StartMeasurement in stationary mode: wait for the answer and the result packet."""
        return self._transact(ES_Command.StartMeasurement, {}, timeout, want="result")[1]

    def get_reflectors(self, *, timeout: float | None = None) -> list[Packet]:
        """GetReflectors: collect the ``total_reflectors`` answers the server sends."""
        return self._transact(ES_Command.GetReflectors, {}, timeout, want="all")

    def _transact(self, command: int, params: dict[str, Any], timeout: float | None,
                  want: str) -> list[Packet]:
        if self._waiting is not None:
            raise DeviceError(f"emScon: {enum_name(ES_Command, command)} issued while "
                              f"{enum_name(ES_Command, self._waiting)} is still in flight",
                              code="tracker_busy")
        data = encode_request(command, **params)
        wait = self.timeout if timeout is None else timeout
        deadline = time.monotonic() + wait
        self._answers, self._results, self._async_error = [], [], None
        self._waiting = int(command)
        try:
            self._send(data, deadline)
            while True:
                done = self._check(command, want)
                if done is not None:
                    for p in done:
                        if p.status:  # accepted, yet a parameter was out of range: say so once
                            log.warning("tracker accepted %s with %s (%d): a parameter was out of range",
                                        enum_name(ES_Command, command), enum_name(ES_ResultStatus, p.status),
                                        int(p.status))
                    return done
                left = deadline - time.monotonic()
                if left <= 0:
                    what = (f"emScon {enum_name(ES_Command, command)}: no "
                            f"{'answer' if not self._answers else 'result'} within {wait:g} s")
                    # the late answer could be taken for the next command's: hang up to resync
                    self.close()
                    self.lost_reason = what + "; connection closed to resynchronise"
                    raise DeviceTimeout(self.lost_reason)
                self._read_once(left)
        finally:
            self._waiting = None

    def _check(self, command: int, want: str) -> list[Packet] | None:
        """Return the finished transaction, raise its error, or None to keep waiting."""
        if self._async_error is not None:
            raise EmsconStatusError(command, self._async_error.status, "sent an ErrorResponse for")
        if not self._answers:
            return None
        first = self._answers[0]
        if not accepted(first.status):
            raise EmsconStatusError(command, first.status)
        if want == "answer":
            return [first]
        if want == "result":
            if not self._results:
                return None
            res = self._results[0]
            if not accepted(res.status):
                raise EmsconStatusError(command, res.status, "returned a failed result for")
            return [first, res]
        total = int(first.values.get("total_reflectors", 0))
        for a in self._answers[1:]:
            if not accepted(a.status):
                raise EmsconStatusError(command, a.status)
        if len(self._answers) >= max(total, 1):
            return self._answers[:max(total, 0)] if total > 0 else []
        return None
