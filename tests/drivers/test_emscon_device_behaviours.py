"""The AT901's documented behaviours the fake can switch on, one per test, against the adapter.

Each behaviour comes from Leica's ES_C_API_Def.h or a public client (fakes/tracker_frames.py cites
them): a frame another client left applied, the stream's packet rate (3-10/s), OutOfRangeOK
answers, the tracker's max_data_rate, and a beam break in the middle of a stream.
"""
from __future__ import annotations

import logging
import time

import numpy as np
import pytest

from drivers.emscon.enums import ES_Command as Cmd
from fakes.world import World
from tests.drivers.test_emscon_integration import (  # noqa: F401 (make and world are fixtures)
    SIGMA, Sink, assert_within_5_sigma, lock_on, make, world)

pytestmark = pytest.mark.timeout(60)


def _pump_until(t, cond, wait_s: float = 10.0) -> bool:
    end = time.monotonic() + wait_s
    while not cond() and time.monotonic() < end:
        t.pump(0.05)
    return cond()


def test_a_frame_another_client_left_is_cleared_on_connect(make, world: World) -> None:
    t = make("foreign_frame=1")
    t.open()
    st = t.server.server.model.state
    assert st.settings["apply_transformation_params"] == 0
    assert st.settings["apply_station_orientation_params"] == 0
    assert st.orientation == (0.0,) * 6 and st.transformation == (0.0,) * 6 + (1.0,)
    truth = lock_on(t, world, "green")
    assert_within_5_sigma(t.measure(), truth)  # the tracker's own frame, not the one left behind


def test_the_fake_applies_a_frame_left_applied(world: World) -> None:
    """The fake's side of the behaviour: with the frame applied, points move (so the test above can fail)."""
    from fakes.tracker import FakeTrackerServer
    srv = FakeTrackerServer(world, foreign_frame=True)
    p = np.array([[3000.0, 1000.0, -500.0]])
    assert np.linalg.norm(srv.in_client_frame(p) - p) > 100.0
    srv.model.state.settings.update(apply_transformation_params=0, apply_station_orientation_params=0)
    assert np.allclose(srv.in_client_frame(p), p)


@pytest.mark.parametrize("opts,want", [("packet_rate_hz=3", 10), ("packet_rate_hz=8&packet_rate=3", 3)])
def test_the_stream_packet_rate_is_set_on_connect(make, opts: str, want: int) -> None:
    t = make(opts)
    t.open()
    assert Cmd.SetLongSystemParameter in t.server.server.commands_seen
    assert t.server.server.packet_rate_hz == want and t.info()["packet_rate"] == want


@pytest.mark.parametrize("bad", ["2", "11"])
def test_a_packet_rate_outside_3_to_10_is_refused_by_name(make, bad: str) -> None:
    with pytest.raises(ValueError, match=f"packet_rate={bad} outside 3-10"):
        make(f"packet_rate={bad}")


def test_a_server_without_the_packet_rate_parameter_keeps_its_own(make, caplog) -> None:
    t = make("fail=SetLongSystemParameter=NotImplemented")
    with caplog.at_level(logging.WARNING):
        t.open()
    assert t.info()["packet_rate"] is None and "packet rate not set" in caplog.text


def test_out_of_range_ok_statuses_are_accepted_with_a_warning(make, world: World, caplog) -> None:
    t = make("ok=SetStationaryModeParams=Parameter1OutOfRangeOK,SetCoordinateSystemType=13")
    with caplog.at_level(logging.WARNING):
        t.open()
    assert "SetStationaryModeParams with Parameter1OutOfRangeOK" in caplog.text
    assert "SetCoordinateSystemType with Parameter2OutOfRangeOK" in caplog.text
    truth = lock_on(t, world, "red")
    assert_within_5_sigma(t.measure(), truth)


def test_a_rate_above_max_data_rate_is_clamped_with_a_warning(make, world: World, caplog) -> None:
    t = make("max_data_rate=250")
    t.open()
    lock_on(t, world, "green")
    with caplog.at_level(logging.WARNING):
        streamed = t.start_stream(1000.0)
    assert streamed == 250.0  # what tracker.stream.start replies
    assert "1000 Hz" in caplog.text and "max_data_rate 250 Hz" in caplog.text
    assert t.status()["streaming"] and t.status()["rate_hz"] == 250.0
    assert t.server.server.model.state.time_separation_ms == 4
    t.stop_stream()


def test_a_beam_break_mid_stream_restarts_the_stream_once_locked(make, world: World) -> None:
    sink = Sink()
    t = make("", sink)
    t.open()
    truth = lock_on(t, world, "green")
    t.start_stream(100.0)
    assert _pump_until(t, lambda: len(sink.topic("tracker.point")) >= 2)
    t.server.break_beam()
    assert _pump_until(t, lambda: t.status()["stream_interrupted"])
    t.server.restore_beam("green")
    assert _pump_until(t, lambda: t.status()["counters"]["stream_restarts"] == 1)
    n = len(sink.topic("tracker.point"))
    assert _pump_until(t, lambda: len(sink.topic("tracker.point")) >= n + 2), "no records after the restart"
    events = [e["event"] for e in sink.topic("tracker.event")]
    assert events.index("stream_interrupted") < events.index("stream_resumed")
    st = t.status()
    assert st["streaming"] and not st["stream_interrupted"] and st["rate_hz"] == 100.0
    last = sink.topic("tracker.point")[-1]
    xyz = np.column_stack([last["x"], last["y"], last["z"]])
    assert np.all(np.abs(xyz - truth) < 6 * SIGMA)
    t.stop_stream()
    assert_within_5_sigma(t.measure(), truth)


def test_stop_after_a_beam_break_without_relock_leaves_stationary_mode(make, world: World) -> None:
    t = make("")
    t.open()
    lock_on(t, world, "green")
    t.start_stream(100.0)
    t.server.break_beam()
    assert _pump_until(t, lambda: t.status()["stream_interrupted"])
    t.stop_stream()
    assert not t.status()["streaming"] and t.server.server.model.state.meas_mode == 0


def test_a_refused_restart_waits_for_the_next_lock_instead_of_retrying_every_pump(make, world: World) -> None:
    sink = Sink()
    t = make("", sink)
    t.open()
    lock_on(t, world, "green")
    t.start_stream(100.0)
    t.server.break_beam()
    assert _pump_until(t, lambda: t.status()["stream_interrupted"])
    t.server.faults.fail[Cmd.StartMeasurement] = 10014  # SystemNotReadyForMeasurement
    t.server.restore_beam("green")
    assert _pump_until(t, lambda: any(e["event"] == "stream_resume_failed"
                                      for e in sink.topic("tracker.event")))
    for _ in range(5):
        t.pump(0.02)
    failed = [e for e in sink.topic("tracker.event") if e["event"] == "stream_resume_failed"]
    assert len(failed) == 1, "a refused restart is retried only on the next lock"
    del t.server.faults.fail[Cmd.StartMeasurement]
    t.server.break_beam()
    t.server.restore_beam("green")
    assert _pump_until(t, lambda: t.status()["counters"]["stream_restarts"] == 1)
