"""A fast in-process ``ritad`` on the simulated world for the ritactl tests (no calibration worker).

Tests play the worker themselves (``calib.report``) to put jobs in a known end state.
"""
from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Callable, Iterator

from daemon.bus.client import Client
from daemon.ritad import config
from daemon.ritad.daemon import Daemon
from tests.ritad_up import ritad_in_process


@contextlib.contextmanager
def sim_daemon(rt: Path, configure: Callable[[config.Config], None] | None = None) -> Iterator[Daemon]:
    """``configure`` edits the config before the daemon starts (e.g. tcp endpoints with CURVE)."""
    # real-time robot motions: a test can interrupt one
    with ritad_in_process(rt, configure=configure, tracker="sim:?time_scale=0.002",
                          robot="sim:?time_scale=1") as (d, _):
        yield d


def post_job(c: Client, procedure: str = "referencing", job: str | None = None) -> str:
    params = {"mark_xy": [0.0, 0.0]} if procedure in ("measure-mark", "experiment") else {}  # required there
    return c.call("calib.start", procedure=procedure, params=params, **({"job": job} if job else {}))["job"]


def report(c: Client, job: str, kind: str, data: dict) -> None:
    """What the worker would send."""
    c.call("calib.report", job=job, kind=kind, data=data)
