"""Hostile bytes injected into a running daemon's device links: it resyncs and keeps serving.

emScon: a TCP proxy between the daemon's real ``EmsconTracker`` and the fake tracker
injects 220 random streams (from ``tests/drivers/test_fuzz_devices``: valid packets,
truncated, oversized, mutated, random bytes, sent whole or split) into the tracker's
byte stream. Every command gets one clear answer (never ``internal``), a broken
stream makes the runner reconnect, the tracker answers again afterwards and the
daemon keeps answering ``status``.

Robot: random lines are written into the simulated base's pty under the same
daemon: each is counted in the right driver counter and ``robot.status`` still works
without a reconnect.
"""
from __future__ import annotations

import queue
import selectors
import socket
import threading
import time
from typing import Any, Iterator

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from daemon.ritad import config
from daemon.bus.client import Client
from daemon.ritad.daemon import Daemon
from daemon.bus.protocol import CommandError
from fakes.tracker import FakeTrackerServer, FakeTrackerThread
from fakes.world import World
from tests.drivers.test_fuzz_devices import FUZZ, emscon_stream, expect_counts, robot_line
from tests.fuzzscale import cases


# ---------------------------------------------------------------------------- live: proxy + daemon


class InjectingProxy:
    """TCP proxy on 127.0.0.1:0 to the fake tracker; ``inject`` writes extra bytes to the client."""

    def __init__(self, upstream_port: int) -> None:
        self.upstream_port = upstream_port
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port = self.listener.getsockname()[1]
        self._wake_r, self._wake_w = socket.socketpair()
        self._inject: queue.Queue[bytes] = queue.Queue()
        self._stop = threading.Event()
        self.accepted = 0
        self._thread = threading.Thread(target=self._run, name="emscon-proxy", daemon=True)
        self._thread.start()

    def inject(self, chunks: list[bytes]) -> None:
        for c in chunks:
            self._inject.put(c)
        self._wake_w.send(b"x")

    def close(self) -> None:
        self._stop.set()
        self._wake_w.send(b"x")
        self._thread.join(5)

    def _run(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self.listener, selectors.EVENT_READ, "accept")
        sel.register(self._wake_r, selectors.EVENT_READ, "wake")
        pair: dict[str, socket.socket] = {}

        def drop() -> None:
            for s in pair.values():
                sel.unregister(s)
                s.close()
            pair.clear()

        while not self._stop.is_set():
            for key, _ in sel.select(0.2):
                try:
                    if key.data == "accept":
                        client, _ = self.listener.accept()
                        drop()
                        up = socket.create_connection(("127.0.0.1", self.upstream_port), timeout=5)
                        pair.update(client=client, up=up)
                        sel.register(client, selectors.EVENT_READ, "client")
                        sel.register(up, selectors.EVENT_READ, "up")
                        self.accepted += 1
                    elif key.data == "wake":
                        self._wake_r.recv(4096)
                        while not self._inject.empty():
                            chunk = self._inject.get()
                            if "client" in pair:
                                pair["client"].sendall(chunk)
                                time.sleep(0.002)  # keep the chunks apart on the wire
                    else:
                        data = key.fileobj.recv(1 << 16)
                        if not data:
                            drop()
                        else:
                            pair["up" if key.data == "client" else "client"].sendall(data)
                except (OSError, KeyError):
                    drop()
        drop()
        for s in (self.listener, self._wake_r, self._wake_w):
            s.close()


def _wait(pred: Any, timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < end, f"timed out waiting for {what}"
        time.sleep(0.01)


@pytest.fixture(scope="module")
def emscon_daemon(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Daemon, InjectingProxy]]:
    fake = FakeTrackerThread(FakeTrackerServer(World(), time_scale=0.002))
    fake.start(0)
    proxy = InjectingProxy(fake.port)
    cfg = config.sim_config(tmp_path_factory.mktemp("fuzzdev"))
    cfg.daemon.start_worker = False
    cfg.devices.camera = "sim:?size=64x48&noise=0"
    # no sample streams (as tests/drivers/test_fuzz_devices.py): a drawn "$STATE"/"$INCL" line would be a
    # malformed sample (syntax) then, not a line of an unknown kind (unexpected)
    cfg.devices.robot = "sim:?stream_hz=0"
    cfg.devices.tracker = f"emscon://127.0.0.1:{proxy.port}?timeout=0.2&meas_time_ms=10&connect_timeout=2"
    d = Daemon(cfg)
    d.start()
    try:
        yield d, proxy
    finally:
        d.stop_event.set()
        d.stop()
        robot = d.rigs.robot.runner.device
        if robot is not None:
            robot.shutdown()
        proxy.close()
        fake.close()


def probe_tracker(c: Client) -> str:
    """One tracker round trip; the unlocked fake answers MeasurementStatusNotReady."""
    try:
        c.call("tracker.measure", timeout=10)
        return "ok"
    except CommandError as exc:
        return exc.code


def test_emscon_streams_through_a_live_daemon(emscon_daemon: tuple[Daemon, InjectingProxy],
                                              caplog: pytest.LogCaptureFixture) -> None:
    d, proxy = emscon_daemon
    runner = d.rigs.tracker.runner
    _wait(lambda: runner.state.value == "READY", 30, "tracker READY")
    n, resynced, codes = [0], [0], {}
    t0 = time.monotonic()
    with Client(d.server.endpoints[0], timeout=10) as c:

        @settings(max_examples=cases(220, 80), **FUZZ)
        @given(s=emscon_stream())
        def run(s: dict[str, Any]) -> None:
            _wait(lambda: runner.state.value == "READY", 10, "tracker READY again")
            before = runner.reconnects
            body = s["body"]
            proxy.inject([body[a:b] for a, b in zip([0, *s["cuts"]], [*s["cuts"], len(body)]) if b > a])
            code = probe_tracker(c)  # whatever the stream did, the command gets one clear answer
            codes[code] = codes.get(code, 0) + 1
            assert code != "internal"
            for _ in range(5):  # recovered: a round trip reaches the tracker again
                _wait(lambda: runner.state.value == "READY", 10, "tracker READY again")
                if probe_tracker(c) == "tracker_MeasurementStatusNotReady":
                    break
            else:
                raise AssertionError(f"tracker did not recover: {runner.snapshot()}")
            if s["how"] in ("truncated", "oversized"):  # a broken stream forces a resync
                assert runner.reconnects > before, s
            resynced[0] += runner.reconnects > before
            assert c.call("status")["alive"] is True
            n[0] += 1

        run()
    print(f"\nlive emScon fuzz: {n[0]} streams in {time.monotonic() - t0:.1f} s, {resynced[0]} reconnects, "
          f"first probe: {codes}")
    assert resynced[0] > 20
    assert not [r for r in caplog.records if r.name == "daemon.ritad.runner" and r.levelname == "ERROR"]



def test_robot_lines_under_a_daemon(emscon_daemon: tuple[Daemon, InjectingProxy]) -> None:
    d, _ = emscon_daemon
    runner = d.rigs.robot.runner
    _wait(lambda: runner.state.value == "READY", 30, "robot READY")
    robot = runner.device
    n = [0]
    with Client(d.server.endpoints[0], timeout=10) as c:
        @settings(max_examples=40, **FUZZ)
        @given(lines=st.lists(robot_line(), min_size=24, max_size=24))
        def run(lines: list[tuple[bytes, str | None]]) -> None:
            before = dict(robot.counters)
            robot.server.inject(b"".join(line for line, _ in lines))  # by the base's own thread, in order
            assert c.call("robot.status")["state"] == "IDLE"
            expect_counts(lines, before, robot.counters)
            assert c.call("status")["devices"]["robot"]["state"] in ("READY", "BUSY")
            n[0] += len(lines)

        run()
    assert n[0] == 960 and runner.reconnects == 0
