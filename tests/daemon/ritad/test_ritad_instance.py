"""ritad as a process: one instance per runtime directory, --check-config, clean stops.

A second ritad on the same directories must exit with code 3 naming the first one's
pid, before it binds anything, and leave the first one's ipc telemetry working.
``--check-config`` validates without binding or locking. A SIGTERM stop logs nothing
at WARNING or above and removes the ipc socket files.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from daemon.bus.client import Client, Subscriber
from daemon.ritad.main import RitadExit
from fakes.launch import RitadProcess
from tests.daemon.ritad.test_faults_process import Ritad, write_config

ROOT = Path(__file__).resolve().parents[3]


def ritad(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "daemon.ritad.main", *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout, env={**os.environ, "PYTHONPATH": str(ROOT)})


def health_messages(endpoint: str, n: int, timeout: float) -> int:
    """How many daemon.health messages a fresh subscriber receives (stops at ``n``)."""
    sub = Subscriber(endpoint, ["daemon.health"])
    got = 0
    end = time.monotonic() + timeout
    try:
        while got < n and time.monotonic() < end:
            got += sub.recv(0.2) is not None
    finally:
        sub.close()
    return got


def sockets_in(rt: Path) -> dict[str, int]:
    return {p.name: p.stat().st_ino for p in rt.iterdir() if p.is_socket()}


def stop(r: RitadProcess) -> None:
    r.proc.send_signal(signal.SIGTERM)
    assert r.proc.wait(15) == 0


def test_second_ritad_leaves_the_first_ones_telemetry_working(tmp_path: Path) -> None:
    cfg, endpoint = write_config(tmp_path, tmp_path / "data")
    rt = tmp_path / "rt"
    first = Ritad(tmp_path, cfg)
    try:
        first.wait_notify_ready()
        telemetry = f"ipc://{rt}/telemetry"
        assert health_messages(telemetry, 2, 10) == 2
        before = sockets_in(rt)
        assert set(before) == {"cmd", "telemetry", "frames"}
        second = ritad("--config", str(cfg), timeout=30)
        assert second.returncode == RitadExit.ALREADY_RUNNING, second.stderr
        assert f"pid {first.proc.pid}" in second.stderr and str(rt) in second.stderr
        assert "Traceback" not in second.stderr
        assert sockets_in(rt) == before  # the same socket files: nothing was rebound or removed
        assert health_messages(telemetry, 2, 10) == 2  # a new subscriber still hears the first ritad
        with Client(endpoint, timeout=10) as c:
            assert c.call("hello")["pid"] == first.proc.pid
        stop(first)
        assert sockets_in(rt) == {}  # removed at stop
        # the lock went with the process: the next ritad starts on the same directories
        third = Ritad(tmp_path, cfg)
        try:
            third.wait_notify_ready()
            assert health_messages(telemetry, 1, 10) == 1
            stop(third)
        finally:
            third.kill()
    finally:
        first.kill()


def test_check_config_binds_nothing_and_names_bad_keys(tmp_path: Path) -> None:
    cfg, _ = write_config(tmp_path, tmp_path / "data")
    ok = ritad("--check-config", str(cfg))
    assert ok.returncode == RitadExit.OK and "configuration OK" in ok.stdout, ok.stderr
    assert "devices.camera = 'sim:?size=" in ok.stdout
    assert list((tmp_path / "rt").iterdir()) == [] and not (tmp_path / "data").exists()  # no socket, no lock
    example = ritad("--check-config", str(ROOT / "systemd" / "ritad.toml"))
    from daemon.ritad.config import load
    from daemon.ritad.keycheck import server_key_candidates

    if any(p.exists() for p in server_key_candidates(load(ROOT / "systemd" / "ritad.toml"))):
        assert example.returncode == RitadExit.OK, example.stderr
    else:  # CURVE is on in the example: this machine has no server key, and the check names it
        assert example.returncode == RitadExit.CANNOT_START and "server.key_secret" in example.stderr
    bad = tmp_path / "bad.toml"
    bad.write_text(cfg.read_text().replace('tracker = "sim:"', 'tracker = "usb://0"'))
    for args in (("--check-config", str(bad)), ("--config", str(bad))):  # the same check at a normal start
        res = ritad(*args)
        assert res.returncode == RitadExit.CONFIG
        assert f"{bad}: devices.tracker: unknown scheme 'usb'" in res.stderr and "Traceback" not in res.stderr
    assert list((tmp_path / "rt").iterdir()) == []


def test_check_config_builds_the_adapters_and_names_a_misspelt_url_option(tmp_path: Path) -> None:
    """emscon://...?timout=3 would run with the default 30 s timeout: the check names the option."""
    cfg, _ = write_config(tmp_path, tmp_path / "data")
    bad = tmp_path / "typo.toml"
    bad.write_text(cfg.read_text().replace('tracker = "sim:"', 'tracker = "emscon://127.0.0.1:700?timout=3"'))
    res = ritad("--check-config", str(bad))
    assert res.returncode == RitadExit.CONFIG, res.stderr
    assert (f"{bad}: devices.tracker: tracker URL 'emscon://127.0.0.1:700?timout=3': unknown option 'timout' "
            f"(known: connect_timeout, ") in res.stderr
    assert "Traceback" not in res.stderr and res.stdout == ""
    bad.write_text(bad.read_text().replace("timout", "timeout"))
    ok = ritad("--check-config", str(bad))
    assert ok.returncode == RitadExit.OK, ok.stderr  # builds, connects to nothing
    assert list((tmp_path / "rt").iterdir()) == [] and not (tmp_path / "data").exists()


def test_clean_sigterm_stop_logs_no_warning(tmp_path: Path) -> None:
    cfg, endpoint = write_config(tmp_path, tmp_path / "data")
    cfg.write_text(cfg.read_text().replace("start_worker = false", "start_worker = true"))  # stop it too
    r = Ritad(tmp_path, cfg)
    try:
        r.wait_notify_ready()
        with Client(endpoint, timeout=10) as c:
            c.wait_ready(worker=True)  # devices READY and the worker polling
        stop(r)
    finally:
        r.kill()
    log = (tmp_path / "ritad.log").read_text()
    assert "INFO ritad: stopped" in log
    bad = [line for line in log.splitlines() if any(f" {lvl} " in line for lvl in ("WARNING", "ERROR", "CRITICAL"))
           or "Traceback" in line]
    assert bad == []
    assert sockets_in(tmp_path / "rt") == {}


def test_insecure_tcp_warns_at_every_start(tmp_path: Path) -> None:
    cfg, _ = write_config(tmp_path, tmp_path / "data")
    text = cfg.read_text().replace('command_endpoints = ["ipc://', 'command_endpoints = ["tcp://127.0.0.1:0", "ipc://')
    cfg.write_text(text + "\n[security]\ninsecure_tcp = true\n")
    for _ in range(2):
        r = Ritad(tmp_path, cfg)  # appends to the same ritad.log
        try:
            r.wait_notify_ready()
            stop(r)
        finally:
            r.kill()
    log = (tmp_path / "ritad.log").read_text()
    assert log.count("WARNING ritad: insecure_tcp = true: tcp://127.0.0.1:0 accept any client without CURVE") == 2
