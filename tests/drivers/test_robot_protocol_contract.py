"""docs/robot-protocol.md is the contract: its figures are the codec's, and the simulated base does what it
says about sessions, a MOVE resent while moving, HELLO during motion, restarts and fault reasons."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from drivers import robot_protocol as rp
from fakes.robot_base import FakeBase
from fakes.world import World, WorldParams

DOC = (Path(__file__).resolve().parents[2] / "docs" / "robot-protocol.md").read_text()


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def _base() -> tuple[FakeBase, Clock]:
    clock = Clock()
    return FakeBase(World(WorldParams(start_pose=(0.0, 0.0, 0.0))), time_scale=1.0, clock=clock), clock


def ask(base: FakeBase, kind: str, *fields: object) -> list[rp.Message]:
    base.handle_line(rp.encode(kind, *fields).rstrip())
    return [rp.decode(line) for line in base.drain()]


def test_the_documented_figures_are_the_codecs() -> None:
    for text, value in (
        ("boot window of 3 s", rp.BOOT_S == 3.0),
        ("Reply budget: 20 ms", rp.REPLY_BUDGET_S == 0.02),
        ("**500 mm/s²**", rp.STOP_DECEL_MM_S2 == 500),
        ("**180 °/s²**", rp.STOP_DECEL_DEG_S2 == 180),
        ("at least 480 bytes", rp.RX_BUFFER_BYTES == 480),
        ("latency timer\n  16 ms", True),
        ("| \\|distance_mm\\| ≤ 5000 |", rp.MAX_DISTANCE_MM == 5000),
        ("| 1 ≤ speed_mm_s ≤ 300 |", rp.MAX_SPEED_MM_S == 300),
        ("| 1 ≤ speed_deg_s ≤ 90 |", rp.MAX_TURN_SPEED_DEG_S == 90),
        ("| 50 ≤ host_timeout_ms ≤ 5000; 300 when absent |", rp.MAX_HOST_TIMEOUT_MS == 5000),
        ("≤ 160 bytes", rp.MAX_LINE == 160),
        ("1 … 9999", rp.SEQ_MAX == 9999),
    ):
        assert text in DOC and value, text
    table = DOC.split("## Fault reasons", 1)[1].split("## Numeric limits", 1)[0]
    assert re.findall(r"^\| `([A-Z_]+)` \|", table, re.M) == list(rp.FAULT_REASONS)


def test_commands_before_any_hello_are_answered_as_version_1() -> None:
    base, _ = _base()
    assert ask(base, "STOP", 1) == [rp.Message("ACK", ("1", "STOP"))]
    (status,) = ask(base, "STATUS", 2)
    assert len(status.fields) == rp.STATUS_V1_FIELDS  # no t_us
    assert ask(base, "STATE", 3, 10)[0].fields[1] == "UNKNOWN"


@pytest.mark.parametrize("version", rp.PROTOCOL_VERSIONS)
def test_hello_never_stops_a_motion(version: int) -> None:
    base, clock = _base()
    ask(base, "HELLO", 1, version)
    assert ask(base, "MOVE", 2, 1000, 100)[0].kind == "ACK"
    clock.t += 0.1
    assert ask(base, "HELLO", 3, version)[0].kind == "VERSION"
    clock.t += 0.1
    assert ask(base, "STATUS", 4)[0].fields[1] == "MOVING"


def test_a_move_resent_while_moving_is_acked_again_and_another_is_busy() -> None:
    base, clock = _base()
    ask(base, "HELLO", 1, 3)
    first = ask(base, "MOVE", 2, 100, 50)
    clock.t += 0.05
    assert ask(base, "MOVE", 2, 100, 50) == first  # the same line: the same ACK, no second motion
    assert ask(base, "MOVE", 2, 120, 50)[0].fields[1] == "BUSY"  # same seq, other arguments: a new MOVE
    assert ask(base, "MOVE", 3, 100, 50)[0].fields[1] == "BUSY"
    events = []
    for seq in range(4, 30):  # 2.6 s kept alive (a version-3 session's host watchdog)
        clock.t += 0.1
        events += [m for m in ask(base, "STATUS", seq) if m.kind in rp.EVENTS]
    assert [e.fields[:3] for e in events] == [("2", "OK", "100")]  # one motion of 100 mm, not two


def test_a_restart_forgets_the_session_the_odometry_and_the_clock() -> None:
    base, clock = _base()
    ask(base, "HELLO", 1, 3)
    ask(base, "MOVE", 2, 100, 100)
    clock.t += 0.5
    before = ask(base, "STATUS", 3)[0]
    base.reset()  # no event for the motion it cut
    clock.t += 1.0
    base.tick()
    assert base.drain() == [base.boot.banner]
    after = ask(base, "STATUS", 4)[0]
    assert len(after.fields) == rp.STATUS_V1_FIELDS and after.fields[1:5] == ("IDLE", "0", "0", "0")
    ask(base, "HELLO", 5, 2)
    t_us = rp.device_us(ask(base, "STATUS", 6)[0], rp.STATUS_V1_FIELDS)
    assert t_us == pytest.approx(1e6, rel=1e-3) and t_us < rp.device_us(before, rp.STATUS_V1_FIELDS)


def test_the_fault_reasons_the_fake_reports_are_documented() -> None:
    base, clock = _base()
    ask(base, "HELLO", 1, 3)
    ask(base, "MOVE", 2, 1000, 100)
    clock.t += 0.5  # silence beyond the 300 ms host timeout
    base.tick()
    (fault,) = [rp.decode(line) for line in base.drain()]
    assert fault.kind == "FAULT" and fault.fields[1] in rp.FAULT_REASONS
    assert "STALL" in rp.FAULT_REASONS  # the fake's other fault (fault_rate)
    assert ask(base, "MOVE", 3, 10, 10)[0].fields[1] == "FAULT"
    assert ask(base, "STOP", 4)[0].kind == "ACK" and ask(base, "STATUS", 5)[0].fields[1] == "IDLE"
