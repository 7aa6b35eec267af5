"""The console's live series (daemon/console/series.py): what the page plots, with each sample's age."""
from __future__ import annotations

import math

from daemon.console.series import Series, rows

MS = 1_000_000  # ns per ms


def odometry(t0_ms: float, n: int, step_ms: float = 20.0) -> dict:
    """A robot.odometry batch as docs/protocol.md gives it: columnar, each sample's own t_ns."""
    t = [int((t0_ms + i * step_ms) * MS) for i in range(n)]
    return {"n": n, "t_ns": t, "host_time_ns": t, "x_mm": [float(i) for i in range(n)],
            "y_mm": [2.0 * i for i in range(n)], "heading_deg": [0.5] * n,
            "v_left_mm_s": [10.0] * n, "v_right_mm_s": [-10.0] * n}


def test_odometry_gives_pose_and_wheel_points_and_the_tracker_its_distance():
    got = list(rows("robot.odometry", odometry(0.0, 2)))
    assert got == [("pose", 0.0, [0.0, 0.0, 0.5]), ("wheels", 0.0, [10.0, -10.0]),
                   ("pose", 20 * MS, [1.0, 2.0, 0.5]), ("wheels", 20 * MS, [10.0, -10.0])]
    point = {"n": 1, "x": [3000.0], "y": [4000.0], "z": [0.0], "t_ns": [5 * MS]}
    assert list(rows("tracker.point", point)) == [("tracker", 5 * MS, [5000.0])]
    assert list(rows("robot.event", {"event": "DONE"})) == []
    assert list(rows("robot.odometry", "not a map")) == []


def test_a_point_is_timed_by_its_sample_on_the_consoles_clock_whatever_the_robots_clock_reads():
    s = Series(min_step_ms=0.0)
    robot_clock_ms = 9e12  # the robot's clock far from the console's: only differences on each clock count
    s.add("robot.odometry", int((robot_clock_ms + 300) * MS), odometry(robot_clock_ms, 1), recv_ms=1000.0)
    (p,) = [p for p in s.since(0) if p["s"] == "pose"]
    assert p["t"] == 700.0  # received at 1000, published 300 ms after the sample was taken


def test_points_are_thinned_to_the_plot_rate_and_a_tab_gets_each_once():
    s = Series(min_step_ms=100.0)
    kept = s.add("robot.odometry", 1000 * MS, odometry(0.0, 50, step_ms=20.0), recv_ms=2000.0)
    assert kept == 2 * 10  # 1 s of 50 Hz samples: 10 per series at one per 100 ms
    first = s.since(0)
    assert [p["no"] for p in first] == list(range(1, 21))
    assert s.since(first[-1]["no"]) == []


def test_polled_pose_only_when_the_base_streams_none_and_missing_values_are_null():
    s = Series(min_step_ms=0.0)
    state = {"state": "IDLE", "x_mm": 1.0, "y_mm": 2.0, "heading_deg": 3.0}   # a version-1 base: no t_ns
    assert s.add("robot.state", 10 * MS, state, recv_ms=50.0) == 1
    assert s.since(0)[-1] == {"no": 1, "s": "pose", "t": 50.0, "v": [1.0, 2.0, 3.0]}
    batch = odometry(0.0, 1)
    batch["v_left_mm_s"] = [None]
    s.add("robot.odometry", 0, batch, recv_ms=100.0)
    assert s.since(1)[-1]["v"] == [None, -10.0]
    assert s.add("robot.state", 20 * MS, state, recv_ms=200.0) == 0  # odometry flows: its pose is newer
    assert all(math.isfinite(p["t"]) for p in s.since(0))
