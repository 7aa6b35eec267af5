"""A motion is done only when the base executed all of it (daemon/worker/motion.py), without a daemon."""
from __future__ import annotations

import pytest

from daemon.bus.procedures import MEASURE_MARK
from daemon.worker.job import Stopped
from daemon.worker.motion import MotionIncomplete, check_motion, odometry_delta
from daemon.worker.nav import Navigator

START = {"x_mm": 100.0, "y_mm": 50.0, "heading_deg": 90.0}


def at(along: float, across: float = 0.0, turned: float = 0.0) -> dict:
    """A pose ``along``/``across`` the start heading (90°: +y) from START."""
    return {"x_mm": 100.0 - across, "y_mm": 50.0 + along, "heading_deg": 90.0 + turned}


def test_odometry_delta_is_along_across_and_turned():
    assert odometry_delta(START, at(93.2, 1.5, -2.0)) == pytest.approx((93.2, 1.5, -2.0))


@pytest.mark.parametrize("done,end", [
    ({"result": "OK"}, None),                                   # the base says so
    ({"result": "UNKNOWN", **at(400.0)}, None),                  # a lost event, the odometry shows all of it
    (None, {"state": "IDLE", **at(400.0)}),                      # no event seen, the status after shows it
])
def test_a_whole_move_is_done(done, end):
    check_motion("move", 400.0, START, done, end)


@pytest.mark.parametrize("done,end,went", [
    ({"result": "STOPPED", **at(93.2)}, None, "after 93.2 mm (DONE STOPPED)"),
    ({"result": "STOPPED", **at(400.0)}, None, "after 400.0 mm (DONE STOPPED)"),  # STOPPED is never done
    ({"result": "UNKNOWN", **at(30.0)}, None, "after 30.0 mm (DONE UNKNOWN)"),
    ({"result": "UNKNOWN", **at(400.0, across=2.0)}, None, "(DONE UNKNOWN)"),      # off the line
    (None, {"state": "IDLE", **at(12.5)}, "after 12.5 mm (DONE no DONE event)"),
    (None, None, "after an unknown part (DONE no DONE event)"),
])
def test_a_move_cut_short_is_not_done(done, end, went):
    with pytest.raises(MotionIncomplete, match="the 400.0 mm move") as exc:
        check_motion("move", 400.0, START, done, end)
    assert went in str(exc.value) and "not recorded" in str(exc.value)
    assert exc.value.resumable


def test_a_turn_is_judged_by_its_heading():
    check_motion("turn", 90.0, START, {"result": "UNKNOWN", **at(0.0, turned=90.0)})
    with pytest.raises(MotionIncomplete, match=r"after 40.0 °"):
        check_motion("turn", 90.0, START, {"result": "STOPPED", **at(0.0, turned=40.0)})


class Bus:
    """robot.status and a robot.move whose DONE is ``result``; what the Navigator sends is recorded."""

    def __init__(self, result: str, along: float, latched: bool = False) -> None:
        self.result, self.along, self.latched, self.sent = result, along, latched, []
        self.state = {"nav": {"heading_deg": 0.0}}
        self.params = MEASURE_MARK.resolve({"mark_xy": [0.0, 0.0]})
        self.resumed = False

    def call(self, cmd: str, timeout: float = 0, **args):
        self.sent.append(cmd)
        if cmd == "robot.status":
            return {"state": "IDLE", **START}
        return {"event": "DONE", "result": self.result, **at(self.along)}

    def check_cancel(self) -> None:
        if self.latched:
            raise Stopped("job stopped: the robot's stop is latched")


def test_the_navigator_does_not_return_from_a_move_cut_short():
    nav = Navigator(Bus("STOPPED", 93.2))  # type: ignore[arg-type]
    with pytest.raises(MotionIncomplete, match="after 93.2 mm"):
        nav.move(400.0)
    nav = Navigator(Bus("STOPPED", 93.2, latched=True))  # type: ignore[arg-type]
    with pytest.raises(Stopped):  # the STOP was latched: the job is stopped, not failed
        nav.move(400.0)
    nav = Navigator(Bus("OK", 400.0))  # type: ignore[arg-type]
    nav.move(400.0)
    assert nav.ctx.sent == ["robot.status", "robot.move"]
