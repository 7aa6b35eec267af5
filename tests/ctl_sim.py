"""A fast in-process ``ritad`` on the simulated world for the ritactl tests (no calibration worker).

Tests play the worker themselves (``calib.report``) to put jobs in a known end state.
"""
from __future__ import annotations

import contextlib
import time
from pathlib import Path
from typing import Callable, Iterator

from daemon.ritad import config
from daemon.bus.client import Client
from daemon.ritad.main import Daemon


@contextlib.contextmanager
def sim_daemon(rt: Path, configure: Callable[[config.Config], None] | None = None) -> Iterator[Daemon]:
    """``configure`` edits the config before the daemon starts (e.g. tcp endpoints with CURVE)."""
    cfg = config.sim_config(rt)
    cfg.daemon.start_worker = False
    cfg.devices.camera = "sim:?size=64x48&noise=0"
    cfg.devices.tracker = "sim:?time_scale=0.002"
    cfg.devices.robot = "sim:?time_scale=1"  # real-time motions: a test can interrupt one
    if configure is not None:
        configure(cfg)
    d = Daemon(cfg)
    d.start()
    try:
        with Client(d.server.endpoints[0], timeout=10) as c:
            end = time.monotonic() + 60
            while not all(v["state"] == "READY" for v in c.call("status")["devices"].values()):
                assert time.monotonic() < end, "sim devices not READY within 60 s"
                time.sleep(0.05)
        yield d
    finally:
        d.stop_event.set()
        d.stop()
        for r in d.runners.values():
            if hasattr(r.device, "shutdown"):
                r.device.shutdown()


def post_job(c: Client, procedure: str = "referencing", job: str | None = None) -> str:
    return c.call("calib.start", procedure=procedure, params={}, **({"job": job} if job else {}))["job"]


def report(c: Client, job: str, kind: str, data: dict) -> None:
    """What the worker would send."""
    c.call("calib.report", job=job, kind=kind, data=data)
