"""Command server and client: bad requests get error replies and the server keeps serving."""
import threading
import time
from concurrent.futures import Future

import msgpack
import pytest
import zmq

from daemon.bus.client import Client, ClientTimeout
from daemon.bus.protocol import CommandError, ErrorCode, make_request, unpack
from daemon.ritad.publisher import FramePublisher, TelemetryPublisher
from daemon.ritad.server import CommandServer, Reply
from drivers.base import Frame
from tools.harness.load import hang_s

import numpy as np


@pytest.fixture
def server(tmp_path):
    ctx = zmq.Context()
    pending: list[Future] = []

    def slow(req):
        fut = Future()
        pending.append(fut)
        return fut

    def boom(req):
        raise RuntimeError("handler bug")

    handlers = {
        "ping": lambda req: {"pong": True},
        "echo": lambda req: req.args,
        "blob": lambda req: Reply({"n": 3}, [b"abc"]),
        "slow": slow,
        "boom": boom,
        "refuse": lambda req: (_ for _ in ()).throw(CommandError(ErrorCode.BAD_ARGS, "nope")),
    }
    # stub commands outside the command table need admin (fail closed): this tests the reply machinery
    srv = CommandServer(ctx, [f"ipc://{tmp_path}/cmd"], handlers, max_message_bytes=1000, plain_role="admin")
    srv.start()
    yield srv, ctx, pending
    srv.stop()
    ctx.term()


def raw_call(ctx, endpoint, payload, timeout=2.0):
    s = ctx.socket(zmq.DEALER)
    s.setsockopt(zmq.LINGER, 0)
    s.connect(endpoint)
    s.send(payload)
    assert s.poll(int(timeout * 1000)), "no reply"
    msg = unpack(s.recv())
    s.close()
    return msg


@pytest.mark.parametrize("payload, code", [
    (b"\xc1\xff not msgpack", ErrorCode.BAD_REQUEST),
    (msgpack.packb([1, 2, 3]), ErrorCode.BAD_REQUEST),
    (msgpack.packb({"v": 1, "id": 1}), ErrorCode.BAD_REQUEST),
    (msgpack.packb({"v": 1, "id": 1.5, "cmd": "ping"}), ErrorCode.BAD_REQUEST),
    (msgpack.packb({"v": 1, "id": 1, "cmd": "ping", "args": [1]}), ErrorCode.BAD_ARGS),
    (msgpack.packb({"v": 99, "id": 1, "cmd": "ping"}), ErrorCode.UNSUPPORTED_VERSION),
    (make_request(1, "no.such.command"), ErrorCode.UNKNOWN_COMMAND),
    (make_request(1, "echo", {"x": "y" * 2000}), ErrorCode.TOO_LARGE),
    (make_request(1, "boom"), ErrorCode.INTERNAL),
    (make_request(1, "refuse"), ErrorCode.BAD_ARGS),
])
def test_bad_requests_get_error_replies(server, payload, code):
    srv, ctx, _ = server
    msg = raw_call(ctx, srv.endpoints[0], payload)
    assert msg["ok"] is False and msg["error"]["code"] == code and msg["error"]["message"]
    assert msg["v"] == 1
    # and the server keeps serving
    with Client(srv.endpoints[0], timeout=2, ctx=ctx) as c:
        assert c.call("ping") == {"pong": True}


def test_reply_ids_and_attachments(server):
    srv, ctx, _ = server
    with Client(srv.endpoints[0], timeout=2, ctx=ctx) as c:
        assert c.call("echo", a=1, b="two") == {"a": 1, "b": "two"}
        result, extra = c.call_raw("blob")
        assert result == {"n": 3} and bytes(extra[0].buffer) == b"abc"
        with pytest.raises(CommandError) as err:
            c.call("refuse")
        assert err.value.code == ErrorCode.BAD_ARGS


def test_future_replies_and_late_reply_discarded(server):
    srv, ctx, pending = server
    with Client(srv.endpoints[0], timeout=0.3, ctx=ctx) as c:
        with pytest.raises(ClientTimeout):
            c.call("slow")
        pending[0].set_result("late")  # answer arrives after the client gave up
        assert c.call("ping") == {"pong": True}
    with Client(srv.endpoints[0], timeout=2, ctx=ctx) as c:
        c._socket().send(make_request("x", "slow"))
        time.sleep(0.1)
        pending[1].set_result({"done": 1})
        assert c.sock.poll(2000)
        assert unpack(c.sock.recv())["result"] == {"done": 1}


def test_unreachable_daemon_times_out(tmp_path):
    t0 = time.monotonic()
    with Client(f"ipc://{tmp_path}/nobody", timeout=0.3) as c:
        with pytest.raises(ClientTimeout, match=r"no answer from ritad .* within 0.3 s"):
            c.call("ping")  # the client's own 0.3 s ended it (a hang: pytest-timeout)
    assert time.monotonic() - t0 >= 0.3


def test_a_send_that_cannot_go_out_still_ends_at_the_timeout():
    """A DEALER with no pipe (here: IMMEDIATE to a port nothing listens on; on a robot, a key the
    daemon just refused before the reconnect) blocks in send; the client's timeout must bound it."""
    with zmq.Context() as ctx, Client("tcp://127.0.0.1:9", ctx=ctx, timeout=0.3) as c:
        sock = ctx.socket(zmq.DEALER)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.IMMEDIATE, 1)  # before connect: no pipe until a connection completes
        sock.connect("tcp://127.0.0.1:9")
        c.sock = sock
        with pytest.raises(ClientTimeout, match=r"nothing from ritad .* within 0.3 s"):
            c.call("ping")  # the send's bound is the call's 0.3 s (a send blocked for good: pytest-timeout)


def test_telemetry_snapshot_and_frames(tmp_path):
    ctx = zmq.Context()
    tel = TelemetryPublisher(ctx, [f"ipc://{tmp_path}/tel"])
    frm = FramePublisher(ctx, [f"ipc://{tmp_path}/frm"])
    tel.start(); frm.start()
    try:
        sub = ctx.socket(zmq.SUB); sub.setsockopt(zmq.SUBSCRIBE, b""); sub.connect(tel.endpoints[0])
        fsub = ctx.socket(zmq.SUB); fsub.setsockopt(zmq.SUBSCRIBE, b""); fsub.connect(frm.endpoints[0])
        time.sleep(0.2)  # slow joiner: only in this unit test, the client uses the Clone snapshot
        tel.publish("robot.state", {"x": 1})
        assert sub.poll(2000)
        topic, body = sub.recv_multipart()
        m = unpack(body)
        assert topic == b"robot.state" and m["data"] == {"x": 1} and m["v"] == 1 and m["seq"] == 1
        snap = tel.snapshot()
        assert snap["seq"] == 1 and snap["latest"]["robot.state"]["data"] == {"x": 1}
        px = np.arange(300 * 200, dtype=np.uint8).reshape(200, 300)
        frm.publish(Frame(px, 7, "S1", "Mono8"))
        assert fsub.poll(2000)
        topic, header, pixels = fsub.recv_multipart()
        h = unpack(header)
        assert h["frame_id"] == 7 and h["shape"] == [200, 300] and h["seq"] == 1
        assert np.array_equal(np.frombuffer(pixels, np.uint8).reshape(200, 300), px)
        sub.close(); fsub.close()
    finally:
        tel.stop(); frm.stop(); ctx.term()


def test_frame_queue_drops_instead_of_blocking(tmp_path):
    ctx = zmq.Context()
    frm = FramePublisher(ctx, [f"ipc://{tmp_path}/frm"], queue_size=2)  # not started: nothing drains
    px = np.zeros((10, 10), np.uint8)
    publisher = threading.Thread(target=lambda: [frm.publish(Frame(px, i, "S", "Mono8")) for i in range(50)],
                                 daemon=True)
    publisher.start()
    publisher.join(hang_s(10))  # a publish that blocked would wait for good: nothing drains
    assert not publisher.is_alive(), "publish blocked on a full queue"
    assert frm.counters()["dropped"] == 48
    for s in frm.socks:
        s.close()
    ctx.term()
