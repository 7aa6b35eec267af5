"""The base conformance kit passes the simulated base and fails a base with each protocol defect on its check.

The bases are fakes/robot_base.py on a pty at real-time speed (time_scale 1: the watchdog and braking
checks see real motions), one defect each from fakes/robot_defects.py.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any, Callable

import pytest

from drivers import robot_conformance as rc
from drivers.robot_conformance_link import Check, Link
from drivers.robot_port import open_port
from fakes.robot import PtyServer
from fakes.robot_defects import DEFECTS, DefectiveBase
from fakes.world import World, WorldParams

pytestmark = pytest.mark.timeout(120)

#: a base up for 5000 s: its t_us is above 2^32, so its width shows
UP_S = 5000.0
#: the host's reply timeout here: it only catches a hang (a loaded test machine may stall the fake's thread
#: for more than the default 0.5 s); the latency check judges the round trips against the reply budget
HANG_S = 2.0


@pytest.fixture
def serve() -> Iterator[Callable[..., PtyServer]]:
    servers: list[PtyServer] = []

    def make(*defects: str, **kwargs: Any) -> PtyServer:
        if "t_us_32bit" not in defects:
            kwargs.setdefault("clock_offset_s", UP_S)
        base = DefectiveBase(
            World(WorldParams(start_pose=(0.0, 0.0, 0.0))), time_scale=1.0, defects=defects, **kwargs
        )
        servers.append(PtyServer(base))
        return servers[-1]

    yield make
    for s in servers:
        s.shutdown()


def run(server: PtyServer, allow_motion: bool) -> dict[str, Check]:
    port = open_port(
        server.path, "serial", baudrate=115200, timeout=0.005, write_timeout=0.5, dtr=False, rts=False
    )
    try:
        results = rc.run_checks(
            Link(port, HANG_S), baudrate=115200, allow_motion=allow_motion, polls=20, clock_s=0.5,
            stream_s=0.5
        )
    finally:
        port.close()
    assert len({r.name for r in results}) == len(results)
    return {r.name: r for r in results}


def test_the_fake_base_passes_every_check(serve: Callable[..., PtyServer]) -> None:
    results = run(serve(), allow_motion=True)
    assert {n: r.line() for n, r in results.items() if r.verdict != "pass"} == {}
    assert set(results) >= {
        "stop_before_hello",
        "versions",
        "nak_checksum",
        "nak_unknown",
        "nak_range",
        "nak_syntax",
        "noise_ignored",
        "retry_status",
        "seq_echo",
        "latency",
        "t_us",
        "t_us_width",
        "streams",
        "framing",
        *rc.MOTION_CHECKS,
    }
    # the names a STOP mid-kit reports as not run: the run's own checks, so none is left unreported
    assert set(results) - {"t_us_width"} == set(rc.CHECKS)
    assert rc.exit_code(list(results.values())) == rc.EXIT_PASS
    assert "above 2^32" in results["t_us_width"].detail and "FAULT HOST_LOST" in results["watchdog"].value


#: defect -> the check that must fail, and whether it needs motion
MATCHING = {
    "bad_checksum": ("framing", False),
    "no_nak": ("nak_checksum", False),
    "wrong_seq": ("seq_echo", False),
    "t_us_32bit": ("t_us", False),
    "no_watchdog": ("watchdog", True),
    "slow_replies": ("latency", False),
    "stop_no_ack": ("stop_before_hello", False),
    "retry_moves_again": ("retry_move", True),
    "v1_with_clock": ("versions", False),
    "no_version_nak": ("versions", False),
}


def test_every_defect_has_its_check() -> None:
    assert set(MATCHING) == set(DEFECTS)


@pytest.mark.parametrize("defect", sorted(MATCHING))
def test_a_base_with_a_defect_fails_the_matching_check(serve: Callable[..., PtyServer], defect: str) -> None:
    check, motion = MATCHING[defect]
    results = run(serve(defect), allow_motion=motion)
    assert results[check].verdict == "fail", results[check].line()
    assert rc.exit_code(list(results.values())) == rc.EXIT_FAIL


def test_a_healthy_base_with_a_32_bit_span_so_far_skips_the_width_not_passes_it(
    serve: Callable[..., PtyServer],
) -> None:
    results = run(serve(clock_offset_s=100.0), allow_motion=False)
    assert results["t_us"].verdict == "pass"
    assert results["t_us_width"].verdict == "skip" and "71.6 min" in results["t_us_width"].detail
    assert results["watchdog"].verdict == "skip" and "--allow-motion" in results["watchdog"].value
    assert rc.exit_code(list(results.values())) == rc.EXIT_PASS


def test_the_command_line(
    serve: Callable[..., PtyServer], capsys: pytest.CaptureFixture[str], tmp_path: Any
) -> None:
    server = serve()
    code = rc.main([f"serial://{server.path}?timeout={HANG_S:g}", "--polls", "10", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert code == rc.EXIT_PASS, [c for c in out["checks"] if c["verdict"] == "fail"]
    assert out["exit"] == 0 and {c["name"]: c["verdict"] for c in out["checks"]}["stop_braking"] == "skip"
    assert rc.main([f"serial://{server.path}?bogus=1"]) == rc.EXIT_USAGE
    assert "unknown option 'bogus'" in capsys.readouterr().err
    assert rc.main([f"serial://{tmp_path}/no-such-port"]) == rc.EXIT_UNREACHABLE
    assert "no-such-port" in capsys.readouterr().err
