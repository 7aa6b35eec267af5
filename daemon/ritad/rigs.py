"""A device as a unit: a rig holds one device kind's runner (its owner thread, which owns the device
clock), the sink its adapter emits into, and what only that kind's handlers use.

The daemon builds one rig per kind and hands each to the handlers of its commands, never the others:
the camera's stamps its frames' exposure time on the host's timeline, the robot's holds the motion
gate (through the stop latch) and the motions waiting for their end. Every rig's sink feeds its own
clock and the shared timelines, then publishes; nothing else routes a device's telemetry.
"""
from __future__ import annotations

from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any, Callable, Iterator

from daemon.bus.names import Topic
from daemon.ritad.config import DaemonSection, RobotSection, TrackerSection
from daemon.ritad.device_clock import DeviceClock
from daemon.ritad.futures import chain
from daemon.ritad.motion import MotionWaiters, RobotJob
from daemon.ritad.publisher import FramePublisher
from daemon.ritad.registry import build_device
from daemon.ritad.runner import DeviceRunner
from daemon.ritad.stop_latch import StopLatch
from daemon.ritad.timelines import Timelines
from daemon.ritad.timeouts import Timeouts
from drivers.base import Camera, Device, DeviceSettings, Frame, Payload
from drivers.camera_settings import CameraSettings
from drivers.motion_gate import MotionGate

Publish = Callable[[str, Any], None]


class Rig:
    """One device kind: its runner and its sink. ``job`` runs ``fn(device)`` in the owner thread."""

    def __init__(self, kind: str, url: str, publish: Publish, timelines: Timelines, daemon: DaemonSection,
                 settings: DeviceSettings = None) -> None:
        self.kind, self.url = kind, url
        self._publish, self._timelines, self._settings = publish, timelines, settings
        self.runner = DeviceRunner(kind, self._build, publish, backoff_min=daemon.reconnect_min_s,
                                   backoff_max=daemon.reconnect_max_s,
                                   heartbeat_timeout=daemon.heartbeat_timeout_s,
                                   open_timeout=daemon.open_timeout_s, owes_halt=self.owes_halt)

    @property
    def clock(self) -> DeviceClock:
        return self.runner.clock

    def _build(self) -> Device:
        """The adapter, built (not opened) in the runner's thread at each (re)connect."""
        return build_device(self.kind, self.url, emit=self.emit, settings=self._settings)

    def emit(self, topic: str, payload: Payload) -> None:
        """The adapter's sink (its owner thread; never blocks): its clock and the timelines, then the bus."""
        self._publish(topic, self._timelines.observe(topic, payload, self.clock))

    def owes_halt(self) -> bool:
        """Whether the device must be reconnected at once, without backoff (the robot's owed halt)."""
        return False

    def job(self, fn: Callable[[Any], Any], *, timeout: float = 60.0) -> Future:
        return self.runner.submit(fn, timeout=timeout)

    def status(self, read: Callable[[Any], dict[str, Any]]) -> Future:
        """``read(device)`` in the owner thread, with the device clock's mapping added."""
        return chain(self.job(read), lambda st: {**st, "clock": self.clock.status()})


class CameraRig(Rig):
    """The camera: frames go on the frame socket with their exposure's host time."""

    def __init__(self, url: str, publish: Publish, frames: FramePublisher, timelines: Timelines,
                 daemon: DaemonSection, settings: CameraSettings) -> None:
        super().__init__("camera", url, publish, timelines, daemon, settings)
        self._frames = frames

    def emit(self, topic: str, payload: Payload) -> None:
        if isinstance(payload, Frame):  # a streamed frame
            self._frames.publish(self.clock.stamp_frame(payload))
            return
        super().emit(topic, payload)

    def latest(self) -> Frame | None:
        """The newest frame published on the frame socket (live view, detection)."""
        return self._frames.last_frame

    def stamped(self, camera: Camera) -> Frame:
        """One triggered frame with its exposure's host time (in the owner thread)."""
        return self.clock.stamp_frame(camera.trigger())

    def trigger(self, timeout: float = 30.0) -> Future:
        return self.job(self.stamped, timeout=timeout)


class TrackerRig(Rig):
    """The tracker, with its station pose and default stream rate."""

    def __init__(self, url: str, publish: Publish, timelines: Timelines, daemon: DaemonSection,
                 section: TrackerSection, abs_H_trk: list[list[float]]) -> None:
        super().__init__("tracker", url, publish, timelines, daemon)
        self.abs_H_trk = abs_H_trk  # tracker frame -> ACS (daemon/bus/station.py)
        self.stream_rate_hz = section.stream_rate_hz


class RobotRig(Rig):
    """The robot base: its motion gate (STOP first, through the latch), its limits and the motions waiting
    for their end."""

    def __init__(self, url: str, publish: Publish, timelines: Timelines, daemon: DaemonSection,
                 limits: RobotSection, latch: StopLatch, timeouts: Timeouts) -> None:
        super().__init__("robot", url, publish, timelines, daemon, latch.gate)
        self.limits, self.latch, self.timeouts = limits, latch, timeouts
        self.motions = MotionWaiters(self._submit_motion, timeouts)
        self.halt_wait_s = 2.0  # how long robot.stop's reply waits for the base to acknowledge the halt

    @property
    def gate(self) -> MotionGate:
        return self.latch.gate

    def _submit_motion(self, fn: RobotJob) -> Future:
        return self.job(fn)

    def emit(self, topic: str, payload: Payload) -> None:
        if topic == Topic.ROBOT_EVENT:  # a motion's DONE or FAULT ends the motions waiting for it
            self.motions.on_event(payload)
        super().emit(topic, payload)

    def owes_halt(self) -> bool:
        return self.gate.pending  # a STOP the base has not acknowledged: reconnect at once to send it


@dataclass(frozen=True)
class Rigs:
    """The daemon's devices, one rig per kind."""

    camera: CameraRig
    tracker: TrackerRig
    robot: RobotRig
    #: the device kinds plugins declare (plugins.DeviceKind)
    more: dict[str, Rig] = field(default_factory=dict)

    def __iter__(self) -> Iterator[Rig]:
        return iter((self.camera, self.tracker, self.robot, *self.more.values()))

    def info(self, kind: str) -> dict[str, Any]:
        """What the device of ``kind`` said about itself when it opened (plugins read the camera's size)."""
        return next(r.runner.info for r in self if r.kind == kind)
