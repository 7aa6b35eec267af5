"""The shared "ritad up with fakes, devices READY" fixture for tests that run ritad in-process.

Tests that need ritad as a real process (signals, systemd notify, the README) use
``fakes.launch.start_ritad`` instead; both wait with ``Client.wait_ready``, the bus
library's one definition of READY. fakes/ may not import ritad (tests/system/test_layers.py),
so the in-process variant lives here.
"""
from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any, Callable, Iterator

from daemon.bus import station
from daemon.bus.client import Client
from daemon.ritad import config
from daemon.ritad.rigs import CameraRig, Rigs, RobotRig, TrackerRig
from daemon.ritad.stop_latch import StopLatch
from daemon.ritad.timelines import Timelines
from daemon.ritad.timeouts import Timeouts
from daemon.ritad.daemon import Daemon

#: a small, noise-free simulated camera: renders in milliseconds
SMALL_CAMERA = "sim:?size=64x48&noise=0"


@contextlib.contextmanager
def ritad_in_process(rt: Path, data: Path | None = None, *, ready: bool = True, timeout: float = 60.0,
                     client_timeout: float = 10.0, configure: Callable[[config.Config], None] | None = None,
                     **devices: str) -> Iterator[tuple[Daemon, Client]]:
    """A sim ritad (no worker, small camera, ``devices`` overriding URLs) and a client to it.

    ``configure`` edits the config last, before the daemon starts (e.g. tcp endpoints with CURVE).

    With ``ready`` the devices are READY when this yields. On exit the daemon stops and the
    fakes' servers (tracker TCP, robot pty) shut down.
    """
    cfg = config.sim_config(rt, data)
    cfg.daemon.start_worker = False
    cfg.devices.camera = SMALL_CAMERA
    for kind, url in devices.items():
        setattr(cfg.devices, kind, url)
    if configure is not None:
        configure(cfg)
    d = Daemon(cfg)
    d.start()
    c = Client(d.server.endpoints[0], timeout=client_timeout)
    try:
        if ready:
            c.wait_ready(timeout=timeout)
        yield d, c
    finally:
        c.close()
        d.stop_event.set()
        d.stop()
        for r in (rig.runner for rig in d.rigs):
            if hasattr(r.device, "shutdown"):
                r.device.shutdown()


def unstarted_rigs(cfg: config.Config, latch: StopLatch | None = None) -> Rigs:
    """The daemon's three rigs for ``cfg``, their runners never started (handlers built, not served):
    a job submitted to one fails ``not_ready`` at once."""
    publish = lambda topic, data: None  # noqa: E731 - nothing is published
    timelines, d = Timelines(), cfg.daemon
    frames: Any = None  # no frame is ever streamed
    latch = latch if latch is not None else StopLatch(publish)
    return Rigs(camera=CameraRig("sim:", publish, frames, timelines, d, cfg.camera),
                tracker=TrackerRig("sim:", publish, timelines, d, cfg.tracker, station.IDENTITY),
                robot=RobotRig("sim:", publish, timelines, d, cfg.robot, latch, Timeouts()))


__all__ = ["SMALL_CAMERA", "ritad_in_process", "unstarted_rigs"]
