"""The systemd watchdog: pings flow from a healthy ritad and stop when an owner thread hangs.

The first test runs ritad as a process with ``NOTIFY_SOCKET`` and ``WATCHDOG_USEC``
(1 s, so a ping every 0.5 s) and counts the pings. The second drives
``Daemon.supervise`` in-process with a notifier on a temporary socket, hangs the
camera's owner thread inside a job far beyond its time limit, and checks that the
pings stop, ``daemon.health.alive`` turns false, and both recover once the job ends.
"""
from __future__ import annotations

import logging
import signal
import socket
import threading
import time
from typing import Callable
from pathlib import Path

import pytest

from daemon.ritad import config
from daemon.bus.client import Client
from daemon.ritad.daemon import Daemon
from daemon.ritad.notify import Notifier
from tests.daemon.ritad.test_faults import SMALL_CAMERA, wait_for
from tests.daemon.ritad.test_faults_process import Ritad, write_config


def count_pings(sock: socket.socket, duration: float) -> int:
    n = 0
    end = time.monotonic() + duration
    while time.monotonic() < end:
        try:
            n += sock.recv(4096).count(b"WATCHDOG=1")
        except socket.timeout:
            pass
    return n


def test_watchdog_pings_from_a_ritad_process(tmp_path: Path) -> None:
    cfg, endpoint = write_config(tmp_path, tmp_path / "data")
    ritad = Ritad(tmp_path, cfg, watchdog_usec=1_000_000)
    try:
        ritad.wait_notify_ready()
        pings = count_pings(ritad.sock, 2.6)
        assert 3 <= pings <= 7  # every 0.5 s: about 5 in 2.6 s
        ritad.proc.send_signal(signal.SIGTERM)
        assert ritad.proc.wait(10) == 0
        assert any("STOPPING=1" in m for m in ritad.recv(0.3))
    finally:
        ritad.kill()


def test_hung_owner_thread_stops_the_pings(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                            caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.setenv("WATCHDOG_USEC", "1000000")
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    sock.settimeout(0.05)
    notifier = Notifier(str(path))
    assert notifier.watchdog_interval == 0.5
    cfg = config.sim_config(tmp_path / "rt")
    cfg.daemon.start_worker = False
    cfg.devices.camera = SMALL_CAMERA
    d = Daemon(cfg)
    d.start()
    sup = threading.Thread(target=d.supervise, args=(notifier,), daemon=True)
    sup.start()
    release = threading.Event()
    try:
        with Client(d.server.endpoints[0], timeout=10) as c:
            c.wait_ready(timeout=30)
            assert count_pings(sock, 1.6) >= 2
            # the job may take 0.5 s; the runner counts as alive until 5 s past that
            hang = d.rigs.camera.job(lambda cam: release.wait(60), timeout=0.5)
            t_hang = time.monotonic()
            wait_for(lambda: not d.alive(), 10, "the hung camera thread to be noticed")
            noticed = time.monotonic() - t_hang
            assert 5.0 <= noticed < 8.0  # 5.5 s plus polling and scheduling slack
            count_pings(sock, 0.2)  # drop a ping sent just before
            with caplog.at_level(logging.ERROR, logger="ritad"):
                assert count_pings(sock, 2.0) == 0  # four intervals without a single ping
            assert "watchdog withheld" in caplog.text
            h = c.call("status")
            assert h["alive"] is False and h["devices"]["camera"]["state"] == "BUSY"
            assert all(h["devices"][k]["state"] == "READY" for k in ("tracker", "robot"))
            release.set()
            assert hang.result(5) is True
            wait_for(d.alive, 5, "alive again")
            assert count_pings(sock, 1.6) >= 2  # the pings resume once the thread is back
            assert c.call("status")["alive"] is True
    finally:
        release.set()
        d.stop_event.set()
        sup.join(5)
        d.stop()
        for r in (rig.runner for rig in d.rigs):
            if hasattr(r.device, "shutdown"):
                r.device.shutdown()
        sock.close()
    print(f"\nhung owner thread noticed after {noticed:.2f} s (job limit 0.5 s + 5 s grace)")


def ping_times(sock: socket.socket, duration: float,
               clock: Callable[[], float] = time.monotonic) -> list[float]:
    """Arrival times (on ``clock``) of the WATCHDOG=1 datagrams within ``duration`` s."""
    times: list[float] = []
    end = time.monotonic() + duration
    while time.monotonic() < end:
        try:
            if b"WATCHDOG=1" in sock.recv(4096):
                times.append(clock())
        except socket.timeout:
            pass
    return times


def test_runner_stays_alive_while_it_waits_in_backoff() -> None:
    """A device that never answers: the owner thread keeps beating through backoffs longer than the
    heartbeat limit, and every retry counts in ``reconnects`` (an operator reads the retries there)."""
    from daemon.ritad.runner import DeviceRunner
    from drivers.base import DeviceState

    attempts: list[float] = []

    def unreachable():
        attempts.append(time.monotonic())
        raise ConnectionRefusedError("tracker switched off")

    # backoff 0.05 s doubling to 2 s: waits of 1.6 s and 2 s exceed the 1 s heartbeat limit
    r = DeviceRunner("tracker", unreachable, lambda *_: None, backoff_min=0.05, backoff_max=2.0)
    r.start()
    try:
        beats = set()
        end = time.monotonic() + 6.0
        while time.monotonic() < end:
            beats.add(r.heartbeat)  # the runner's own beat times (its thread sets them)
            time.sleep(0.02)
        sampled_until = time.monotonic()
        assert r.state is DeviceState.FAULT and "switched off" in r.reason
        long_waits = [(a, b) for a, b in zip(attempts, attempts[1:]) if b - a >= 1.5 and b < sampled_until]
        assert long_waits  # the backoff really did outlast the 1 s heartbeat limit
        # order, not age: the runner beat inside every such wait, so a watchdog never sees it hung there
        silent = [(round(a - attempts[0], 2), round(b - a, 2)) for a, b in long_waits
                  if not any(a < h < b for h in beats)]
        assert silent == [], f"no heartbeat during the backoff waits starting at (t, length) {silent}"
        assert r.reconnects == len(attempts) - 1 >= 6  # the first attempt is a connect, the rest retries
    finally:
        r.stop()
    assert not r.is_alive()


def test_watchdog_pings_with_every_device_unreachable(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """All three devices unreachable for > 2 x WatchdogSec, with reconnect backoffs longer than both
    the ping interval and the heartbeat limit (the robot's 30 s / 10 s / 20 s scaled by 1/10):
    pings never stop, ``health.alive`` stays true, devices are FAULT with a reason."""
    monkeypatch.setenv("WATCHDOG_USEC", "2000000")  # WatchdogSec=2: a ping every second
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    sock.settimeout(0.05)
    notifier = Notifier(str(path))
    rt = tmp_path / "rt"
    cfg = config.from_dict({
        "daemon": {"command_endpoints": [f"ipc://{rt}/cmd"], "telemetry_endpoints": [f"ipc://{rt}/tel"],
                   "frame_endpoints": [f"ipc://{rt}/frm"], "data_dir": str(tmp_path / "data"),
                   "reconnect_min_s": 0.5, "reconnect_max_s": 3.0, "heartbeat_timeout_s": 1.0},
        "devices": {"camera": "genicam:///nonexistent/producer.cti", "tracker": "emscon://127.0.0.1:1",
                    "robot": "socket://127.0.0.1:1"}})
    d = Daemon(cfg)
    d.start()
    sup = threading.Thread(target=d.supervise, args=(notifier,), daemon=True)
    sup.start()
    try:
        with Client(d.server.endpoints[0], timeout=10) as c:
            sub = c.subscriber(["daemon.health", "daemon.state"])
            pings = ping_times(sock, 9.0, time.time)  # backoffs 0.5, 1, 2, 3, 3 s: two waits of 3 s in here
            healths, attempts = [], []
            while (msg := sub.recv(0.05)) is not None:
                if msg[0] == "daemon.health":
                    healths.append(msg[1]["data"])
                elif msg[1]["data"]["state"] == "CONNECTING":  # a connect attempt, on the host's clock
                    attempts.append((msg[1]["data"]["device"], msg[1]["t_ns"] / 1e9))
            sub.close()
            h = c.call("status")
    finally:
        d.stop_event.set()
        sup.join(5)
        d.stop()
        notifier.close()
        sock.close()
    # order, not age: a ping inside every backoff wait longer than WatchdogSec (2 s), so systemd never
    # sees ritad hung while its devices back off
    long_waits = []
    for kind in ("camera", "tracker", "robot"):
        times = [t for k, t in attempts if k == kind]
        long_waits += [(a, b) for a, b in zip(times, times[1:]) if b - a >= 2.5 and b <= pings[-1]]
    assert long_waits, attempts  # the backoffs really did outlast WatchdogSec
    silent = [(round(a, 2), round(b - a, 2)) for a, b in long_waits if not any(a < p < b for p in pings)]
    assert silent == [], f"no watchdog ping during the backoff waits (start, length) {silent}"
    assert len(healths) >= 3 and all(x["alive"] for x in healths)
    assert h["alive"] is True
    for kind, dev in h["devices"].items():
        assert dev["state"] in ("FAULT", "CONNECTING"), (kind, dev)
        assert dev["reason"] or dev["state"] == "CONNECTING", (kind, dev)
        assert dev["reconnects"] >= 3, (kind, dev)  # every retry counts
