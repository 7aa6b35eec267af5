"""The STOP fault rig the fault tests and the STOP benchmark share: a fake base at real-time speed on
its own pty (a thread of the caller's process, apart from ritad's), a cable that can be cut between
it (fakes/link_proxy.py), and ritad as a process on the cable's pty with the other devices absent.
Distances and times are the base's own (its odometry and clock), never what ritad reports."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from daemon.bus.client import Client
from fakes.launch import RitadProcess, start_ritad
from fakes.link_proxy import LinkProxy
from fakes.robot import PtyServer
from fakes.robot_base import FakeBase
from fakes.world import World, WorldParams
from tools.harness.config import NO_DEVICES, ritad_toml

#: mm/s: a 2000 mm move lasts 20 s, far longer than a test or a benchmark round waits
SPEED = 100.0


def wait_for(pred: Any, timeout: float, what: str, poll: float = 0.002) -> Any:
    """Poll ``pred`` until it is true; AssertionError naming ``what`` after ``timeout`` s (hangs only)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if got := pred():
            return got
        time.sleep(poll)
    raise AssertionError(f"not within {timeout} s: {what}")


class StopRig:
    """The base (protocol ``protocol``), the cable and a ritad on it."""

    def __init__(self, tmp: Path, protocol: int) -> None:
        self.tmp = tmp
        world = World(WorldParams(seed=1, start_pose=(0.0, 0.0, 0.0)))
        self.base = FakeBase(world, time_scale=1.0, max_protocol=protocol)
        self.server = PtyServer(self.base)
        self.proxy = LinkProxy(self.server.path)
        self.ritad: RitadProcess | None = None
        self._clients: list[Client] = []

    def x(self) -> float:
        """The base's odometry x (mm) now."""
        with self.base._lock:  # the odometry and the motion in one consistent read
            self.base.tick()
            return self.base.odometry[0]

    def moving(self) -> bool:
        with self.base._lock:
            self.base.tick()
            return self.base.moving

    def start(self, query: str = "") -> RitadProcess:
        """ritad on the cable's pty (``query``: robot URL options, e.g. ``host_timeout=5``)."""
        devices = {**NO_DEVICES, "robot": f"serial://{self.proxy.path}" + (f"?{query}" if query else "")}
        self.ritad = start_ritad(ritad_toml(devices=devices, log_level="INFO"), tmp=self.tmp, timeout=60)
        return self.ritad

    def client(self) -> Client:
        """A client of the running ritad, once its robot is READY."""
        assert self.ritad is not None
        c = self.ritad.client(timeout=10)
        self._clients.append(c)  # closed with the rig
        c.wait_ready(devices=["robot"], timeout=60)
        return c

    def move(self, c: Client, distance: float = 2000.0) -> None:
        """Start a move and wait until the base is under way."""
        x0 = self.x()
        c.call("robot.move", distance_mm=distance, speed_mm_s=SPEED, confirm=True, wait=False)
        wait_for(lambda: self.x() > x0 + 20.0, 10, "the base under way")

    def harness_late(self, start: float, end: float) -> float:
        """How late (s) a line may have crossed the cable and reached the base between ``start`` and ``end``
        (monotonic) because this rig's own threads stalled (a loaded machine), not the host: the longest
        stall of the cable's thread plus the base's (their wake-ups, fakes/link_proxy.StallLog)."""
        return self.proxy.stalls.longest(start, end) + self.server.stalls.longest(start, end)

    def halted(self, timeout: float = 30.0) -> float:
        """Wait until the base no longer moves; its odometry x then."""
        wait_for(lambda: not self.moving(), timeout, "the base halted")
        return self.x()

    def close(self) -> None:
        for c in self._clients:
            c.close()
        if self.ritad is not None:
            self.ritad.kill()
        self.proxy.close()
        self.server.shutdown()


__all__ = ["SPEED", "StopRig", "wait_for"]
