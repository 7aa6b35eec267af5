"""``ritactl replay``: a recording republished as if ritad were live, for ``watch``, the console and tests.

It binds the three bus endpoints a client expects (docs/protocol.md): a command socket that
answers ``hello`` (which names the other two), ``ping``, ``state`` (the Clone snapshot, as of the
replay's position) and ``status`` (the last ``daemon.health`` replayed); every other
command is refused with ``forbidden``, as a viewer's would be: a replay can be watched, not
driven. Telemetry goes out on a PUB socket in the bus's own format
(``[topic, msgpack {v, seq, t_ns, data}]`` with the message's log time, its sample's time, as t_ns,
and the replay's own seq, one counter across topics as ritad's: the file's sequences count each
channel's messages), frames on a frame socket. Channels are named ``/robot/state`` for the bus's
``robot.state`` (mcapfile.mcap_topic; an older recording's ``robot.state`` is read as it is). A null
the recorder left out of a message (its schema has a type for the field: mcapfile.drop_typed_nulls)
is put back; the journal's foxglove.Log becomes a ``log`` record again; a CompressedImage frame is
decoded (with OpenCV; skipped without it); the channels derived for Foxglove (poses) are not
replayed, their sources are. Messages keep the file's order; pacing follows their log times
divided by ``--speed``.

Only 127.0.0.1 and ipc endpoints are accepted: a replay is for this computer.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import socket
import struct
import sys
import tempfile
import time
from pathlib import Path
from typing import IO, Any, Iterator

import zmq

from daemon import __version__
from daemon.bus.protocol import (SCHEMA_VERSION, ErrorCode, ProtocolError, error_reply, ok_reply, pack,
                                 parse_request, telemetry)
from daemon.ctl import foxglove as fox
from daemon.ctl import mcapfile as fmt
from daemon.ctl.exitcodes import CtlError, Exit, bad_input

_LOCAL_TCP = re.compile(r"^tcp://(127\.0\.0\.1|localhost):(\d{1,5}|\*)$")
ANSWERED = ("hello", "ping", "state", "status")


def default_endpoint() -> str:
    return f"ipc://{Path(tempfile.gettempdir()) / 'rita-replay' / 'cmd'}"


def _check_free(path: Path) -> None:
    """Refuse a socket file something listens on: binding it would take the endpoint from a live ritad."""
    if not path.exists():
        return
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.connect(str(path))
    except OSError:
        return  # nothing listening (a stale file from an earlier replay): ours to reuse
    finally:
        probe.close()
    raise CtlError(Exit.USAGE, "usage", f"bad replay endpoint ipc://{path}: something is listening there "
                                        f"(a running ritad?); choose another path")


def endpoints(cmd: str) -> tuple[str, str, str]:
    """Command, telemetry and frame endpoints: ipc siblings of the command socket, or tcp ports of
    the system's."""
    if cmd.startswith("ipc://"):
        path = Path(cmd.removeprefix("ipc://"))
        if not path.parent.is_dir():
            raise bad_input(f"--endpoint {cmd}: the folder {path.parent} does not exist")
        for p in (path, path.parent / "telemetry", path.parent / "frames"):
            _check_free(p)
        return cmd, f"ipc://{path.parent / 'telemetry'}", f"ipc://{path.parent / 'frames'}"
    m = _LOCAL_TCP.match(cmd)
    if not m or (m.group(2) != "*" and not 0 <= int(m.group(2)) < 65536):
        raise CtlError(Exit.USAGE, "usage", f"bad replay endpoint {cmd!r}: use ipc:///PATH or "
                                            f"tcp://127.0.0.1:PORT (a replay serves this computer only)")
    host = m.group(1)
    cmd = f"tcp://{host}:*" if m.group(2) == "0" else cmd
    return cmd, f"tcp://{host}:*", f"tcp://{host}:*"


class ReplayServer:
    """The bus sockets of a replay and the state a late joiner asks for."""

    def __init__(self, cmd: str, source: str, ctx: zmq.Context | None = None) -> None:
        self.ctx = ctx or zmq.Context.instance()
        want = endpoints(cmd)
        self.router = self._bind(zmq.ROUTER, want[0])
        self.pub = self._bind(zmq.XPUB, want[1])  # XPUB: we see subscriptions arrive
        self.frames = self._bind(zmq.XPUB, want[2])
        self.pub.setsockopt(zmq.SNDHWM, 0)  # a replay has the whole file: never drop for a slow reader
        self.frames.setsockopt(zmq.SNDHWM, 2)  # frames are 12 MB: drop for a slow reader, as ritad does
        self.source = source
        self.latest: dict[str, dict[str, Any]] = {}
        self.seq = 0
        self.subscribers = 0  # subscriptions seen on the telemetry socket
        self.frame_subscribers = 0

    def _bind(self, kind: int, endpoint: str) -> zmq.Socket:
        s = self.ctx.socket(kind)
        s.setsockopt(zmq.LINGER, 2000)  # the last messages still reach the subscribers after the end
        s.bind(endpoint)
        return s

    def endpoint(self, s: zmq.Socket) -> str:
        return str(s.getsockopt_string(zmq.LAST_ENDPOINT))

    def hello(self) -> dict[str, Any]:
        return {"name": "ritactl replay", "version": __version__, "schema": SCHEMA_VERSION,
                "pid": os.getpid(), "sim": False, "replay": self.source,
                "endpoints": [self.endpoint(self.router)],
                "telemetry_endpoints": [self.endpoint(self.pub)],
                "frame_endpoints": [self.endpoint(self.frames)]}

    def state(self) -> dict[str, Any]:
        health = self.latest.get("daemon.health", {}).get("data") or {}
        devices = dict(health.get("devices") or {})
        change = self.latest.get("daemon.state", {}).get("data")
        if change and change.get("device"):  # a state change newer than the last health message
            devices[change["device"]] = {**devices.get(change["device"], {}), **change}
        latch = self.latest.get("robot.latch", {}).get("data")
        return {"seq": self.seq, "latest": self.latest, "devices": devices, "latch": latch}

    def _answer(self, cmd: str) -> Any:
        if cmd == "hello":
            return self.hello()
        if cmd == "ping":
            return {"pong": True, "t_ns": time.time_ns()}
        if cmd == "state":
            return self.state()
        if "daemon.health" not in self.latest:
            raise ProtocolError(ErrorCode.NOT_READY, "no daemon.health replayed yet")
        return self.latest["daemon.health"]["data"]

    def serve(self, timeout: float) -> None:
        """Answer requests and note subscriptions for up to ``timeout`` seconds (at least one poll)."""
        poller = zmq.Poller()
        poller.register(self.router, zmq.POLLIN)
        poller.register(self.pub, zmq.POLLIN)
        poller.register(self.frames, zmq.POLLIN)
        end = time.monotonic() + timeout
        while True:
            ready = dict(poller.poll(max(0, int((end - time.monotonic()) * 1000))))
            if self.pub in ready:
                self.subscribers += self._subscriptions(self.pub)
            if self.frames in ready:
                self.frame_subscribers += self._subscriptions(self.frames)
            if self.router in ready:
                self._request(self.router.recv_multipart())
            if time.monotonic() >= end or not ready:
                return

    @staticmethod
    def _subscriptions(s: zmq.Socket) -> int:
        """New subscriptions waiting on an XPUB socket (a first byte 1; 0 is an unsubscription)."""
        n = 0
        while s.poll(0):
            n += s.recv()[:1] == b"\x01"
        return n

    def _request(self, frames: list[bytes]) -> None:
        ident, body = frames[0], frames[-1]
        req_id: Any = None
        try:
            req = parse_request(body)
            req_id = req["id"]
            if req["cmd"] not in ANSWERED:
                raise ProtocolError(ErrorCode.FORBIDDEN,
                                    f"{req['cmd']!r}: this is a replay of {self.source}; "
                                    f"it answers only {', '.join(ANSWERED)}")
            reply = ok_reply(req_id, self._answer(req["cmd"]))
        except ProtocolError as exc:
            reply = error_reply(req_id, exc.code, str(exc))
        self.router.send_multipart([ident, reply])

    def publish(self, topic: str, seq: int, t_ns: int, data: Any) -> None:
        self.seq = seq
        self.latest[topic] = {"seq": seq, "t_ns": t_ns, "data": data}
        self.pub.send_multipart([topic.encode(), telemetry(seq, t_ns, data)])

    def publish_frame(self, header: dict[str, Any], pixels: bytes | memoryview) -> None:
        self.frames.send_multipart([fmt.FRAME_TOPIC.encode(), pack(header), pixels])

    def close(self) -> None:
        for s in (self.router, self.pub, self.frames):
            s.close()


def messages(f: IO[bytes]) -> Iterator[tuple[str, str, str, bytes, int, bytes]]:
    """``(channel, message encoding, schema name, schema data, log_time, data)`` in the file's order
    (the order received)."""
    try:
        from mcap.exceptions import McapError
        from mcap.reader import make_reader
    except ImportError as exc:
        raise CtlError(Exit.BAD_INPUT, "missing_package", f"replay needs the mcap package ({exc.name} is not "
                                                          f"installed): pip install --upgrade rita") from None
    try:
        for schema, channel, m in make_reader(f).iter_messages(log_time_order=False):
            yield (channel.topic, channel.message_encoding, schema.name if schema else "",
                   schema.data if schema else b"", m.log_time, m.data)
    except (McapError, OSError, ValueError, struct.error) as exc:  # a truncated file fails its seeks too
        raise bad_input(f"{getattr(f, 'name', 'the file')} is not a readable MCAP recording: {exc}") from None


#: channels the recorder derives from others for Foxglove: a replay has their source already
DERIVED = (fox.ROBOT_POSE_TOPIC, fox.TRACKER_POSE_TOPIC)


def _image(schema_name: str, data: bytes) -> memoryview | None:
    """A frame's pixels from its RawImage, or its CompressedImage decoded (OpenCV; None without it)."""
    if schema_name != fmt.COMPRESSED_IMAGE_SCHEMA:
        return fmt.pixels_of(data)
    try:
        import cv2
        import numpy as np
    except ImportError:
        return None
    image = cv2.imdecode(np.frombuffer(fmt.compressed_data(data), dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    return None if image is None else memoryview(np.ascontiguousarray(image).tobytes())


def _decoded(topic: str, encoding: str, schema_name: str, data: bytes, schema: dict[str, Any]) -> Any:
    """A message's content, or None for one not in ritad's layout (another tool's channel, bad JSON):
    a frame's pixels, or the bus message's ``data`` (a foxglove.Log turned back into a ``log`` record)."""
    if topic == fmt.FRAME_TOPIC:
        return _image(schema_name, data) if encoding == "cdr" else None
    if encoding != "json":
        return None
    try:
        if schema_name == "foxglove." + fox.LOG_SCHEMA:
            return fox.log_record(json.loads(data))
        return fmt.restore_nulls(json.loads(data), schema)
    except (ValueError, TypeError):
        return None


def _schema(cache: dict[bytes, dict[str, Any]], data: bytes) -> dict[str, Any]:
    if data not in cache:
        try:
            parsed = json.loads(data) if data else {}
        except ValueError:
            parsed = {}
        cache[data] = parsed if isinstance(parsed, dict) else {}
    return cache[data]


def play(server: ReplayServer, f: IO[bytes], speed: float | None) -> tuple[int, int]:
    """Publish every message of ``f``: ``(published, skipped)``. ``speed`` None: as fast as possible."""
    n = skipped = 0
    start = time.monotonic()
    first: int | None = None
    due = 0.0
    header: dict[str, Any] | None = None
    schemas: dict[bytes, dict[str, Any]] = {}
    for channel, encoding, schema_name, schema, log_ns, data in messages(f):
        if channel in DERIVED:
            continue
        topic = fmt.bus_topic(channel)
        first = log_ns if first is None else first
        if speed is not None:
            due = max(due, (log_ns - first) / 1e9 / speed)
            server.serve(max(0.0, start + due - time.monotonic()))
        elif n % 256 == 0:
            server.serve(0)
        content = _decoded(topic, encoding, schema_name, data,
                           _schema(schemas, schema) if encoding == "json" else {})
        if content is None:
            skipped += 1
            continue
        if topic == fmt.FRAME_HEADER_TOPIC:
            header = content
        elif topic == fmt.FRAME_TOPIC:
            if header is not None:
                server.publish_frame(header, content)
            header = None
        else:
            server.publish(topic, server.seq + 1, log_ns, content)
        n += 1
    return n, skipped


def _speed(text: str) -> float | None:
    if text == "max":
        return None
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is neither a factor like 2 nor 'max'") from None
    if not 0 < value <= 1e6:
        raise argparse.ArgumentTypeError(f"{text!r} must be more than 0")
    return value


def _linger(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not 0 <= value <= 3600:
        raise argparse.ArgumentTypeError(f"{text!r} must be between 0 and 3600 seconds")
    return value


def cmd_replay(_: None, a: argparse.Namespace) -> int:
    path = Path(a.file)
    if not path.is_file():
        raise bad_input(f"{path}: no such file")
    cmd = getattr(a, "endpoint", None) or default_endpoint()
    if cmd == default_endpoint():
        Path(cmd.removeprefix("ipc://")).parent.mkdir(mode=0o700, exist_ok=True)
    server = ReplayServer(cmd, str(path))
    try:
        print(f"replaying {path} on {server.endpoint(server.router)}: watch it with `ritactl --endpoint "
              f"{server.endpoint(server.router)} watch`", file=sys.stderr, flush=True)
        if not a.no_wait:
            print("waiting for a subscriber (Ctrl-C ends)", file=sys.stderr, flush=True)
            while server.subscribers == 0:
                server.serve(0.2)
        with open(path, "rb") as f:
            n, skipped = play(server, f, a.speed)
        server.serve(a.linger)
        other = f" ({skipped} skipped: not in ritactl record's layout)" if skipped else ""
        print(f"replayed {n} messages from {path}{other}", file=sys.stderr, flush=True)
        return Exit.OK
    except KeyboardInterrupt:
        return Exit.INTERRUPTED
    finally:
        server.close()


def add_parser(sub: Any) -> None:
    p = sub.add_parser("replay",
                       help="republish an MCAP recording on a local bus endpoint (for watch, console)",
                       description="Republish a `ritactl record` file as if ritad were live: "
                                   "point `ritactl --endpoint ENDPOINT watch` or the console at it. "
                                   "127.0.0.1 or ipc only.")
    p.add_argument("file", metavar="FILE.mcap", help="the recording")
    p.add_argument("--speed", type=_speed, default=1.0, metavar="X|max",
                   help="X times the recorded pace, or max: as fast as possible (default 1)")
    p.add_argument("--endpoint", default=argparse.SUPPRESS, metavar="ENDPOINT",
                   help=f"command endpoint to serve, ipc:///PATH or tcp://127.0.0.1:PORT; "
                        f"telemetry and frames are bound beside it (default {default_endpoint()})")
    p.add_argument("--no-wait", action="store_true", help="start at once instead of waiting for a subscriber")
    p.add_argument("--linger", type=_linger, default=1.0, metavar="S",
                   help="keep answering for S seconds after the last message (default 1)")
    p.add_argument("--json", action="store_true", default=argparse.SUPPRESS, help=argparse.SUPPRESS)
    p.set_defaults(fn=cmd_replay, offline=True)
