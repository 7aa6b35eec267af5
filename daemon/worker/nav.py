"""Closed-loop driving with the tracker: turn, drive straight, re-measure.

The base only knows odometry; the tracker knows where the reflector really is. The
heading is known after every straight move (the direction of the measured
displacement) and carried through turns by odometry. ``approach`` ends with a
straight move of ``d`` along the wanted heading, so every stop has the two
positions (P_prev, P_at) the paper's robot pose needs.
"""
from __future__ import annotations

import logging
import math
from typing import Any

import numpy as np

from daemon.worker.compensations import read_tilt
from daemon.worker.job import JobContext
from daemon.worker.motion import confirm_done
from daemon.worker.stream import record_move

MIN_HEADING_MOVE_MM = 20.0

log = logging.getLogger(__name__)


def wrap_deg(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


class Navigator:
    """Drives the robot through the bus; its heading estimate lives in the job state, its speeds and the
    compensations' recording settings are the job's parameters."""

    def __init__(self, ctx: JobContext, turn_speed_deg_s: float = 30.0) -> None:
        self.ctx = ctx
        self.speed = ctx.params.speed_mm_s
        self.turn_speed = turn_speed_deg_s
        self.nav = ctx.state.setdefault("nav", {"heading_deg": None})
        if ctx.resumed:  # a run stopped (or killed) mid-turn leaves the robot off the checkpointed heading
            self.nav["heading_deg"] = None
        self.last_points: tuple[dict[str, Any], dict[str, Any]] | None = None
        #: compensation inputs of the last recorded approach: imu_prev, stream (see :meth:`straight`)
        self.last_record: dict[str, Any] = {}

    # ------------------------------------------------------------------ primitives

    def where(self) -> tuple[np.ndarray, dict[str, Any]]:
        p = self.ctx.call("tracker.measure", timeout=60)
        return np.asarray(p["abs_xyz"], dtype=float), p

    def move(self, distance_mm: float) -> None:
        """Drive straight; returns only once the base executed all of it (else MotionIncomplete, Stopped)."""
        while abs(distance_mm) > 1e-3:
            step = math.copysign(min(abs(distance_mm), 1900.0), distance_mm)
            start = self.ctx.call("robot.status")  # how far a move cut short went: odometry from here
            done = self.ctx.call("robot.move", timeout=600, distance_mm=step, speed_mm_s=self.speed,
                                 confirm=True)
            confirm_done(self.ctx, "move", step, start, done)
            distance_mm -= step

    def turn(self, angle_deg: float) -> None:
        if abs(angle_deg) < 1e-3:
            return
        start = self.ctx.call("robot.status")
        done = self.ctx.call("robot.turn", timeout=600, angle_deg=angle_deg, speed_deg_s=self.turn_speed,
                             confirm=True)
        confirm_done(self.ctx, "turn", angle_deg, start, done)  # cut short: the heading is unknown
        if self.nav["heading_deg"] is not None:
            self.nav["heading_deg"] = wrap_deg(self.nav["heading_deg"] + angle_deg)

    @property
    def heading(self) -> float:
        if self.nav["heading_deg"] is None:
            self.learn_heading()
        return float(self.nav["heading_deg"])

    def learn_heading(self, probe_mm: float = 50.0) -> None:
        """Drive a short probe forward and back to learn the heading from the tracker."""
        a, _ = self.where()
        self.move(probe_mm)
        b, _ = self.where()
        self.nav["heading_deg"] = math.degrees(math.atan2(b[1] - a[1], b[0] - a[0]))
        self.move(-probe_mm)

    def straight(self, distance_mm: float, record: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """Move and update the heading from the measured displacement; returns (before, after).

        ``record``: the compensations' inputs go to ``last_record`` (:meth:`_recorded_move`).
        """
        a, pa = self.where()
        if record:
            self._recorded_move(distance_mm, pa)
        else:
            self.move(distance_mm)
        b, pb = self.where()
        self.last_points = (pa, pb)  # the full tracker points, for the dataset
        if abs(distance_mm) >= MIN_HEADING_MOVE_MM:
            d = (b - a) * math.copysign(1.0, distance_mm)
            self.nav["heading_deg"] = math.degrees(math.atan2(d[1], d[0]))
        return a, b

    def _recorded_move(self, distance_mm: float, pa: dict[str, Any]) -> None:
        """The move with the compensations' inputs in ``last_record``, as a mark procedure's parameters set
        them: the inclinometer at the start (``imu_readings`` averaged), the odometry there and the tracker's
        stream along the move."""
        p = self.ctx.params
        # robot_prev: the odometry at P_prev, so the dataset shows the move the base executed
        self.last_record = {"imu_prev": read_tilt(self.ctx.call, p.imu_readings, p.imu_interval_s),
                            "robot_prev": self.ctx.call("robot.status")}
        rate: float | None = p.stream_rate_hz  # None: the tracker's configured rate; 0: no stream
        if pa.get("abs_H_trk") is None or rate == 0 or abs(distance_mm) > 1900:
            self.move(distance_mm)
            return
        # the recorded final move may run slower: more stream points and inclinometer samples along it
        stream, why = record_move(self.ctx, distance_mm, p.approach_speed_mm_s, pa["abs_H_trk"], rate,
                                  self.last_record["imu_prev"])
        if stream is None:  # heading_fit then reports "no tracker stream was recorded"; the log says why
            log.warning("approach without the tracker's stream: %s", why)
            self.move(distance_mm)
        else:
            self.last_record["stream"] = stream

    def turn_to(self, heading_deg: float) -> None:
        self.turn(wrap_deg(heading_deg - self.heading))

    # ------------------------------------------------------------------ compound

    def goto(self, xy: np.ndarray, tol_mm: float = 1.0, max_iter: int = 4) -> np.ndarray:
        """Bring the reflector to ``xy`` (ACS) within ``tol_mm``: turn toward it, drive, check."""
        P = self.where()[0]
        for _ in range(max_iter):
            vec = np.asarray(xy, float) - P[:2]
            dist = float(np.hypot(*vec))
            if dist < tol_mm:
                return P
            self.turn_to(math.degrees(math.atan2(vec[1], vec[0])))
            P = self.straight(dist)[1]
        return P

    def approach(self, xy: np.ndarray, heading_deg: float, d_mm: float,
                 record: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """Stop at ``xy`` facing ``heading_deg`` after a straight run of ``d_mm``: (P_prev, P_at); ``record``:
        that run's compensation inputs too (:meth:`straight`)."""
        u = np.array([math.cos(math.radians(heading_deg)), math.sin(math.radians(heading_deg))])
        self.goto(np.asarray(xy, float) - d_mm * u)
        self.turn_to(heading_deg)
        return self.straight(d_mm, record=record)
