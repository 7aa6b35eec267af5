"""Telemetry and frame publishers: each PUB socket has its own owner thread.

Producers (device runners, the server, the supervisor) call ``publish`` from any
thread; it only appends to a bounded queue and never blocks. When a queue is full
the message is dropped and counted, so a stalled publisher or subscriber can never
stall acquisition. Telemetry keeps a last-value cache per topic with the sequence
number, which the ``state`` command returns (Clone pattern: subscribe first, then
fetch the snapshot, then drop updates with ``seq`` <= the snapshot's).
"""
from __future__ import annotations

import collections
import logging
import queue
import threading
import time
from typing import TYPE_CHECKING, Any, Callable

import zmq

from daemon.bus.protocol import SCHEMA_VERSION, pack, telemetry
from drivers.base import Frame

if TYPE_CHECKING:  # imported where used: only a CURVE daemon loads zmq.auth
    from daemon.bus.auth import Security

log = logging.getLogger(__name__)


def open_sockets(ctx: zmq.Context, kind: int, endpoints: list[str], security: Security | None = None,
                 setup: Callable[[zmq.Socket], None] | None = None) -> tuple[list[zmq.Socket], list[str]]:
    """One socket for the plain endpoints and, with ``security``, one CURVE socket for the tcp ones.

    The security mechanism is a property of a socket, so local ipc clients and remote
    CURVE clients need separate sockets; the owner thread serves both.
    """
    from daemon.bus.auth import is_secure_endpoint

    secure = [e for e in endpoints if security is not None and is_secure_endpoint(e)]
    plain = [e for e in endpoints if e not in secure]
    socks, bound = [], []
    for group, curve in ((plain, None), (secure, security)):
        if not group:
            continue
        sock = ctx.socket(kind)
        socks.append(sock)
        try:
            sock.setsockopt(zmq.LINGER, 0)
            if setup is not None:
                setup(sock)
            if curve is not None:
                curve.apply(sock)
            bound += bind_all(sock, group)
        except BaseException:  # e.g. a port in use: close what this opened, or the context never ends
            for opened in socks:
                opened.close(linger=0)
            raise
    return socks, bound


def stop_owner(owner: threading.Thread, stop_evt: threading.Event, close: Callable[[], None],
               timeout: float) -> None:
    """End a socket's owner thread and wait for it; one never started (its daemon's build failed
    later) closes its sockets here, as no thread will."""
    stop_evt.set()
    if owner.ident is None:
        close()
    else:
        owner.join(timeout)


def bind_all(sock: zmq.Socket, endpoints: list[str]) -> list[str]:
    """Bind to every endpoint; return the endpoints actually bound (tcp port 0 resolved)."""
    bound = []
    for ep in endpoints:
        if ep.startswith("ipc://"):
            from pathlib import Path

            Path(ep[len("ipc://"):]).parent.mkdir(parents=True, exist_ok=True)
        sock.bind(ep)
        bound.append(sock.getsockopt_string(zmq.LAST_ENDPOINT))
    return bound


class _Publisher(threading.Thread):
    """One PUB socket per endpoint, fed from a bounded queue by this owner thread only."""

    def __init__(self, name: str, ctx: zmq.Context, endpoints: list[str], hwm: int, queue_size: int,
                 security: Security | None) -> None:
        super().__init__(name=name, daemon=True)
        self.socks, self.endpoints = open_sockets(ctx, zmq.PUB, endpoints, security,
                                                  lambda s: s.setsockopt(zmq.SNDHWM, hwm))
        self._q: queue.Queue[Any] = queue.Queue(queue_size)
        self._stop_evt = threading.Event()
        self.seq = 0
        self.sent = 0
        self.heartbeat = time.monotonic()

    def _send(self, item: Any) -> None:
        raise NotImplementedError

    def run(self) -> None:
        while not self._stop_evt.is_set():
            self.heartbeat = time.monotonic()
            try:
                item = self._q.get(timeout=0.2)
            except queue.Empty:
                continue
            self._send(item)
        self._close()

    def _close(self) -> None:
        for sock in self.socks:
            sock.close(linger=0)

    def stop(self, timeout: float = 2.0) -> None:
        stop_owner(self, self._stop_evt, self._close, timeout)


class TelemetryPublisher(_Publisher):
    """Owner of the telemetry PUB socket."""

    def __init__(self, ctx: zmq.Context, endpoints: list[str], hwm: int = 10000, queue_size: int = 20000,
                 security: Security | None = None) -> None:
        super().__init__("pub-telemetry", ctx, endpoints, hwm, queue_size, security)
        self._lock = threading.Lock()
        self.latest: dict[str, dict[str, Any]] = {}
        self._dropped: collections.Counter[str] = collections.Counter()  # under _lock: every producer counts

    def _drop(self, topic: str) -> None:
        with self._lock:
            self._dropped[topic] += 1

    @property
    def dropped(self) -> dict[str, int]:
        with self._lock:
            return dict(self._dropped)

    def publish(self, topic: str, data: Any) -> None:
        try:
            self._q.put_nowait((topic, data, time.time_ns()))
        except queue.Full:
            self._drop(topic)

    def snapshot(self) -> dict[str, Any]:
        """Last value per topic and the sequence number they are current at."""
        with self._lock:
            return {"seq": self.seq, "latest": dict(self.latest)}

    def counters(self) -> dict[str, Any]:
        return {"sent": self.sent, "queued": self._q.qsize(), "dropped": self.dropped}

    def _send(self, item: tuple[str, Any, int]) -> None:
        topic, data, t_ns = item
        with self._lock:
            self.seq += 1
            seq = self.seq
            self.latest[topic] = {"seq": seq, "t_ns": t_ns, "data": data}
        try:
            msg = [topic.encode(), telemetry(seq, t_ns, data)]
        except (TypeError, ValueError) as exc:  # a payload msgpack cannot encode: a bug, not a crash
            log.error("cannot publish %s: %s", topic, exc)
            self._drop(topic)
            return
        for sock in self.socks:
            try:
                sock.send_multipart(msg, flags=zmq.NOBLOCK)
            except zmq.Again:
                self._drop(topic)
        self.sent += 1


class FramePublisher(_Publisher):
    """Owner of the frame PUB socket: ``[topic, header, pixels]`` zero-copy, small HWM."""

    def __init__(self, ctx: zmq.Context, endpoints: list[str], hwm: int = 2, queue_size: int = 4,
                 security: Security | None = None) -> None:
        super().__init__("pub-frames", ctx, endpoints, hwm, queue_size, security)
        self._drops_lock = threading.Lock()  # the camera's thread and this one both count drops
        self._dropped = 0  # frames dropped (publisher or subscriber could not keep up)
        self.last_frame: Frame | None = None  # camera.preview makes live-view pictures from it

    def _drop(self) -> None:
        with self._drops_lock:
            self._dropped += 1

    @property
    def dropped(self) -> int:
        with self._drops_lock:
            return self._dropped

    def publish(self, frame: Frame) -> None:
        try:
            self._q.put_nowait(frame)
        except queue.Full:
            self._drop()

    def counters(self) -> dict[str, Any]:
        return {"sent": self.sent, "dropped": self.dropped, "queued": self._q.qsize(), "seq": self.seq}

    def _send(self, frame: Frame) -> None:
        self.seq += 1
        header = {"v": SCHEMA_VERSION, "seq": self.seq, "dropped": self.dropped,
                  "publish_monotonic_ns": time.monotonic_ns(), **frame.header()}
        pixels = frame.pixels if frame.pixels.flags.c_contiguous else frame.pixels.copy()
        packed = pack(header)
        for sock in self.socks:
            try:
                # copy=False: libzmq references the daemon-owned array; nobody mutates it afterwards
                sock.send_multipart([b"camera.frame", packed, pixels.data], copy=False, flags=zmq.NOBLOCK)
            except zmq.Again:
                self._drop()
        self.sent += 1
        self.last_frame = frame
