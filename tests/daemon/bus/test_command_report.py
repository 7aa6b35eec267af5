"""``daemon.command``: the command server reports each answered non-polled command with its reply.

Stub handlers under real command names (the table decides what is polled); the report hook is a
list, or one that raises, which must not cost the caller its reply.
"""
from __future__ import annotations

import threading
import time
from concurrent.futures import Future
from pathlib import Path
from typing import Any, Iterator

import pytest
import zmq

from daemon.bus.client import Client
from daemon.bus.command_table import COMMANDS
from daemon.bus.protocol import CommandError, ErrorCode
from daemon.ritad.server import AUDIT_ARGS_BYTES, CommandServer

pytestmark = pytest.mark.timeout(30)


class Rig:
    def __init__(self, tmp: Path, hook: Any) -> None:
        self.ctx = zmq.Context()
        self.moves: list[Future] = []
        handlers = {"ping": lambda r: {"pong": True}, "robot.move": self._move,
                    "robot.stop": lambda r: {"stopped": True},
                    "tracker.find":
                        lambda r: (_ for _ in ()).throw(CommandError("tracker_NotLocked", "no target")),
                    "keys.allow": lambda r: {}, "calib.plate.upload": lambda r: {"saved": True}}
        self.srv = CommandServer(self.ctx, [f"ipc://{tmp}/cmd"], handlers, max_message_bytes=1 << 20,
                                 plain_role="operator", on_command=hook)
        self.srv.start()
        self.client = Client(self.srv.endpoints[0], timeout=5)

    def _move(self, _: Any) -> Future:
        fut: Future = Future()
        self.moves.append(fut)
        threading.Timer(0.05, fut.set_result, args=({"done": True},)).start()  # a motion's end, later
        return fut

    def close(self) -> None:
        self.client.close()
        self.srv.stop()
        self.ctx.term()


@pytest.fixture
def reported(tmp_path: Path) -> Iterator[tuple[Rig, list[dict[str, Any]]]]:
    got: list[dict[str, Any]] = []
    rig = Rig(tmp_path, got.append)
    yield rig, got
    rig.close()


def _wait(got: list[Any], n: int) -> None:
    end = time.monotonic() + 5
    while len(got) < n and time.monotonic() < end:
        time.sleep(0.01)


def test_each_non_polled_command_is_reported_with_its_reply_and_times(reported) -> None:
    rig, got = reported
    assert COMMANDS["ping"].polled and not COMMANDS["robot.move"].polled
    t0 = time.time_ns()
    assert rig.client.call("ping")["pong"]
    # answered at the motion's end
    assert rig.client.call("robot.move", distance_mm=10.0, confirm=True)["done"]
    with pytest.raises(CommandError):
        rig.client.call("tracker.find")
    with pytest.raises(CommandError) as refused:
        rig.client.call("keys.allow", name="bob", public_key="x" * 40)  # operator: forbidden
    rig.client.call("calib.plate.upload", plate={"dots": "d" * (AUDIT_ARGS_BYTES + 10)})
    _wait(got, 4)
    assert [r["cmd"] for r in got] == ["robot.move", "tracker.find", "keys.allow", "calib.plate.upload"]
    move, find, allow, upload = got
    assert move["args"] == {"distance_mm": 10.0, "confirm": True} and move["ok"] is True
    assert (move["code"], move["message"], move["key"], move["role"]) == (None, None, None, "operator")
    assert t0 <= move["recv_ns"] and move["reply_ns"] - move["recv_ns"] >= 40_000_000  # the motion's 50 ms
    assert (find["ok"], find["code"], find["message"]) == (False, "tracker_NotLocked", "no target")
    assert allow["ok"] is False and allow["code"] == refused.value.code == ErrorCode.FORBIDDEN
    assert upload["ok"] is True and upload["args"] is None  # too large to repeat on telemetry
    assert all(r["recv_ns"] <= r["reply_ns"] for r in got)
    assert len({r["id"] for r in got}) == 4  # the request ids


def test_a_failing_report_never_fails_the_command(tmp_path: Path, caplog) -> None:
    def hook(_: dict[str, Any]) -> None:
        raise RuntimeError("publisher gone")

    rig = Rig(tmp_path, hook)
    try:
        assert rig.client.call("robot.stop") == {"stopped": True}
        assert rig.client.call("robot.move", distance_mm=1.0, confirm=True)["done"]
        assert rig.client.call("robot.stop") == {"stopped": True}  # the server still serves
    finally:
        rig.close()
    assert "daemon.command report of robot.stop failed" in caplog.text
