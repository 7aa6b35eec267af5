"""ritad with the simulated base of protocol 2: its STATE/INCL samples on the bus, on the host's timeline.

The daemon asks the base for its sample stream at open (the robot URL's ``stream_hz``), feeds every
batch to the base clock's map (daemon/ritad/device_clock.py) and publishes ``robot.odometry`` and
``robot.incl`` with each sample's ``t_ns`` and ``t_sigma_ns``; ``robot.status`` shows the map as
``clock`` and the streams the base sends.
"""
from __future__ import annotations

import time

import pytest

from tests.ritad_up import ritad_in_process

pytestmark = pytest.mark.timeout(90)


def _paper_imu(cfg) -> None:
    cfg.plugins["sim"]["profile"] = "paper+imu"  # a base with an inclinometer


def _collect(sub, topics: set[str], want: int, wait_s: float) -> dict[str, list[dict]]:
    got: dict[str, list[dict]] = {t: [] for t in topics}
    end = time.monotonic() + wait_s
    while time.monotonic() < end and min(sum(m["n"] for m in v) for v in got.values()) < want:
        msg = sub.recv(timeout=0.2)
        if msg is not None and msg[0] in got:
            got[msg[0]].append(msg[1]["data"])
    return got


def test_ritad_publishes_the_bases_samples_on_the_host_timeline(tmp_path):
    with ritad_in_process(tmp_path / "rt", tmp_path / "data", configure=_paper_imu) as (_, c):
        sub = c.subscriber(["robot.odometry", "robot.incl"])
        try:
            got = _collect(sub, {"robot.odometry", "robot.incl"}, 40, 20.0)
        finally:
            sub.close()
        st = c.call("robot.status")
    for topic, fields in (("robot.odometry", ("x_mm", "y_mm", "heading_deg", "v_left_mm_s", "v_right_mm_s")),
                          ("robot.incl", ("roll_deg", "pitch_deg"))):
        msgs = got[topic]
        assert sum(m["n"] for m in msgs) >= 40, (topic, len(msgs))
        for m in msgs:
            for key in ("t_us", "host_time_ns", "t_ns", "t_sigma_ns", *fields):
                assert len(m[key]) == m["n"], (topic, key)
            # the sample's host time is before the host read its line, and not long before
            assert all(0 <= rx - t < 1e9 for t, rx in zip(m["t_ns"], m["host_time_ns"])), topic
            assert all(s > 0 for s in m["t_sigma_ns"])
        t_us = [t for m in msgs for t in m["t_us"]]
        assert t_us == sorted(t_us) and len(set(t_us)) == len(t_us), f"{topic}: samples out of order or repeated"
    assert st["streams"] == ["robot.odometry", "robot.incl"] and st["t_us"] > 0, st
    clock = st["clock"]
    assert clock["samples"] > 40 and clock["offset_ns"] is not None and clock["sigma_ns"] > 0, clock


def test_ritad_with_the_stream_off_polls_as_before(tmp_path):
    with ritad_in_process(tmp_path / "rt", tmp_path / "data", robot="sim:?stream_hz=0&protocol=1") as (_, c):
        st = c.call("robot.status")
    assert st["streams"] == [] and st["t_us"] is None and st["clock"]["samples"] == 0, st
