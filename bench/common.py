"""Shared helpers for the benchmark scripts: machine facts, percentiles, a ritad process."""
from __future__ import annotations

import os
import platform
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def machine() -> str:
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, "
            f"{platform.system()} {platform.release()}, {time.strftime('%Y-%m-%d', time.gmtime())}")


def pct(values: list[float], q: float) -> float:
    v = sorted(values)
    return v[min(len(v) - 1, int(round(q / 100 * (len(v) - 1))))] if v else float("nan")


def start_ritad(config_text: str | None = None, notify: bool = True, extra: list[str] | None = None,
                timeout: float = 60) -> tuple[subprocess.Popen, str, float, Path]:
    """Start ritad (sim, or with ``config_text``); return (proc, command endpoint, seconds to READY, tmp)."""
    tmp = Path(tempfile.mkdtemp(prefix="rita-bench-"))
    sock_path = tmp / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(sock_path))
    sock.settimeout(0.05)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NOTIFY_SOCKET": str(sock_path)}
    if config_text is None:
        args = ["--sim", "--runtime-dir", str(tmp / "rt"), "--data-dir", str(tmp / "data")]
    else:
        (tmp / "ritad.toml").write_text(config_text.replace("@TMP@", str(tmp)))
        args = ["--config", str(tmp / "ritad.toml")]
    t0 = time.monotonic()
    proc = subprocess.Popen([sys.executable, "-m", "daemon.ritad.main", *args, *(extra or [])], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=open(tmp / "ritad.log", "w"), text=True)
    ready = None
    while time.monotonic() - t0 < timeout:
        try:
            if b"READY=1" in sock.recv(4096):
                ready = time.monotonic() - t0
                break
        except socket.timeout:
            if proc.poll() is not None:
                raise RuntimeError(f"ritad exited: {(tmp / 'ritad.log').read_text()[-2000:]}") from None
    sock.close()
    if ready is None:
        proc.kill()
        raise RuntimeError("ritad never sent READY=1")
    line = proc.stdout.readline().strip()  # "ritad ready: <endpoints>"
    endpoint = line.split(": ", 1)[1].split()[0]
    return proc, endpoint, ready, tmp


def stop_ritad(proc: subprocess.Popen) -> None:
    import signal

    proc.send_signal(signal.SIGTERM)
    try:
        proc.wait(10)
    except subprocess.TimeoutExpired:
        proc.kill()
