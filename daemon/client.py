"""Bus client for ritactl, the calibration worker and tests (pyzmq + msgpack only).

``Client.call`` sends one request on a DEALER socket and waits (bounded) for the
reply with the same id; replies to earlier, timed-out requests are discarded. After
a timeout the socket is closed and reopened (the zguide's Lazy Pirate), so one lost
reply never poisons the next call. ``Subscriber`` follows telemetry or frames.
"""
from __future__ import annotations

import itertools
import os
import time
import uuid
from typing import Any, Iterator
from urllib.parse import urlsplit

import zmq

from daemon.protocol import CommandError, make_request, unpack

DEFAULT_ENDPOINT = "ipc:///run/ritad/cmd"
ENV_ENDPOINT = "RITA_ENDPOINT"


class ClientTimeout(CommandError):
    def __init__(self, message: str) -> None:
        super().__init__("timeout", message)


def default_endpoint() -> str:
    return os.environ.get(ENV_ENDPOINT) or DEFAULT_ENDPOINT


def resolve_endpoint(advertised: str, command_endpoint: str) -> str:
    """Make a bound endpoint reachable from here (``tcp://0.0.0.0:P`` → the daemon's host)."""
    if advertised.startswith("tcp://"):
        host = urlsplit(advertised).hostname or ""
        if host in ("0.0.0.0", "::", "*", ""):
            cmd_host = urlsplit(command_endpoint).hostname or "127.0.0.1"
            port = urlsplit(advertised).port
            return f"tcp://{cmd_host}:{port}"
    return advertised


class Client:
    """Synchronous request/reply client."""

    def __init__(self, endpoint: str | None = None, timeout: float = 5.0, curve: dict[str, bytes] | None = None,
                 ctx: zmq.Context | None = None) -> None:
        self.endpoint = endpoint or default_endpoint()
        self.timeout = timeout
        self.curve = curve  # {"public", "secret", "server"} z85 keys, when the daemon requires CURVE
        self.ctx = ctx or zmq.Context.instance()
        self._ids = itertools.count(1)
        self._prefix = uuid.uuid4().hex[:8]
        self.sock: zmq.Socket | None = None
        self._hello: dict[str, Any] | None = None

    def _socket(self) -> zmq.Socket:
        if self.sock is None:
            s = self.ctx.socket(zmq.DEALER)
            s.setsockopt(zmq.LINGER, 0)
            if self.curve:
                s.curve_publickey = self.curve["public"]
                s.curve_secretkey = self.curve["secret"]
                s.curve_serverkey = self.curve["server"]
            s.connect(self.endpoint)
            self.sock = s
        return self.sock

    def _reset(self) -> None:
        if self.sock is not None:
            self.sock.close(linger=0)
            self.sock = None

    def call_raw(self, cmd: str, args: dict[str, Any] | None = None,
                 timeout: float | None = None) -> tuple[Any, list[zmq.Frame]]:
        """Send a command; return ``(result, attachments)`` or raise CommandError/ClientTimeout."""
        req_id = f"{self._prefix}-{next(self._ids)}"
        sock = self._socket()
        sock.send(make_request(req_id, cmd, args))
        wait = self.timeout if timeout is None else timeout
        deadline = time.monotonic() + wait
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not sock.poll(int(left * 1000) + 1, zmq.POLLIN):
                if time.monotonic() < deadline:
                    continue
                self._reset()
                raise ClientTimeout(f"no answer from ritad at {self.endpoint} to {cmd!r} within {wait:g} s "
                                    f"(is the daemon running? set --endpoint or ${ENV_ENDPOINT})")
            frames = sock.recv_multipart(copy=False)
            try:
                msg = unpack(frames[0].buffer)
            except Exception:
                continue  # not ours to understand; keep waiting for our reply
            if not isinstance(msg, dict) or msg.get("id") != req_id:
                continue  # a late reply to an earlier, timed-out request
            if msg.get("ok"):
                return msg.get("result"), frames[1:]
            err = msg.get("error") or {}
            raise CommandError(err.get("code", "error"), err.get("message", "unknown error"))

    def call(self, cmd: str, timeout: float | None = None, **args: Any) -> Any:
        return self.call_raw(cmd, args, timeout)[0]

    def hello(self) -> dict[str, Any]:
        if self._hello is None:
            self._hello = self.call("hello")
        return self._hello

    def subscriber(self, topics: list[str] | None = None, frames: bool = False, hwm: int = 0) -> "Subscriber":
        """A SUB socket on the daemon's telemetry (or frame) endpoint, subscribed first."""
        info = self.hello()
        key = "frame_endpoints" if frames else "telemetry_endpoints"
        eps = info[key]
        # prefer an endpoint of the same transport as the command channel
        same = [e for e in eps if e.split("://")[0] == self.endpoint.split("://")[0]] or eps
        return Subscriber(resolve_endpoint(same[0], self.endpoint), topics, ctx=self.ctx,
                          curve=self.curve, hwm=hwm)

    def close(self) -> None:
        self._reset()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Subscriber:
    """Telemetry/frame subscriber; ``recv`` returns ``(topic, message, extra_frames)``."""

    def __init__(self, endpoint: str, topics: list[str] | None = None, ctx: zmq.Context | None = None,
                 curve: dict[str, bytes] | None = None, hwm: int = 0) -> None:
        self.ctx = ctx or zmq.Context.instance()
        self.sock = self.ctx.socket(zmq.SUB)
        self.sock.setsockopt(zmq.LINGER, 0)
        if hwm:
            self.sock.setsockopt(zmq.RCVHWM, hwm)
        if curve:
            self.sock.curve_publickey = curve["public"]
            self.sock.curve_secretkey = curve["secret"]
            self.sock.curve_serverkey = curve["server"]
        for t in topics or [""]:
            self.sock.setsockopt(zmq.SUBSCRIBE, t.encode())
        self.sock.connect(endpoint)
        self.endpoint = endpoint

    def recv(self, timeout: float = 1.0) -> tuple[str, Any, list[zmq.Frame]] | None:
        if not self.sock.poll(int(timeout * 1000), zmq.POLLIN):
            return None
        frames = self.sock.recv_multipart(copy=False)
        return frames[0].bytes.decode(), unpack(frames[1].buffer), frames[2:]

    def iter(self, duration: float) -> Iterator[tuple[str, Any, list[zmq.Frame]]]:
        end = time.monotonic() + duration
        while (left := end - time.monotonic()) > 0:
            msg = self.recv(min(left, 0.5))
            if msg is not None:
                yield msg

    def close(self) -> None:
        self.sock.close(linger=0)
