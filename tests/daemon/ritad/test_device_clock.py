"""The tracker clock's mapping in ``tracker.status`` (daemon/ritad/device_clock.py)."""
from __future__ import annotations

import time

from daemon.ritad.device_clock import DeviceClock
from fakes.operator import lock_on_robot
from tests.ritad_up import ritad_in_process

HOST0 = 1_760_000_000_000_000_000


def _packet(i: int, late_us: int) -> dict:
    dev_us = 5_000_000 + i * 10_000  # a packet every 10 ms of device time
    return {"n": 1, "device_time": [[dev_us // 10**6], [dev_us % 10**6]],
            "host_time_ns": HOST0 + i * 10_000_000 + late_us * 1000}


def test_packets_feed_the_map_and_bad_ones_add_nothing():
    clock = DeviceClock()
    assert clock.status()["samples"] == 0
    for i in range(200):
        clock.observe_tracker_packet(_packet(i, late_us=(i * 37) % 500))
    for bad in (None, {"n": 1}, {"device_time": None, "host_time_ns": 1}, {"device_time": [[], []]},
                {"device_time": [["x"], [1]], "host_time_ns": 1}):
        clock.observe_tracker_packet(bad)
    st = clock.status()
    assert st["samples"] == 200, st
    # the least-delayed packets (0 µs late) carry the offset: host - device
    assert abs(st["offset_ns"] - (HOST0 - 5_000_000_000)) <= 3 * st["sigma_ns"], st


def test_tracker_status_shows_the_mapping_of_its_stream(tmp_path):
    with ritad_in_process(tmp_path / "rt", tmp_path / "data", timeout=30) as (_, c):
        assert c.call("tracker.status")["clock"]["samples"] == 0
        lock_on_robot(c)
        c.call("tracker.stream.start", rate_hz=200.0)
        try:
            end = time.monotonic() + 10.0
            while (clock := c.call("tracker.status")["clock"])["samples"] < 20 and time.monotonic() < end:
                time.sleep(0.1)
        finally:
            c.call("tracker.stream.stop")
        assert clock["samples"] >= 20, clock
        assert clock["sigma_ns"] > 0 and isinstance(clock["offset_ns"], int), clock
