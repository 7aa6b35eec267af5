"""What bus handlers may use of the daemon: exactly this, never the ``Daemon`` itself.

``Daemon.services()`` fills it in; tests build one with fakes. Each field says what a
handler group needs: device jobs, robot motions, the storage thread, the data dir, the
few config values handlers read, the calibration mailbox and the stop latch.
"""
from __future__ import annotations

from concurrent.futures import Executor, Future
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Protocol

from daemon.ritad.calib_jobs import CalibJobs
from daemon.ritad.config import RobotSection
from daemon.ritad.motion import RobotJob
from daemon.ritad.stop_latch import StopLatch
from drivers.base import Frame


class SubmitJob(Protocol):
    """Run ``fn(device)`` in the device's owner thread, in arrival order."""

    def __call__(self, kind: str, fn: Callable[[Any], Any], *, timeout: float = 60.0) -> Future: ...


@dataclass(frozen=True)
class Services:
    job: SubmitJob
    motion: Callable[[RobotJob, bool, float], Future]  # (fn(robot), wait, timeout_s)
    storage: Executor                    # the one storage thread: file work never holds up a device or the bus
    data_dir: Path
    private_dirs: tuple[str, ...]        # top-level data-dir folders files.* never serve
    auth_dir: Path                       # the CURVE allow-list folder (keys.* commands, admin)
    save_capture: Callable[..., Path]    # (parts, label, dataset=None) -> entry path; call in ``storage``
    abs_H_trk: list[list[float]]         # tracker frame -> ACS (daemon/bus/station.py)
    stream_rate_hz: float                # default tracker stream rate (config [tracker])
    robot: RobotSection                  # motion limits (config [robot])
    calib: CalibJobs
    device_info: Callable[[str], dict[str, Any]]
    hello: Callable[[], dict[str, Any]]
    health: Callable[[], dict[str, Any]]
    state: Callable[[], dict[str, Any]]
    latest_frame: Callable[[], Frame | None] = lambda: None  # the newest published Frame, for camera.preview
    latch: StopLatch = field(default_factory=lambda: StopLatch(lambda topic, data: None))  # the latched stop
    abort_motions: Callable[[str], None] = lambda why: None  # fail every motion waiting for its end
    clock_status: Callable[[str], dict[str, Any]] = lambda kind: {}  # a device clock's mapping (device_clock.py)
    at_time: Callable[[int, float], dict[str, dict[str, Any]]] = lambda t_ns, wait_s: {}  # streams at an instant
    stamp_frame: Callable[[Frame], Frame] = lambda frame: frame  # its exposure's host time (device_clock.py)
    halt_wait_s: float = 2.0  # how long robot.stop's reply waits for the base to acknowledge the halt
