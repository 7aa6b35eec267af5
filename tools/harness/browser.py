"""The console's browser harness: tests/console, bench/bench_console.py and tools/console_screenshots.py.

One simulated ritad (ipc for the local operator and the worker, CURVE tcp for a viewer
key), ``ritactl console`` as a real process on port 0, and Debian's headless chromium
driven by selenium through chromium-driver. Every wait has a timeout.
"""
from __future__ import annotations

import contextlib
import os
import select
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Callable, Iterator

from daemon.bus import roles
from daemon.bus.auth import create_keypair, load_public
from fakes.launch import RitadProcess, start_ritad
from tools.harness.config import ritad_toml

ROOT = Path(__file__).resolve().parents[2]
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"


def robot_config(camera: str = "sim:", worker: bool = True) -> str:
    """The console's robot: ipc for the local operator and the worker, CURVE tcp for laptop keys."""
    return ritad_toml(tcp=True, devices={"camera": camera}, worker=worker, seed=3, curve=True)


def browser_available() -> str | None:
    """Why the browser tests cannot run here, or None."""
    for exe in (CHROMIUM, CHROMEDRIVER):
        if not os.access(exe, os.X_OK):
            return f"{exe} is missing (apt install chromium chromium-driver; .ci/run does)"
    try:
        import selenium  # noqa: F401
        import aiohttp  # noqa: F401
    except ImportError as exc:
        return f"{exc.name} is missing (pip install -e '.[test]')"
    return None


def start_robot(tmp: Path, camera: str = "sim:", worker: bool = True,
                keys: dict[str, str] | None = None) -> tuple[RitadProcess, Path]:
    """ritad on the fakes with CURVE on tcp; client keys (default: viewer ``vic``) in ``tmp/laptop``."""
    data, laptop = tmp / "data", tmp / "laptop"
    create_keypair(data / "keys", "server")
    for name, role in (keys or {"vic": "viewer"}).items():
        public, _ = create_keypair(laptop, name)
        roles.write_entry(data / "authorized_keys", name, load_public(public), role)
    (laptop / "server.key").write_bytes((data / "keys" / "server.key").read_bytes())
    r = start_ritad(robot_config(camera, worker), tmp=tmp, timeout=90)
    try:
        r.wait_ready(timeout=90, worker=worker)
    except BaseException:
        r.stop()
        raise
    return r, laptop


class ConsoleProcess:
    """``ritactl ARGS console --port PORT`` as a process; ``url`` from its first line."""

    def __init__(self, args: list[str], tmp: Path, timeout: float = 30.0, port: int = 0,
                 token: str | None = None) -> None:
        tmp.mkdir(parents=True, exist_ok=True)
        env = {**os.environ, "PYTHONPATH": str(ROOT), "RITA_CONFIG": str(tmp / "none.toml")}
        (tmp / "none.toml").write_text("")
        self.log = tmp / "console.log"
        with open(self.log, "ab") as log:
            more = ["--token", token] if token else []
            self.proc = subprocess.Popen([sys.executable, "-m", "daemon.ctl.main", *args, "console",
                                          "--port", str(port), "--captures", str(tmp / "captures"), *more],
                                         cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=log, text=True)
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        line = self.proc.stdout.readline() if ready else ""
        if "http://" not in line:
            self.stop()
            raise RuntimeError(f"ritactl console did not start within {timeout:g} s: {line!r} "
                               f"{self.log.read_text(errors='replace')[-2000:]}")
        self.url = line[line.index("http://"):].split()[0]  # the page, with this launch's ?token=
        self.base, self.token = self.url.split("?token=")

    def at(self, path: str) -> str:
        """``path`` on this console with the token (as the page's links get it from their cookie)."""
        return f"{self.base}{path}{'&' if '?' in path else '?'}token={self.token}"

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        if self.proc.stdout:
            self.proc.stdout.close()


def browser(width: int = 1400, height: int = 1100) -> Any:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                f"--window-size={width},{height}", "--disable-extensions", "--no-first-run"):
        opts.add_argument(arg)
    d = webdriver.Chrome(service=Service(CHROMEDRIVER), options=opts)
    d.set_page_load_timeout(30)
    d.set_script_timeout(30)
    return d


def wait_for(what: str, fn: Callable[[], Any], timeout: float, poll: float = 0.1) -> Any:
    """Poll ``fn`` until it returns something truthy; AssertionError naming ``what`` after ``timeout`` s."""
    end = time.monotonic() + timeout
    last: Any = None
    while time.monotonic() < end:
        try:
            last = fn()
        except Exception as exc:  # noqa: BLE001 - a stale element or a page still loading: try again
            last = exc
        else:
            if last:
                return last
        time.sleep(poll)
    raise AssertionError(f"{what}: not within {timeout:g} s (last: {last!r})")


@contextlib.contextmanager
def console_session(args: list[str], tmp: Path) -> Iterator[tuple[ConsoleProcess, Any]]:
    """A console process and a browser on its page, page connected (role known)."""
    con = ConsoleProcess(args, tmp)
    drv = None
    try:
        drv = browser()
        drv.get(con.url)
        wait_for("the page knows its role",
                 lambda: drv.execute_script("return window.rita.role") != "unknown", 20)
        yield con, drv
    finally:
        if drv is not None:
            drv.quit()
        con.stop()


__all__ = ["ConsoleProcess", "browser", "browser_available", "console_session", "robot_config", "start_robot",
           "wait_for"]
