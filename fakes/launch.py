"""Start ``ritad`` as a process on the fakes: the one helper tests, benchmarks and the demo share.

``start_ritad()`` runs ``python -m daemon.ritad.main`` (``--sim`` or a config text) with a
private ``NOTIFY_SOCKET``, waits for ``READY=1`` (the bus is bound) and reads the
endpoints from its "ritad ready:" line; ``RitadProcess.wait_ready()`` then waits until the
devices are READY through :meth:`daemon.bus.client.Client.wait_ready`, the bus library's
single definition of READY. Everything stays in one temp dir; ``stop()`` sends SIGTERM
(ritad stops its worker) and kills only after a bounded wait.
"""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, Iterable

from daemon.bus.client import Client

ROOT = Path(__file__).resolve().parents[1]


class RitadProcess:
    """A running ritad: ``proc``, its command ``endpoint``, its ``tmp`` dir and notify messages."""

    def __init__(self, proc: subprocess.Popen, tmp: Path, sock: socket.socket) -> None:
        self.proc, self.tmp, self.sock = proc, tmp, sock
        self.messages: list[str] = []
        self.endpoint = ""
        self.endpoints: list[str] = []
        self.ready_s = float("nan")  #: seconds from start to READY=1
        self.started = time.monotonic()

    @property
    def log(self) -> Path:
        return self.tmp / "ritad.log"

    def log_tail(self, n: int = 3000) -> str:
        return self.log.read_text(errors="replace")[-n:] if self.log.exists() else ""

    def recv(self, duration: float) -> list[str]:
        """Notify datagrams received within ``duration`` s (also kept in ``messages``)."""
        got: list[str] = []
        end = time.monotonic() + duration
        while time.monotonic() < end:
            try:
                got.append(self.sock.recv(4096).decode())
            except socket.timeout:
                continue
        self.messages += got
        return got

    def wait_notify_ready(self, timeout: float = 60.0) -> None:
        """Wait for READY=1, then read the "ritad ready: <endpoints>" line from stdout."""
        t0 = self.started
        end = t0 + timeout
        while not any("READY=1" in m for m in self.messages):
            if self.proc.poll() is not None:
                raise RuntimeError(f"ritad exited with {self.proc.returncode}: {self.log_tail()}")
            if time.monotonic() > end:
                raise RuntimeError(f"ritad sent no READY=1 within {timeout:g} s: {self.log_tail()}")
            self.recv(0.05)
        self.ready_s = time.monotonic() - t0
        line = self.proc.stdout.readline().strip() if self.proc.stdout else ""
        if not line.startswith("ritad ready:"):
            raise RuntimeError(f"unexpected first line from ritad {line!r}: {self.log_tail()}")
        self.endpoints = line.split(": ", 1)[1].split()
        self.endpoint = self.endpoints[0]

    def client(self, timeout: float = 10.0, endpoint: str | None = None, **kw: Any) -> Client:
        return Client(endpoint or self.endpoint, timeout=timeout, **kw)

    def wait_ready(self, devices: Iterable[str] | None = None, timeout: float = 90.0,
                   worker: bool = False) -> dict[str, Any]:
        """Devices READY (and the worker seen, with ``worker``); returns ``status``."""
        with self.client() as c:
            return c.wait_ready(devices, timeout, worker=worker, alive=lambda: self.proc.poll() is None)

    def kill(self) -> None:
        """SIGKILL (a crash, for fault tests) and release the notify socket."""
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(10)
        self.stop()

    def stop(self, timeout: float = 10.0) -> int:
        """SIGTERM, then kill after ``timeout`` s; returns the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout)
        self.sock.close()
        if self.proc.stdout:
            self.proc.stdout.close()
        return self.proc.returncode

    def __enter__(self) -> "RitadProcess":
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def spawn_ritad(args: Iterable[str], *, tmp: Path, env: dict[str, str] | None = None) -> RitadProcess:
    """Run ``ritad ARGS`` with a private NOTIFY_SOCKET in ``tmp``; returns at once (no wait).

    ``env`` adds to the environment (e.g. ``WATCHDOG_USEC``); stderr goes to ``tmp/ritad.log``.
    """
    tmp.mkdir(parents=True, exist_ok=True)
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock_path = tmp / f"notify-{time.monotonic_ns()}.sock"
    sock.bind(str(sock_path))
    sock.settimeout(0.05)
    full_env = {**os.environ, "PYTHONPATH": str(ROOT), "NOTIFY_SOCKET": str(sock_path)}
    full_env.pop("WATCHDOG_PID", None)
    full_env.pop("WATCHDOG_USEC", None)
    full_env.update(env or {})
    t0 = time.monotonic()
    with open(tmp / "ritad.log", "ab") as log:  # the child keeps its own copy of the descriptor
        proc = subprocess.Popen([sys.executable, "-m", "daemon.ritad.main", *args], cwd=ROOT,
                                env=full_env, stdout=subprocess.PIPE, stderr=log, text=True)
    ritad = RitadProcess(proc, tmp, sock)
    ritad.started = t0
    return ritad


def start_ritad(config_text: str | None = None, *, tmp: Path | None = None, args: Iterable[str] = (),
                env: dict[str, str] | None = None, timeout: float = 60.0,
                keep_notify: bool = False) -> RitadProcess:
    """Start ritad and wait for READY=1 (bus bound; devices may still connect).

    Without ``config_text`` it runs ``--sim`` with its runtime and data dirs in ``tmp``;
    else ``config_text`` (``@TMP@`` replaced by ``tmp``) is written to ``tmp/ritad.toml``.
    Stops ritad on failure. The notify socket is closed after READY=1 unless
    ``keep_notify``: ritad's notify datagrams block once an unread socket's queue is
    full, which would stall its supervisor.
    """
    tmp = Path(tmp or tempfile.mkdtemp(prefix="ritad-fakes-"))
    if config_text is None:
        where = ["--sim", "--runtime-dir", str(tmp / "rt"), "--data-dir", str(tmp / "data")]
    else:
        tmp.mkdir(parents=True, exist_ok=True)
        (tmp / "ritad.toml").write_text(config_text.replace("@TMP@", str(tmp)))
        where = ["--config", str(tmp / "ritad.toml")]
    ritad = spawn_ritad([*where, *args], tmp=tmp, env=env)
    try:
        ritad.wait_notify_ready(timeout)
    except BaseException:
        ritad.stop()
        raise
    if not keep_notify:
        ritad.sock.close()  # ritad's sends now fail at once (ECONNREFUSED), which it ignores
    return ritad


__all__ = ["RitadProcess", "spawn_ritad", "start_ritad"]
