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

from daemon.bus.procedures import DEFAULTS as PARAM_DEFAULTS
from daemon.worker.compensations import DEFAULT_IMU_READINGS, read_tilt
from daemon.worker.job import JobContext
from daemon.worker.motion import confirm_done
from daemon.worker.stream import DEFAULT_STREAM_RATE_HZ, record_move

MIN_HEADING_MOVE_MM = 20.0

log = logging.getLogger(__name__)


def wrap_deg(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


class Navigator:
    """Drives the robot through the bus; its heading estimate lives in the job state."""

    def __init__(self, ctx: JobContext, speed_mm_s: float = 100.0, turn_speed_deg_s: float = 30.0) -> None:
        self.ctx = ctx
        self.speed = speed_mm_s
        self.turn_speed = turn_speed_deg_s
        self.nav = ctx.state.setdefault("nav", {"heading_deg": None})
        if ctx.resumed:  # a run stopped (or killed) mid-turn leaves the robot off the checkpointed heading
            self.nav["heading_deg"] = None
        self.last_points: tuple[dict[str, Any], dict[str, Any]] | None = None
        #: compensation inputs of the last recorded approach: imu_prev, stream (see :meth:`straight`)
        self.last_record: dict[str, Any] = {}
        self.imu_readings = int(ctx.params.get("imu_readings", DEFAULT_IMU_READINGS))
        self.imu_interval_s = float(ctx.params.get("imu_interval_s", PARAM_DEFAULTS["imu_interval_s"]))
        # the recorded final move may run slower: more stream points and inclinometer samples along it
        self.approach_speed = float(ctx.params.get("approach_speed_mm_s") or speed_mm_s)
        rate = ctx.params.get("stream_rate_hz", DEFAULT_STREAM_RATE_HZ)
        self.stream_rate_hz = None if rate is None else float(rate)

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

        ``record``: the inclinometer at the start (``imu_readings`` averaged) and the
        tracker's stream along the move go to ``last_record`` (the compensations' inputs).
        """
        a, pa = self.where()
        if record:  # robot_prev: the odometry at P_prev, so the dataset shows the move the base executed
            self.last_record = {"imu_prev": read_tilt(self.ctx.call, self.imu_readings, self.imu_interval_s),
                                "robot_prev": self.ctx.call("robot.status")}
        if (record and pa.get("abs_H_trk") is not None and (self.stream_rate_hz is None or self.stream_rate_hz > 0)
                and abs(distance_mm) <= 1900):
            stream, why = record_move(self.ctx, distance_mm, self.approach_speed, pa["abs_H_trk"], self.stream_rate_hz,
                                      self.last_record["imu_prev"])
            if stream is None:  # heading_fit then reports "no tracker stream was recorded"; the log says why
                log.warning("approach without the tracker's stream: %s", why)
                self.move(distance_mm)
            else:
                self.last_record["stream"] = stream
        else:
            self.move(distance_mm)
        b, pb = self.where()
        self.last_points = (pa, pb)  # the full tracker points, for the dataset
        if abs(distance_mm) >= MIN_HEADING_MOVE_MM:
            d = (b - a) * math.copysign(1.0, distance_mm)
            self.nav["heading_deg"] = math.degrees(math.atan2(d[1], d[0]))
        return a, b

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

    def approach(self, xy: np.ndarray, heading_deg: float, d_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """Stop at ``xy`` facing ``heading_deg`` after a straight run of ``d_mm``: (P_prev, P_at)."""
        u = np.array([math.cos(math.radians(heading_deg)), math.sin(math.radians(heading_deg))])
        self.goto(np.asarray(xy, float) - d_mm * u)
        self.turn_to(heading_deg)
        return self.straight(d_mm, record=True)
