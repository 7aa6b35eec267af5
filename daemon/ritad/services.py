"""What every bus handler group may share of the daemon: exactly this, never the ``Daemon`` itself.

A device's own things (its jobs, clock, motion gate, limits) are in its rig (daemon/ritad/rigs.py),
handed only to the handlers of its commands; this is what the groups share: the command table, the
storage thread and the data dir, the calibration mailbox and the stop latch, and the daemon's
reports. ``Daemon`` fills it in; tests build one with fakes.
"""
from __future__ import annotations

from concurrent.futures import Executor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

from daemon.bus.command_table import Command
from daemon.ritad.calib_jobs import CalibJobs
from daemon.ritad.stop_latch import StopLatch


@dataclass(frozen=True)
class Reports:
    """The daemon's answers about itself: ``hello``, ``health`` (``status``), late joiners' ``state``."""

    hello: Callable[[], dict[str, Any]]
    health: Callable[[], dict[str, Any]]
    state: Callable[[], dict[str, Any]]


@dataclass(frozen=True)
class Services:
    storage: Executor                    # the one storage thread: file work never holds up a device or bus
    data_dir: Path
    private_dirs: tuple[str, ...]        # top-level data-dir folders files.* never serve
    auth_dir: Path                       # the CURVE allow-list folder (keys.* commands, admin)
    save_capture: Callable[..., Path]    # (parts, label, dataset=None) -> entry path; call in ``storage``
    calib: CalibJobs
    latch: StopLatch                     # the latched stop: motions refused until robot.release
    device_info: Callable[[str], dict[str, Any]]  # what a device said when it opened (plugins)
    table: Mapping[str, Command]         # the daemon's command table, with its plugins' commands
