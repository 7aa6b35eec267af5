"""Command server: the ROUTER socket and its owner thread.

Requests are decoded and validated here; every request gets exactly one reply,
``ok`` + result or an error with a stable code, whatever the input was. Handlers
either return a result at once or a ``Future`` (device jobs); completed futures are
handed back to this thread through a pipe that wakes the poller, so the ROUTER is
only ever touched by its owner.

Every request is checked against its sender's role before a handler sees it
(:mod:`daemon.bus.roles`): CURVE clients have the role of their allow-list entry,
looked up again at every request so a revocation or a new role applies to open
connections; plain (ipc) clients have ``[security] ipc_role``. Motion commands are
logged with the key that asked for them.

Every command the table does not mark ``polled`` is also reported, once its reply is sent, to
``on_command`` (ritad publishes it as ``daemon.command`` telemetry, so a recording holds the
session's command/reply pairs): name, arguments, the caller's key name and role, ok or the error
code and message, and the receive and reply times. Reporting never fails a command: an exception
from ``on_command`` is logged.
"""
from __future__ import annotations

import functools
import logging
import os
import queue
import reprlib
import threading
import time
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Mapping, NamedTuple

import zmq

from daemon.bus.command_table import COMMANDS, Command
from daemon.bus.protocol import (CommandError, ErrorCode, ProtocolError, error_reply, ok_reply,
                             parse_request)
from daemon.bus.repeatlog import RepeatGate, times
from daemon.bus.roles import refusal
from daemon.ritad.publisher import open_sockets, stop_owner

if TYPE_CHECKING:  # imported where used: only a CURVE daemon loads zmq.auth
    from daemon.bus.auth import Security

log = logging.getLogger(__name__)


@dataclass
class Reply:
    """A handler result with raw binary attachments sent as extra frames (e.g. pixels)."""

    result: Any
    attachments: list[Any] = field(default_factory=list)


@dataclass
class Request:
    """What a handler sees of the request."""

    id: Any
    cmd: str
    args: dict[str, Any]
    peer: str  # "name (public key)" of a CURVE client, "local peer-<routing id hex>" of a plain one
    role: str = "viewer"  # the sender's role; the server already checked it against the command's
    key: str | None = None  # the CURVE client's z85 public key; None for plain (ipc) clients


class Caller(NamedTuple):
    peer: str  # for logs and job owners
    who: str  # for messages: "key bob" or "local client"
    role: str
    key: str | None
    name: str | None = None  # the CURVE key's allow-list name; None for a plain (ipc) client


class Audit(NamedTuple):
    """What ``daemon.command`` reports of a request, kept until its reply is sent."""

    cmd: str
    id: Any
    args: Any  # None when the request was larger than AUDIT_ARGS_BYTES
    key: str | None
    role: str
    recv_ns: int


#: requests larger than this (plate uploads) are reported without their arguments: telemetry stays small
AUDIT_ARGS_BYTES = 8192
CommandHook = Callable[[dict[str, Any]], None]


#: a refusal repeated by a client in a loop is logged once per window with its count
REFUSAL_WINDOW_S = 60.0
_ARGS = reprlib.Repr()  # motion args in the log, bounded whatever a client sends
_ARGS.maxdict, _ARGS.maxstring, _ARGS.maxother = 10, 60, 60

Handler = Callable[[Request], Any]


class CommandServer(threading.Thread):
    """Owner of the ROUTER socket."""

    def __init__(self, ctx: zmq.Context, endpoints: list[str], handlers: dict[str, Handler],
                 max_message_bytes: int = 1 << 20, security: Security | None = None,
                 plain_role: str = "operator", on_command: CommandHook | None = None,
                 table: Mapping[str, Command] = COMMANDS) -> None:
        super().__init__(name="cmd-server", daemon=True)
        self.handlers = handlers
        self.table = table  # the daemon's: roles, motions and polled reads of its plugins' commands too
        self.on_command = on_command
        self.max_bytes = max_message_bytes
        self.plain_role = plain_role  # of clients on sockets without CURVE (ipc; tcp with insecure_tcp)
        self.keyring = security.keyring if security is not None else None

        def setup(sock: zmq.Socket) -> None:
            sock.setsockopt(zmq.ROUTER_MANDATORY, 1)
            # hard guard against memory abuse; our own check below answers politely first
            sock.setsockopt(zmq.MAXMSGSIZE, max(4 * max_message_bytes, 1 << 22))
            sock.setsockopt(zmq.HEARTBEAT_IVL, 2000)
            sock.setsockopt(zmq.HEARTBEAT_TIMEOUT, 6000)

        self.socks, self.endpoints = open_sockets(ctx, zmq.ROUTER, endpoints, security, setup)
        self._curve_socks = {s for s in self.socks if s.getsockopt(zmq.CURVE_SERVER)}
        self._done: queue.Queue[tuple[tuple[zmq.Socket, list[bytes]], Any, str, Audit | None, Future]] = \
            queue.Queue()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        self._stop_evt = threading.Event()
        self.requests = 0
        self.errors = 0
        self.pending = 0
        self.heartbeat = time.monotonic()
        self._refusals: RepeatGate[tuple[str, str, str]] = RepeatGate(REFUSAL_WINDOW_S)  # owner thread only
        self._flushed = time.monotonic()

    # ------------------------------------------------------------------ helpers

    def _send(self, envelope: tuple[zmq.Socket, list[bytes]], payload: bytes,
              attachments: list[Any] | None = None) -> None:
        sock, route = envelope
        frames = [*route, payload, *(attachments or [])]
        try:
            sock.send_multipart(frames, copy=not attachments)
        except zmq.ZMQError as exc:  # EHOSTUNREACH: the client went away; nothing to do
            log.info("reply to a vanished client dropped: %s", exc)

    def _reply(self, envelope: tuple[zmq.Socket, list[bytes]], req_id: Any, cmd: str, result: Any) -> None:
        if isinstance(result, Reply):
            self._send(envelope, ok_reply(req_id, result.result), result.attachments)
        else:
            self._send(envelope, ok_reply(req_id, result))

    def _error(self, envelope: tuple[zmq.Socket, list[bytes]], req_id: Any, code: str, message: str,
               cmd: str = "", who: str = "") -> None:
        self.errors += 1
        self._log_error(cmd or "?", code, message, who)
        self._send(envelope, error_reply(req_id, code, message))

    def _audit(self, audit: Audit | None, code: str | None = None, message: str | None = None) -> None:
        """Report a sent reply to ``on_command`` (never raises: a command must not fail over its report)."""
        if audit is None or self.on_command is None:
            return
        try:
            self.on_command({"cmd": audit.cmd, "id": audit.id, "args": audit.args, "key": audit.key,
                             "role": audit.role, "ok": code is None, "code": code, "message": message,
                             "recv_ns": audit.recv_ns, "reply_ns": time.time_ns()})
        except Exception:
            log.exception("daemon.command report of %s failed (the command itself was answered)", audit.cmd)

    def _log_error(self, cmd: str, code: str, message: str, who: str) -> None:
        """One line per (command, code, sender) per window; a crash is always logged."""
        level = logging.WARNING if code in (ErrorCode.FORBIDDEN, ErrorCode.STOPPED) else logging.INFO
        text = f"command {cmd} failed: [{code}] {message}" + (f" ({who})" if who else "")
        held = 0 if code == ErrorCode.INTERNAL else self._refusals.admit((cmd, code, who), (level, text))
        if held is not None:
            log.log(level, "%s%s", text, times(held + 1, REFUSAL_WINDOW_S) if held else "")

    def _flush_refusals(self) -> None:
        """Counts of refusals held back whose window ended (at most once a second)."""
        now = time.monotonic()
        if now - self._flushed < 1.0:
            return
        self._flushed = now
        for _, n, (level, text) in self._refusals.overdue():
            log.log(level, "%s%s", text, times(n, REFUSAL_WINDOW_S))

    def _caller(self, sock: zmq.Socket, frames: list[zmq.Frame]) -> Caller | None:
        """Who sent ``frames`` and their role; None for a CURVE key that is no longer allowed."""
        if sock not in self._curve_socks:
            peer = f"local peer-{bytes(frames[0].bytes).hex()[:10]}"
            return Caller(peer, "local client", self.plain_role, None)
        try:
            user_id = frames[-1].get("User-Id")  # the z85 public key ZAP accepted at the handshake
        except (zmq.ZMQError, AttributeError):
            user_id = None
        key = user_id if isinstance(user_id, str) else None
        entry = self.keyring.lookup(key.encode()) if key and self.keyring is not None else None
        if entry is None:
            return None
        return Caller(f"{entry.name} ({key})", f"key {entry.name}", entry.role, key, entry.name)

    def _admit(self, envelope: tuple[zmq.Socket, list[bytes]], frames: list[zmq.Frame], req_id: Any,
               cmd: str, audit: Callable[[Caller], Audit | None]) -> Caller | None:
        """The caller when it may send ``cmd``; else the error is sent here and None returned."""
        caller = self._caller(envelope[0], frames)
        if caller is None:
            self._error(envelope, req_id, ErrorCode.UNAUTHORIZED, "this key is no longer in the daemon's "
                                                                  "allow-list (revoked)", cmd)
            return None
        if cmd not in self.handlers:
            self._error(envelope, req_id, ErrorCode.UNKNOWN_COMMAND,
                        f"unknown command {cmd!r}; 'help' lists the commands", cmd)
            return None
        why = refusal(cmd, caller.role, caller.who, self.table)
        if why is not None:  # a WARNING naming the sender (rate-limited like every refusal)
            self._error(envelope, req_id, ErrorCode.FORBIDDEN, why, cmd,
                        f"from {caller.peer}, role {caller.role}")
            self._audit(audit(caller), ErrorCode.FORBIDDEN, why)
            return None
        return caller

    # ------------------------------------------------------------------ owner thread

    def _on_request(self, sock: zmq.Socket, frames: list[zmq.Frame]) -> None:
        recv_ns = time.time_ns()
        self.requests += 1
        envelope = (sock, [f.bytes for f in frames[:-1]])
        body = frames[-1]
        if len(frames) < 2:
            return  # no routing id: nothing we could answer
        req_id: Any = None
        if len(body) > self.max_bytes:
            self._error(envelope, None, ErrorCode.TOO_LARGE,
                        f"request of {len(body)} bytes exceeds the {self.max_bytes}-byte limit")
            return
        try:
            msg = parse_request(body.buffer)
        except ProtocolError as exc:
            self._error(envelope, None, exc.code, str(exc))
            return
        req_id, cmd = msg["id"], msg["cmd"]
        declared = self.table.get(cmd)

        def audit(c: Caller) -> Audit | None:
            if self.on_command is None or declared is not None and declared.polled:
                return None
            args = msg["args"] if len(body) <= AUDIT_ARGS_BYTES else None
            return Audit(cmd, req_id, args, c.name, c.role, recv_ns)

        caller = self._admit(envelope, frames, req_id, cmd, audit)
        if caller is None:
            return
        request = Request(req_id, cmd, msg["args"], caller.peer, caller.role, caller.key)
        self._handle(envelope, request, declared, audit(caller))

    def _handle(self, envelope: tuple[zmq.Socket, list[bytes]], request: Request, declared: Command | None,
                audit: Audit | None) -> None:
        req_id, cmd = request.id, request.cmd
        if declared is not None and declared.motion:  # moves and stops: logged with the caller
            log.info("motion %s id=%s from %s (role %s): %s", cmd, req_id, request.peer, request.role,
                     _ARGS.repr(request.args))
        else:
            # polled reads at DEBUG, else one open console page alone writes several INFO lines a second
            log.log(logging.DEBUG if declared is not None and declared.polled else logging.INFO,
                    "command %s id=%s from %s", cmd, req_id, request.peer)
        try:
            result = self.handlers[cmd](request)
        except CommandError as exc:
            self._error(envelope, req_id, exc.code, exc.args[0], cmd)
            self._audit(audit, exc.code, exc.args[0])
            return
        except Exception as exc:
            log.exception("handler %s crashed", cmd)
            self._error(envelope, req_id, ErrorCode.INTERNAL, f"{type(exc).__name__}: {exc}", cmd)
            self._audit(audit, ErrorCode.INTERNAL, f"{type(exc).__name__}: {exc}")
            return
        if isinstance(result, Future):
            self.pending += 1
            result.add_done_callback(functools.partial(self._complete, envelope, req_id, cmd, audit))
        else:
            self._reply(envelope, req_id, cmd, result)
            self._audit(audit)

    def _complete(self, envelope: tuple[zmq.Socket, list[bytes]], req_id: Any, cmd: str, audit: Audit | None,
                  fut: Future) -> None:
        """Called in whatever thread finished the future: hand it to the owner thread."""
        self._done.put((envelope, req_id, cmd, audit, fut))
        try:
            os.write(self._wake_w, b"x")
        except OSError:
            pass

    def _drain_done(self) -> None:
        try:
            os.read(self._wake_r, 4096)
        except BlockingIOError:
            pass
        while True:
            try:
                envelope, req_id, cmd, audit, fut = self._done.get_nowait()
            except queue.Empty:
                return
            self.pending -= 1
            exc = fut.exception()
            if exc is None:
                self._reply(envelope, req_id, cmd, fut.result())
                self._audit(audit)
            elif isinstance(exc, CommandError):
                self._error(envelope, req_id, exc.code, exc.args[0], cmd)
                self._audit(audit, exc.code, exc.args[0])
            else:
                self._error(envelope, req_id, ErrorCode.INTERNAL, f"{type(exc).__name__}: {exc}", cmd)
                self._audit(audit, ErrorCode.INTERNAL, f"{type(exc).__name__}: {exc}")

    def run(self) -> None:
        poller = zmq.Poller()
        for sock in self.socks:
            poller.register(sock, zmq.POLLIN)
        poller.register(self._wake_r, zmq.POLLIN)
        while not self._stop_evt.is_set():
            self.heartbeat = time.monotonic()
            self._flush_refusals()
            events = dict(poller.poll(200))
            if self._wake_r in events:
                self._drain_done()
            for sock in self.socks:
                if sock not in events:
                    continue
                for _ in range(100):  # bounded batch so completions are not starved
                    try:
                        frames = sock.recv_multipart(zmq.NOBLOCK, copy=False)
                    except zmq.Again:
                        break
                    self._on_request(sock, frames)
        self._close()

    def stop(self, timeout: float = 2.0) -> None:
        stop_owner(self, self._stop_evt, self._close, timeout)

    def _close(self) -> None:
        for sock in self.socks:
            sock.close(linger=0)
        os.close(self._wake_r)
        os.close(self._wake_w)
