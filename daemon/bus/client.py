"""Bus client for ritactl, the calibration worker and tests (pyzmq + msgpack only).

``Client.call`` sends one request on a DEALER socket and waits (bounded) for the
reply with the same id; replies to earlier, timed-out requests are discarded. After
a timeout the socket is closed and reopened (the zguide's Lazy Pirate), so one lost
reply never poisons the next call. ``Subscriber`` follows telemetry or frames.

On tcp the client also watches its socket's handshake events: when the daemon's ZAP
handler refuses the CURVE key, libzmq (>= 4.3) sends a ZMTP ERROR and the monitor
reports ``EVENT_HANDSHAKE_FAILED_AUTH``; a plaintext client meeting a CURVE server
sees a mechanism mismatch. Either raises :class:`ClientRefused` at once instead of
waiting for the timeout. Without such a signal a timeout cannot tell a dead daemon
from a refused key, and its message says so.
"""
from __future__ import annotations

import itertools
import os
import time
import uuid
from typing import Any, Callable, Iterable, Iterator
from urllib.parse import urlsplit

import zmq

from daemon.bus.protocol import CommandError, make_request, unpack

DEFAULT_ENDPOINT = "ipc:///run/ritad/cmd"
ENV_ENDPOINT = "RITA_ENDPOINT"


class ClientTimeout(CommandError):
    """No answer in time (exit code 3 in ritactl)."""

    def __init__(self, message: str, code: str = "timeout") -> None:
        super().__init__(code, message)


class ClientRefused(ClientTimeout):
    """The daemon refused the handshake (key not allowed, or CURVE on one side only)."""

    def __init__(self, message: str) -> None:
        super().__init__(message, code="refused")


#: handshake events that mean "refused" rather than "no daemon"
#: and a dropped handshake: a CURVE server hangs up on a HELLO it cannot decrypt (wrong server key),
#: and on a plaintext greeting when it reads ours before we read its
_REFUSAL_EVENTS = zmq.EVENT_HANDSHAKE_FAILED_AUTH | zmq.EVENT_HANDSHAKE_FAILED_PROTOCOL \
    | zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL


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

    def __init__(self, endpoint: str | None = None, timeout: float = 5.0,
                 curve: dict[str, bytes] | tuple[dict[str, bytes] | None, str | None] | None = None,
                 ctx: zmq.Context | None = None, key_id: str | None = None, fail_fast: bool = False) -> None:
        """``fail_fast``: an ipc endpoint without its socket file is no daemon; say so at once (ritactl)
        instead of waiting out the timeout, as a client started before its daemon must."""
        if isinstance(curve, tuple):  # the (curve, key_id) pair from daemon.ctl.keys.client_curve
            keys, key_id = curve[0], key_id or curve[1]
        else:
            keys = curve
        self.endpoint = endpoint or default_endpoint()
        self.timeout = timeout
        self.curve = keys  # {"public", "secret", "server"} z85 keys, when the daemon requires CURVE
        self.key_id = key_id or (keys["public"].decode() if keys else None)  # named in refusals
        self.ctx = ctx or zmq.Context.instance()
        self._ids = itertools.count(1)
        self._prefix = uuid.uuid4().hex[:8]
        self.sock: zmq.Socket | None = None
        self._monitor: zmq.Socket | None = None
        self._hello: dict[str, Any] | None = None
        self.fail_fast = fail_fast

    def _socket(self) -> zmq.Socket:
        if self.sock is None:
            s = self.ctx.socket(zmq.DEALER)
            s.setsockopt(zmq.LINGER, 0)
            if self.curve:
                s.curve_publickey = self.curve["public"]
                s.curve_secretkey = self.curve["secret"]
                s.curve_serverkey = self.curve["server"]
            if self.endpoint.startswith("tcp://"):  # ipc has no key to refuse
                addr = f"inproc://client-monitor-{uuid.uuid4().hex}"
                s.monitor(addr, _REFUSAL_EVENTS)
                self._monitor = self.ctx.socket(zmq.PAIR)
                self._monitor.setsockopt(zmq.LINGER, 0)
                self._monitor.connect(addr)
            s.connect(self.endpoint)
            self.sock = s
        return self.sock

    def _reset(self) -> None:
        if self.sock is not None:
            if self._monitor is not None:
                self.sock.disable_monitor()
                self._monitor.close(linger=0)
                self._monitor = None
            self.sock.close(linger=0)
            self.sock = None

    def _refusal(self) -> ClientRefused | None:
        """A handshake failure reported by the socket monitor, as the error to raise (or None)."""
        from zmq.utils.monitor import parse_monitor_message

        assert self._monitor is not None
        while self._monitor.poll(0, zmq.POLLIN):
            event = parse_monitor_message(self._monitor.recv_multipart())
            if event["event"] == zmq.EVENT_HANDSHAKE_FAILED_AUTH:
                return ClientRefused(f"refused: key {self.key_id} is not allowed by the daemon "
                                     f"at {self.endpoint} (on the robot: "
                                     f"`ritactl keys allow FILE.key --name NAME --role operator`, "
                                     f"or --role viewer to watch only)")
            mismatch = event["value"] == zmq.PROTOCOL_ERROR_ZMTP_MECHANISM_MISMATCH
            if mismatch and self.curve:
                return ClientRefused(f"refused: the daemon at {self.endpoint} does not use CURVE, but this "
                                     f"client does (key {self.key_id})")
            if not self.curve:  # a mismatch, or a CURVE server hanging up on our plaintext greeting
                return ClientRefused(f"refused: the daemon at {self.endpoint} requires CURVE keys "
                                     f"and this client has none "
                                     f"(`ritactl keys init`, then --key NAME; docs/operations.md, Keys)")
            if event["event"] == zmq.EVENT_HANDSHAKE_FAILED_NO_DETAIL:
                return ClientRefused(f"refused: the daemon at {self.endpoint} dropped the CURVE handshake "
                                     f"(key {self.key_id}): "
                                     f"is the server key the robot's current server.key?")
        return None

    def _no_answer(self, cmd: str, wait: float) -> ClientTimeout:
        if not self.endpoint.startswith("tcp://"):
            return ClientTimeout(f"no answer from ritad at {self.endpoint} to {cmd!r} within {wait:g} s "
                                 f"(is the daemon running? set --endpoint or ${ENV_ENDPOINT})")
        key = self.key_id or "none: plaintext"
        return ClientTimeout(f"no answer: the daemon is down, or it refused this key ({key}); "
                             f"nothing from ritad at {self.endpoint} to {cmd!r} within {wait:g} s "
                             f"(check --endpoint or ${ENV_ENDPOINT})")

    def _check_socket(self, cmd: str) -> None:
        path = self.endpoint.removeprefix("ipc://")
        if self.endpoint.startswith("ipc://") and not path.startswith("@") and not os.path.exists(path):
            raise ClientTimeout(f"no answer from ritad at {self.endpoint} to {cmd!r}: "
                                f"its socket file {path} does not exist "
                                f"(is the daemon running? `systemctl status ritad`; "
                                f"another daemon: set --endpoint or ${ENV_ENDPOINT})", code="no_answer")

    def call_raw(self, cmd: str, args: dict[str, Any] | None = None,
                 timeout: float | None = None) -> tuple[Any, list[zmq.Frame]]:
        """Send a command; return ``(result, attachments)`` or raise CommandError/ClientTimeout."""
        if self.fail_fast:
            self._check_socket(cmd)
        req_id = f"{self._prefix}-{next(self._ids)}"
        sock = self._socket()
        wait = self.timeout if timeout is None else timeout
        deadline = time.monotonic() + wait
        # a DEALER without a pipe (a key just refused, the reconnect not yet made) blocks in send: bound it
        sock.setsockopt(zmq.SNDTIMEO, max(0, int(wait * 1000)))
        try:
            sock.send(make_request(req_id, cmd, args))
        except zmq.Again:
            refused = self._refusal() if self._monitor is not None else None
            self._reset()
            raise refused or self._no_answer(cmd, wait) from None
        poller = zmq.Poller()
        poller.register(sock, zmq.POLLIN)
        if self._monitor is not None:
            poller.register(self._monitor, zmq.POLLIN)
        while True:
            left = deadline - time.monotonic()
            ready = dict(poller.poll(int(left * 1000) + 1)) if left > 0 else {}
            refused = self._refusal() if self._monitor is not None and self._monitor in ready else None
            if refused is not None:
                self._reset()
                raise refused
            if sock not in ready:
                if time.monotonic() < deadline:
                    continue
                self._reset()
                raise self._no_answer(cmd, wait)
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

    def wait_ready(self, devices: Iterable[str] | None = None, timeout: float = 60.0, *, worker: bool = False,
                   alive: Callable[[], bool] | None = None, poll: float = 0.1) -> dict[str, Any]:
        """Poll ``status`` until the named devices (default: all) are READY; return that status.

        The one definition of "ritad is up, devices READY" that tests, benchmarks and the
        demo share. ``worker`` also waits until the calibration worker has been seen;
        ``alive`` (e.g. "the ritad process still runs") ends the wait early. No answer yet
        counts as not ready (ritad may still be binding); a refused key does not.
        Raises :class:`ClientTimeout` naming the device states last seen.
        """
        end = time.monotonic() + timeout
        last: dict[str, Any] = {}
        while True:
            if alive is not None and not alive():
                raise ClientTimeout(f"ritad at {self.endpoint} went away while waiting for READY")
            try:
                last = self.call("status", timeout=max(0.1, min(2.0, end - time.monotonic())))
            except ClientRefused:
                raise
            except ClientTimeout:
                last = {}
            devs = last.get("devices", {})
            want = list(devs) if devices is None else list(devices)
            ready = bool(devs) and all(devs.get(k, {}).get("state") == "READY" for k in want)
            if ready and (not worker or last.get("worker", {}).get("seen_s_ago") is not None):
                return last
            if time.monotonic() >= end:
                states = {k: v.get("state") for k, v in devs.items()} or "no answer"
                extra = f", worker {last.get('worker')}" if worker else ""
                raise ClientTimeout(f"devices not READY within {timeout:g} s at {self.endpoint}: "
                                    f"{states}{extra}")
            time.sleep(poll)

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
