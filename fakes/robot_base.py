"""The simulated drive controller: protocol state machine and kinematics.

:class:`FakeBase` answers protocol lines (docs/robot-protocol.md) and moves the robot in the shared
:class:`~fakes.world.World`. It knows nothing about ports: the pty server in :mod:`fakes.robot` feeds it
lines, calls :meth:`FakeBase.tick` and sends what :meth:`FakeBase.drain` returns. Every public method
takes the base's own lock, so tests may inject faults from another thread. Its boot (silence, banner,
a reset on DTR): :mod:`fakes.robot_boot`; protocol defects for the conformance kit:
:mod:`fakes.robot_defects`.

Two poses are kept apart on purpose: *odometry* integrates the commanded motion (starts at 0, 0, 0 at
power-on, like wheel encoders) and *truth* (``world.robot``) adds the drive errors from ``world.params``:

* ``drive_scale_error`` — a fixed relative error of every move distance and turn
  angle (a wrong wheel diameter), not random;
* ``drive_heading_sigma_deg`` — Gaussian heading error per move and per turn;
* ``drive_lateral_sigma_mm`` — Gaussian sideways offset of the end point per move;
* ``floor_tilt_sigma_mrad`` — a new Gaussian roll and pitch at every stop, in STATUS with an inclinometer.

Protocol version 2 (a host's ``HELLO,seq,2``; ``max_protocol=1`` makes a version-1 base): the
base's own clock (offset and drift apart from the host's) in STATUS, and the STATE/INCL sample
streams of :mod:`fakes.robot_stream`, queued by :meth:`FakeBase.tick` apart from the replies.
Version 3 (``HELLO,seq,3[,host_timeout_ms]``) adds the host watchdog: a motion halts itself, FAULT
HOST_LOST, when no valid host line came within the agreed timeout.
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import replace
from typing import Callable

from drivers import robot_protocol as rp
from fakes.robot_boot import Boot, reboot
from fakes.robot_motion import (HostWatchdog, Motion, fraction_at, inclinometer_output, motion_state,
                                pose_on_path, unit_interval, wrap_deg)
from fakes.robot_stream import DEFAULT_DRIFT_PPM, INCL_RATE_HZ, BaseClock, SampleStreams, seeded_offset_s
from fakes.world import RobotPose, World

MODEL = "RITA-SIM-BASE"
FIRMWARE = "sim-1.0"
SERIAL_NUMBER = "SIM-0001"
BATTERY_FULL_V = 25.2
BATTERY_V_PER_M = 0.002  # volts lost per metre driven (keeps the number alive)


class FakeBase:
    """A simulated base controller driving ``world.robot``."""

    def __init__(self, world: World, *, time_scale: float = 0.02, fault_rate: float = 0.0,
                 clock: Callable[[], float] = time.monotonic, max_protocol: int = rp.PROTOCOL_VERSION,
                 clock_offset_s: float | None = None, clock_drift_ppm: float = DEFAULT_DRIFT_PPM,
                 incl_rate_hz: float = INCL_RATE_HZ, boot: Boot | None = None) -> None:
        if not time_scale >= 0.0:
            raise ValueError(f"time_scale={time_scale!r} must be >= 0")
        if max_protocol not in rp.PROTOCOL_VERSIONS:
            raise ValueError(f"max_protocol={max_protocol!r} must be one of {rp.PROTOCOL_VERSIONS}")
        self.max_protocol = max_protocol
        self.session = 1  # the protocol of the session the last HELLO opened
        self.watchdog = HostWatchdog()  # armed by a version-3 HELLO
        self.world = world
        self.time_scale = time_scale
        self.fault_rate = unit_interval("fault_rate", fault_rate)
        self.clock = clock
        self._lock = threading.RLock()
        self._drive_rng = world.rng("robot.drive")
        self._tilt_rng = world.rng("robot.tilt")
        self._fault_rng = world.rng("robot.fault")
        self._slip_rng = world.rng("robot.slip")
        self._bend_rng = world.rng("robot.bend")
        # inclinometer noise: at a standstill from a generator drawn afresh for each stop, so that the
        # readings a procedure takes there do not depend on how many polls (ritad's 2 Hz STATUS, the
        # worker's polls while moving) came before; while moving from its own generator
        self._imu_rng = world.rng("robot.imu")
        self._imu_moving_rng = world.rng("robot.imu.moving")
        self._stops = 0
        self._imu_held: tuple[float, tuple[float, float]] | None = None  # (clock, sample) of the output
        self.odometry = (0.0, 0.0, 0.0)
        self.state = "IDLE"
        self.fault = ""
        self.motion: Motion | None = None
        #: the motion finished last and the clock time of the tick that finished it (pose_at)
        self._last_motion: tuple[Motion | None, float] = (None, 0.0)
        self.travelled_mm = 0.0
        if clock is time.monotonic:  # the world's clock: the tracker asks for poses on it
            world.pose_source = self.pose_at
        self._last_motion_cmd: tuple[str, bytes] | None = None  # (body, reply) for retries
        self._out: list[bytes] = []
        self._stream_out: list[bytes] = []
        offset = seeded_offset_s(world.rng("robot.clock")) if clock_offset_s is None else clock_offset_s
        self.base_clock = BaseClock(clock(), offset, clock_drift_ppm)
        incl_rng = world.rng("robot.incl.stream")  # its own: STATUS readings stay as they were
        self.streams = SampleStreams(self.base_clock,
                                     (lambda r, p: world.effects.inclinometer(r, p, incl_rng))
                                     if world.params.base_has_inclinometer else None,
                                     time_scale, incl_rate_hz)
        self.counters = {"rx_lines": 0, "garbage": 0, "bad_checksum": 0, "naks": 0, "duplicates": 0,
                         "lost_booting": 0}
        self.boot = boot or Boot()  # silent while it boots, its banner after (fakes/robot_boot.py)
        self.boot.power_on(clock())  # a base with a boot time boots with its host

    # ------------------------------------------------------------------ I/O side

    def drain(self) -> list[bytes]:
        """Lines waiting to be sent (replies and events), oldest first."""
        with self._lock:
            out, self._out = self._out, []
            return out

    def drain_stream(self) -> list[bytes]:
        """STATE/INCL sample lines waiting to be sent, oldest first (a full line may drop these)."""
        with self._lock:
            out, self._stream_out = self._stream_out, []
            return out

    @property
    def moving(self) -> bool:
        return self.motion is not None

    @property
    def last_halt(self) -> float:
        """Clock time of the tick that ended the last motion (0 before any): when its wheels stopped."""
        return self._last_motion[1]

    def handle_line(self, line: bytes) -> None:
        """Process one received line (terminator removed); replies go to the outbox."""
        with self._lock:
            if not line.strip():
                return
            if self.boot.booting(self.clock()):  # the bootloader does not listen to the protocol
                self.counters["lost_booting"] += 1
                return
            self.counters["rx_lines"] += 1
            try:
                msg = rp.decode(line)
            except rp.ProtocolError as exc:
                if exc.kind == "checksum":
                    # the seq of a corrupted line cannot be trusted: answer without one
                    self._nak(None, "CHECKSUM", str(exc))
                    self.counters["bad_checksum"] += 1
                elif exc.kind == "syntax":
                    self._nak(None, "SYNTAX", str(exc))
                else:
                    self.counters["garbage"] += 1  # line noise: nothing to answer
                return
            self.watchdog.heard(self.clock())  # a valid line: the host is alive, whatever it says
            try:
                seq = msg.seq()
            except rp.ProtocolError as exc:
                self._nak(None, "SYNTAX", str(exc))
                return
            if seq is None:
                self._nak(None, "SYNTAX", f"{msg.kind}: empty seq")
                return
            handler = {"HELLO": self._hello, "MOVE": self._move, "TURN": self._turn,
                       "STOP": self._stop, "STATUS": self._status, "STATE": self._state}.get(msg.kind)
            if handler is None or (msg.kind == "STATE" and self.session < 2):  # STATE is unknown to v1
                self._nak(seq, "UNKNOWN", f"unknown command {msg.kind}")
                return
            try:
                handler(seq, msg)
            except rp.ProtocolError as exc:
                self._nak(seq, "SYNTAX", str(exc))

    def _send(self, kind: str, *fields: object) -> bytes:
        line = rp.encode(kind, *fields)
        self._out.append(line)
        return line

    def _nak(self, seq: int | None, reason: str, text: str) -> None:
        self.counters["naks"] += 1
        self._send("NAK", seq, reason, rp.text_field(text))

    # ------------------------------------------------------------------ commands

    def _hello(self, seq: int, msg: rp.Message) -> None:
        version = msg.field(1, "protocol")
        spoken = [str(v) for v in rp.PROTOCOL_VERSIONS if v <= self.max_protocol]
        if version not in spoken:
            self._nak(seq, "VERSION", f"base speaks protocol {' '.join(spoken)} not {version}")
            return
        timeout_ms = msg.optional_number(2, "host_timeout_ms") if version == "3" else None
        timeout_ms = rp.DEFAULT_HOST_TIMEOUT_MS if timeout_ms is None and version == "3" else timeout_ms
        if timeout_ms is not None and (why := rp.host_timeout_error(timeout_ms)) is not None:
            self._nak(seq, "RANGE", why)
            return
        self._last_motion_cmd = None  # a new session: seq numbers start over
        self.session = int(version)
        self.watchdog.timeout_s = None if timeout_ms is None else timeout_ms / 1000.0
        self.streams.set_rate(0.0, self.clock())  # and no stream until this host asks for one
        caps = [rp.CAP_INCL] if self.world.params.base_has_inclinometer else []
        caps += [rp.CAP_CLOCK, rp.CAP_STATE] if self.session >= 2 else []
        caps += [rp.CAP_WATCHDOG] if self.session >= 3 else []
        agreed = () if timeout_ms is None else (rp.num(timeout_ms, 0),)  # v3: the timeout the base uses
        self._send("VERSION", seq, self.session, MODEL, FIRMWARE, SERIAL_NUMBER, "+".join(caps), *agreed)

    def _state(self, seq: int, msg: rp.Message) -> None:
        rate = msg.number(1, "rate_hz")
        why = rp.state_rate_error(rate)
        if why is not None:
            self._nak(seq, "RANGE", why)
            return
        self._advance()
        self.streams.set_rate(rate, self.clock())
        self._send("ACK", seq, "STATE")

    def _status(self, seq: int, msg: rp.Message) -> None:
        self._advance()
        with self.world.lock:
            pose = self.world.robot
        roll = pitch = None
        if self.world.params.base_has_inclinometer:
            roll, pitch = inclinometer_output(self, pose)
        x, y, h = self.odometry
        battery = BATTERY_FULL_V - BATTERY_V_PER_M * self.travelled_mm / 1000.0
        clock = (self.base_clock.device_us(self.clock()),) if self.session >= 2 else ()  # CLOCK: t_us last
        self._send("STATUS", seq, self.state, rp.num(x, 4), rp.num(y, 4), rp.num(h, 6),
                   None if roll is None else rp.num(roll, 6), None if pitch is None else rp.num(pitch, 6),
                   rp.num(battery, 3), rp.text_field(self.fault), *clock)

    def _stop(self, seq: int, msg: rp.Message) -> None:
        self._advance()
        self._send("ACK", seq, "STOP")
        if self.motion is not None:
            self._finish(self._fraction(), "STOPPED")
        elif self.state == "FAULT":
            self.state, self.fault = "IDLE", ""  # STOP acknowledges a latched fault

    def _motion_precheck(self, seq: int, msg: rp.Message) -> bool:
        """Duplicate/busy/fault handling shared by MOVE and TURN; True = go ahead."""
        body = msg.body()
        if self._last_motion_cmd is not None and self._last_motion_cmd[0] == body:
            # same seq and arguments as the last accepted motion: the host retried
            # because our ACK got lost — repeat the ACK, do not move twice
            self.counters["duplicates"] += 1
            self._out.append(self._last_motion_cmd[1])
            return False
        self._advance()
        if self.state == "FAULT":
            self._nak(seq, "FAULT", f"latched fault {self.fault}; send STOP to clear")
            return False
        if self.motion is not None:
            self._nak(seq, "BUSY", f"moving (seq {self.motion.seq}); send STOP first")
            return False
        return True

    def _accepted(self, seq: int, msg: rp.Message, amount: float, speed: float, limit: float,
                  speeds: tuple[float, float], symbol: str) -> RobotPose | None:
        """MOVE/TURN admission: range, then state; the start pose, or None once a NAK went out."""
        if abs(amount) > limit or not speeds[0] <= speed <= speeds[1]:
            self._nak(seq, "RANGE", f"{msg.kind} {amount} at {speed}: limits |{symbol}|<={limit} "
                                    f"speed {speeds[0]}..{speeds[1]}")
            return None
        if not self._motion_precheck(seq, msg):
            return None
        with self.world.lock:
            return self.world.robot

    def _move(self, seq: int, msg: rp.Message) -> None:
        dist, speed = msg.number(1, "distance_mm"), msg.number(2, "speed_mm_s")
        start = self._accepted(seq, msg, dist, speed, rp.MAX_DISTANCE_MM,
                               (rp.MIN_SPEED_MM_S, rp.MAX_SPEED_MM_S), "d")
        if start is None:
            return
        p, fx = self.world.params, self.world.effects
        z_heading, z_lateral = self._drive_rng.standard_normal(2)
        travelled = dist * (1.0 + p.drive_scale_error + fx.slip(self._slip_rng))
        lateral = z_lateral * p.drive_lateral_sigma_mm
        heading = start.heading_deg + z_heading * p.drive_heading_sigma_deg
        bend = 0.0
        if fx.model.robot is not None:  # the error model's arc adds to the independent drive errors
            bend, turn = fx.bend(travelled, self._bend_rng)
            lateral, heading = lateral + bend, heading + turn
        a = math.radians(start.heading_deg)
        end = replace(start, x_mm=float(start.x_mm + travelled * math.cos(a) - lateral * math.sin(a)),
                      y_mm=float(start.y_mm + travelled * math.sin(a) + lateral * math.cos(a)),
                      heading_deg=float(heading))
        ox, oy, oh = self.odometry
        ob = math.radians(oh)
        odo_end = (ox + dist * math.cos(ob), oy + dist * math.sin(ob), oh)
        self._start_motion(seq, msg, start, end, odo_end, abs(dist) / speed, abs(dist), bend)

    def _turn(self, seq: int, msg: rp.Message) -> None:
        angle, speed = msg.number(1, "angle_deg"), msg.number(2, "speed_deg_s")
        start = self._accepted(seq, msg, angle, speed, rp.MAX_ANGLE_DEG,
                               (rp.MIN_TURN_SPEED_DEG_S, rp.MAX_TURN_SPEED_DEG_S), "a")
        if start is None:
            return
        p, fx = self.world.params, self.world.effects
        z_heading = self._drive_rng.standard_normal()
        end = replace(start, heading_deg=float(start.heading_deg + angle * (1.0 + p.drive_scale_error
                                                                            + fx.slip(self._slip_rng))
                                               + z_heading * p.drive_heading_sigma_deg))
        ox, oy, oh = self.odometry
        self._start_motion(seq, msg, start, end, (ox, oy, oh + angle), abs(angle) / speed, 0.0)

    def _start_motion(self, seq: int, msg: rp.Message, start: RobotPose, end: RobotPose,
                      odo_end: tuple[float, float, float], seconds: float, path_mm: float,
                      bend_mm: float = 0.0) -> None:
        fault_at = None
        if self.fault_rate > 0 and self._fault_rng.random() < self.fault_rate:
            fault_at = float(self._fault_rng.uniform(0.2, 0.8))
        self.motion = Motion(seq, start, end, self.odometry, odo_end, self.clock(),
                             seconds * self.time_scale, path_mm, fault_at, bend_mm)
        self.state = "MOVING"
        ack = self._send("ACK", seq, msg.kind)
        self._last_motion_cmd = (msg.body(), ack)
        self._advance()  # an instant motion (time_scale 0) is DONE right after its ACK

    # ------------------------------------------------------------------ motion

    def tick(self) -> None:
        """Advance the motion in progress to the current time and queue the samples due (the server
        calls it)."""
        with self._lock:
            if (banner := self.boot.banner_due(self.clock())) is not None:
                self._out.append(banner)
            self._advance()
            self._stream_out += self.streams.due(self.clock(), self)

    def set_dtr(self, on: bool) -> None:
        """The host set DTR (over RFC 2217); an assertion resets a base with auto-reset (robot_boot.py)."""
        self.reset(when=self.boot.set_dtr(on))

    def reset(self, when: bool = True) -> None:
        """The MCU restarts now (a reset line, a brown-out): boot silence, banner, state forgotten."""
        with self._lock:
            if when:
                reboot(self, self.clock())

    def state_at(self, t: float
                 ) -> tuple[tuple[float, float, float], tuple[float, float], tuple[float, float]]:
        """Odometry, wheel speeds and true tilt at clock time ``t`` (the STATE/INCL samples' source)."""
        return motion_state(self, t)

    def _fraction(self) -> float:
        m = self.motion
        assert m is not None
        return fraction_at(m, self.clock())

    def _advance(self) -> None:
        m = self.motion
        if m is None:
            return
        f = self._fraction()
        expiry = self.watchdog.expired(self.clock())
        if expiry is not None and (lost := fraction_at(m, expiry)) < min(
                1.0, 1.0 if m.fault_at is None else m.fault_at):
            m.fault_at = lost  # the wheels stop where the timer fired: the path ends there too (pose_at)
            self._finish(lost, "FAULT", rp.FAULT_HOST_LOST, "no host line within the host timeout")
        elif m.fault_at is not None and f >= m.fault_at:
            self._finish(m.fault_at, "FAULT", "STALL")
        elif f >= 1.0:
            self._finish(1.0, "OK")
        else:
            self._place(f)

    def _pose(self, m: Motion, f: float) -> RobotPose:
        return pose_on_path(self.world, m, f)

    def pose_at(self, t: float) -> RobotPose | None:
        """The true pose at clock time ``t`` during the motion in progress or the last one until it was
        finished, from its velocity profile: a continuous function of time, however seldom the base is
        ticked (the world's ``robot_at`` asks here first). None outside those motions."""
        with self._lock:
            for m, t_done in ((self.motion, math.inf), self._last_motion):
                if m is None or not m.t0 <= t <= t_done:
                    continue
                f = 1.0 if m.duration <= 0.0 else (t - m.t0) / m.duration
                return self._pose(m, min(f, 1.0 if m.fault_at is None else m.fault_at))
        return None

    def _place(self, f: float) -> tuple[RobotPose, tuple[float, float, float]]:
        """Put truth and odometry at fraction ``f`` of the motion (linear in time)."""
        m = self.motion
        assert m is not None
        pose = self._pose(m, f)
        odo = m.odo_end if f >= 1.0 else tuple(a + f * (b - a) for a, b in zip(m.odo_start, m.odo_end))
        self.world.set_robot(pose)
        self.odometry = odo  # type: ignore[assignment]
        return pose, odo  # type: ignore[return-value]

    def _finish(self, f: float, result: str, reason: str = "", text: str = "simulated wheel stall") -> None:
        """End the motion at fraction ``f``: settle (new tilt), report DONE or FAULT."""
        m = self.motion
        assert m is not None
        pose, (ox, oy, oh) = self._place(f)
        p = self.world.params
        roll, pitch = self._tilt_rng.standard_normal(2) * p.floor_tilt_sigma_mrad * 1e-3
        # settle adds the surface's tilt under the wheels to the random settling tilt
        self.world.set_robot(self.world.settle(replace(pose, heading_deg=wrap_deg(pose.heading_deg),
                                                       roll_rad=float(roll), pitch_rad=float(pitch),
                                                       z_mm=None)))
        self.odometry = (ox, oy, wrap_deg(oh))
        self.travelled_mm += f * m.path
        self._last_motion = (m, self.clock())  # pose_at answers for it up to this tick
        self.motion = None
        self._stops += 1
        self._imu_rng = self.world.rng(f"robot.imu.stop{self._stops}")
        self._imu_held = None
        if result == "FAULT":
            self.state, self.fault = "FAULT", reason
            self._send("FAULT", m.seq, reason, text)
        else:
            self.state = "IDLE"
            self._send("DONE", m.seq, result, rp.num(ox, 4), rp.num(oy, 4), rp.num(wrap_deg(oh), 6))
