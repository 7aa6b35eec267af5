"""STOP during the conformance kit: the kit's :class:`Link` writes the halt its motion gate owes at its next
read slice, ahead of anything else, and ends the run; the command line's Ctrl-C / SIGTERM is such a STOP.

The bases are fakes/robot_base.py on a pty at real-time speed, recording each line they handle: the tests
assert what the base heard after the STOP and whether it still moves, never how fast.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Callable

import pytest

from drivers import robot_conformance as rc
from drivers.motion_gate import MotionGate
from drivers.robot_conformance_link import STOPPED, Check, KitStopped, Link
from drivers.robot_port import open_port
from fakes.robot import PtyServer
from fakes.robot_defects import DefectiveBase
from fakes.world import World, WorldParams
from tools.harness.stop_rig import wait_for

pytestmark = pytest.mark.timeout(120)

ROOT = Path(__file__).resolve().parents[2]
#: the reply timeout: it only catches a hang on a loaded machine
HANG_S = 2.0


def record_lines(fake: Any) -> list[tuple[float, str]]:
    """From now on, (host time, kind) of every line the fake base ``fake`` handles."""
    heard: list[tuple[float, str]] = []
    handle = fake.handle_line

    def recording(line: bytes) -> None:
        heard.append((time.monotonic(), line.split(b",", 1)[0].lstrip(b"$").decode(errors="replace")))
        handle(line)

    fake.handle_line = recording
    return heard


def is_moving(fake: Any) -> bool:
    with fake._lock:
        fake.tick()
        return bool(fake.moving)


class Base:
    """A fake base (with ``defects``) on a pty, recording (host time, kind) of every line it handles."""

    def __init__(self, *defects: str) -> None:
        self.base = DefectiveBase(World(WorldParams(seed=1, start_pose=(0.0, 0.0, 0.0))), time_scale=1.0,
                                  defects=defects, clock_offset_s=5000.0)
        self.heard = record_lines(self.base)
        self.server = PtyServer(self.base)

    def moving(self) -> bool:
        return is_moving(self.base)

    def x(self) -> float:
        with self.base._lock:
            self.base.tick()
            return self.base.odometry[0]

    def since(self, t: float) -> list[str]:
        return [kind for at, kind in list(self.heard) if at >= t]

    def port(self) -> Any:
        return open_port(self.server.path, "serial", baudrate=115200, timeout=0.005, write_timeout=0.5,
                         dtr=False, rts=False)


@pytest.fixture
def serve() -> Iterator[Callable[..., Base]]:
    made: list[Base] = []

    def make(*defects: str) -> Base:
        made.append(Base(*defects))
        return made[-1]

    yield make
    for b in made:
        b.server.shutdown()


def still(base: Base, seconds: float = 0.3) -> bool:
    """The base stands and its odometry does not advance over ``seconds``."""
    x = base.x()
    time.sleep(seconds)
    return not base.moving() and base.x() == x


def test_a_stop_during_the_kits_move_halts_the_base_and_ends_the_run(serve: Callable[..., Base]) -> None:
    base, gate = serve(), MotionGate()
    port = base.port()
    link = Link(port, HANG_S, gate=gate)
    out: list[list[Check]] = []
    kit = threading.Thread(target=lambda: out.append(rc.run_checks(
        link, baudrate=115200, allow_motion=True, polls=10, clock_s=0.3, stream_s=0.3)), daemon=True)
    try:
        kit.start()
        wait_for(base.moving, 60, "the kit's first MOVE under way")
        t_stop = time.monotonic()
        halted = gate.engage()
        assert halted.result(timeout=5) is True  # the base acknowledged the kit's STOP
        kit.join(timeout=30)
        assert not kit.is_alive()
    finally:
        port.close()
    heard = base.since(t_stop)
    assert "STOP" in heard and not {"MOVE", "TURN"} & set(heard), heard
    assert still(base)
    results = {r.name: r for r in out[0]}
    assert "acknowledged by the base" in link.stopped and "an operator's STOP" in link.stopped
    assert {results[n].value for n in rc.MOTION_CHECKS} == {STOPPED}, results  # the MOVE ran in `done`
    assert {results[n].verdict for n in rc.MOTION_CHECKS} == {"fail"} and results["latency"].verdict == "pass"
    assert rc.exit_code(out[0], bool(link.stopped)) == rc.EXIT_STOPPED


def test_while_latched_the_kit_writes_no_motion_line(serve: Callable[..., Base]) -> None:
    base, gate = serve(), MotionGate()
    gate.engage()
    gate.halted(1)  # latched, the halt acknowledged already: nothing owed, motions refused
    port = base.port()
    try:
        link = Link(port, HANG_S, gate=gate)
        assert link.ask("HELLO", 3, 300)[1] is not None  # what is no motion still goes out
        with pytest.raises(KitStopped, match="MOVE refused: the stop is latched"):
            link.ask("MOVE", 100, 50)
    finally:
        port.close()
    assert "MOVE" not in base.since(0.0) and not base.moving()


def test_a_stop_the_base_never_acknowledges_stays_owed_and_says_so(serve: Callable[..., Base]) -> None:
    """The kit waits a bounded time for the ACK, ends the run saying so, and leaves the halt owed to the gate
    (ritad's driver writes it first at its next connect)."""
    base, gate = serve("stop_no_ack"), MotionGate()
    port = base.port()
    try:
        link = Link(port, 0.2, gate=gate)
        link.ask("HELLO", 2)
        assert link.ask("MOVE", 1000, 50)[1] is not None
        wait_for(base.moving, 10, "the MOVE under way")
        halted = gate.engage()
        with pytest.raises(KitStopped, match="NOT acknowledged in 0.6 s"):
            link.quiet(5.0)
    finally:
        port.close()
    assert gate.pending and not halted.done()
    assert still(base)  # this defect's STOP halts, it only never answers


def test_sigterm_to_the_command_line_writes_stop_and_exits_4(serve: Callable[..., Base]) -> None:
    base = serve()
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "drivers.robot_conformance", f"serial://{base.server.path}?timeout={HANG_S:g}",
         "--allow-motion", "--polls", "5", "--json"], cwd=ROOT, env=env, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True)
    try:
        wait_for(base.moving, 90, "the kit's first MOVE under way")
        t_stop = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        stdout, stderr = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=10)
    assert proc.returncode == rc.EXIT_STOPPED, stderr
    heard = base.since(t_stop)
    assert "STOP" in heard and not {"MOVE", "TURN"} & set(heard), heard
    assert still(base)
    out = json.loads(stdout)
    assert out["exit"] == rc.EXIT_STOPPED and "acknowledged by the base" in out["stopped"], out
    assert {c["name"]: c["value"] for c in out["checks"]}["stop_braking"] == STOPPED
    assert "stopped: Ctrl-C or SIGTERM: STOP" in stderr and "Traceback" not in stderr
