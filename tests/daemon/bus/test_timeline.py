"""The time-indexed lookup: a stream's value at an instant, with the gap it bridged."""
from __future__ import annotations

import random

import pytest

from daemon.bus.timeline import TimeSeries

MS = 1_000_000


def test_interpolates_between_the_samples_around_the_instant_and_reports_the_gap():
    ts = TimeSeries("robot", ("x_mm", "y_mm"))
    ts.add(10 * MS, (0.0, 5.0))
    ts.add(30 * MS, (20.0, 5.0), sigma_ns=40_000)
    a = ts.at(25 * MS)
    assert a.values == {"x_mm": pytest.approx(15.0), "y_mm": pytest.approx(5.0)}
    assert a.gap_ns == 20 * MS and a.sigma_ns == 40_000 and not a.extrapolated
    exact = ts.at(10 * MS)
    assert exact.values["x_mm"] == 0.0 and exact.gap_ns == 0


def test_samples_out_of_order_take_their_place():
    ts = TimeSeries("tracker", ("x",))
    order = list(range(100))
    random.Random(3).shuffle(order)
    for k in order:
        ts.add(k * MS, (float(k),))
    assert ts.at(int(41.5 * MS)).values["x"] == pytest.approx(41.5)
    assert ts.span() == (0, 99 * MS)


def test_outside_the_samples_it_refuses_unless_it_may_reach():
    ts = TimeSeries("tilt", ("roll_deg",))
    with pytest.raises(LookupError, match="'tilt': no samples"):
        ts.at(0)
    ts.add(100 * MS, (0.1,))
    ts.add(200 * MS, (0.2,))
    with pytest.raises(LookupError, match=r"5\.000 ms after the last sample"):
        ts.at(205 * MS)
    held = ts.at(205 * MS, reach_ns=10 * MS)
    assert held.extrapolated and held.gap_ns == 5 * MS and held.values["roll_deg"] == 0.2
    with pytest.raises(LookupError, match="before the first"):
        ts.at(50 * MS, reach_ns=10 * MS)


def test_angles_go_the_short_way_round():
    ts = TimeSeries("pose", ("x_mm", "heading_deg"), angles=("heading_deg",))
    ts.add(0, (0.0, 179.0))
    ts.add(10 * MS, (10.0, -179.0))
    h = ts.at(5 * MS).values["heading_deg"]
    assert abs(abs(h) - 180.0) < 1e-9, h  # not 0°: the robot turned 2°, not 358°
    assert ts.at(int(2.5 * MS)).values["heading_deg"] == pytest.approx(179.5)


def test_keeps_its_span_and_drops_what_is_older():
    ts = TimeSeries("fast", ("v",), span_s=1.0)
    for k in range(5000):  # 5 s at 1 kHz
        ts.add(k * MS, (float(k),))
    first, last = ts.span()
    assert last == 4999 * MS and 1000 * MS <= last - first <= 2000 * MS  # at least the span, at most twice
    with pytest.raises(LookupError, match="before the first"):
        ts.at(0)


def test_bad_declarations_and_rows_are_named():
    with pytest.raises(ValueError, match="distinct"):
        TimeSeries("a", ("x", "x"))
    with pytest.raises(ValueError, match=r"angles \['h'\]"):
        TimeSeries("a", ("x",), angles=("h",))
    with pytest.raises(ValueError, match="span_s=0"):
        TimeSeries("a", ("x",), span_s=0)
    with pytest.raises(ValueError, match=r"2 values for fields \['x'\]"):
        TimeSeries("a", ("x",)).add(0, (1.0, 2.0))
