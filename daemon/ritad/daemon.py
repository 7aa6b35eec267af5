"""ritad's daemon: everything it runs, built in ``Daemon(config)`` and torn down by ``stop()``.

Build order: the plugins (the simulator's world), the tracker station they may install, the bus's
sockets (bound here: a port in use fails the build, not a later start), the stop latch and the
calibration mailbox, then one rig per device kind (daemon/ritad/rigs.py) and the handlers, each
given only what it uses. ``start()`` starts the owner threads; devices connect in the background
(their state is in ``daemon.health``), so a missing tracker never blocks the bus. The main thread
is the supervisor: it publishes health every second and pings the systemd watchdog only while every
owner thread is responsive (a device waiting to reconnect is). The CLI is daemon/ritad/main.py.
"""
from __future__ import annotations

import contextlib
import functools
import logging
import os
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any

import zmq

from daemon import __version__
from daemon.bus import station
from daemon.bus.command_table import CommandTable
from daemon.bus.names import KINDS, Topic
from daemon.bus.protocol import SCHEMA_VERSION
from daemon.ritad import config as config_mod, files, plugins
from daemon.ritad.calib_jobs import CalibJobs
from daemon.ritad.commands import build_handlers
from daemon.ritad.instance import remove_socket_files
from daemon.ritad.notify import Notifier
from daemon.ritad.publisher import FramePublisher, TelemetryPublisher
from daemon.ritad.rigs import CameraRig, Rig, Rigs, RobotRig, TrackerRig
from daemon.ritad.server import CommandServer, Handler
from daemon.ritad.services import Reports, Services
from daemon.ritad.stop_latch import LATCH_FILE, StopLatch
from daemon.ritad.timelines import Timelines
from daemon.ritad.timeouts import Timeouts
from daemon.ritad.worker_supervisor import WorkerSupervisor

if TYPE_CHECKING:  # imported where used: only a CURVE daemon loads zmq.auth
    from daemon.bus.auth import Security

log = logging.getLogger("ritad")


class Daemon:
    """Everything ritad runs: built (and bound) here, ``start()`` launches the threads, ``stop()`` tears down.

    A build that fails (a port in use, a bad station file) undoes what it built and raises."""

    def __init__(self, cfg: config_mod.Config) -> None:
        self.config = cfg
        self.started = time.monotonic()
        data = Path(cfg.daemon.data_dir)
        data.mkdir(parents=True, exist_ok=True)
        self.table = CommandTable()  # the product's commands and, next, the installed plugins'
        self.plugins = plugins.installed(self.table)
        self.ctx = zmq.Context()
        self.storage = ThreadPoolExecutor(max_workers=1, thread_name_prefix="storage")
        self.timeouts = Timeouts()
        self.stop_event = threading.Event()
        with contextlib.ExitStack() as undo:  # a failed build closes what it opened, in reverse
            undo.callback(self.ctx.term)
            undo.callback(self.storage.shutdown)
            self.running = plugins.start(self.plugins, cfg.plugins, data, self._urls())
            undo.callback(self.running.close)
            self.abs_H_trk, source = station.abs_H_trk(cfg.tracker.abs_H_trk, data)
            log.info("tracker station abs_H_trk from %s", source)
            self.security = self._security(data)
            if self.security is not None:
                undo.callback(self.security.stop)
            self._bind(undo)
            undo.pop_all()  # built: stop() tears it down from here

    def _security(self, data: Path) -> Security | None:
        """CURVE's authenticator, started first: a CURVE server without it accepts any key."""
        if not self.config.security.curve:
            return None
        from daemon.bus.auth import Security

        sec = self.config.security
        auth_dir = Path(sec.authorized_keys_dir)
        security = Security(data / "keys", auth_dir if auth_dir.is_absolute() else data / auth_dir)
        security.start(self.ctx)
        return security

    def _bind(self, undo: contextlib.ExitStack) -> None:
        """The publishers, what handlers use, the devices' rigs and the command server."""
        cfg, s = self.config.daemon, self.security
        self.telemetry = TelemetryPublisher(self.ctx, cfg.telemetry_endpoints, hwm=cfg.telemetry_hwm,
                                            security=s)
        undo.callback(self.telemetry.stop)
        self.frames = FramePublisher(self.ctx, cfg.frame_endpoints, hwm=cfg.frame_hwm, security=s)
        undo.callback(self.frames.stop)
        data = Path(cfg.data_dir)
        self.latch = StopLatch(self.telemetry.publish, data / LATCH_FILE)  # persists across restarts
        undo.callback(self.latch.close)
        # data_dir lets calib.resume find jobs a previous ritad ran
        self.calib = CalibJobs(self.telemetry.publish, data_dir=data, latch=self.latch,
                               timeouts=self.timeouts)
        self.timelines = Timelines()
        self.rigs = self._rigs(self.running.urls(self._urls()))
        services = self._services()
        handlers = build_handlers(services, self.rigs, Reports(self.hello, self.health, self.state),
                                  self.timelines, self._plugin_handlers(services))
        audit = functools.partial(self.telemetry.publish, Topic.DAEMON_COMMAND)
        self.server = CommandServer(self.ctx, cfg.command_endpoints, handlers, cfg.max_message_bytes,
                                    security=s, plain_role=self.config.security.ipc_role, table=self.table,
                                    on_command=audit)
        undo.callback(self.server.stop)
        self.worker = WorkerSupervisor(self._worker_cmd, data / "worker.log", enabled=cfg.start_worker)

    def _urls(self) -> dict[str, str]:
        """Every device's URL: the product's three, and those of the device kinds plugins declare."""
        sections = self.config.plugins
        more = {name: sections.get(name, {}).get("url") for name in plugins.device_kinds(self.plugins)}
        return {**self.config.device_urls(), **{name: url for name, url in more.items() if url}}

    def _rigs(self, urls: dict[str, str]) -> Rigs:
        cfg, publish, timelines = self.config, self.telemetry.publish, self.timelines
        more = {kind: Rig(kind, url, publish, timelines, cfg.daemon) for kind, url in urls.items()
                if kind not in KINDS}
        return Rigs(camera=CameraRig(urls["camera"], publish, self.frames, timelines, cfg.daemon, cfg.camera),
                    tracker=TrackerRig(urls["tracker"], publish, timelines, cfg.daemon, cfg.tracker,
                                       self.abs_H_trk),
                    robot=RobotRig(urls["robot"], publish, timelines, cfg.daemon, cfg.robot, self.latch,
                                   self.timeouts), more=more)

    def _plugin_handlers(self, services: Services) -> dict[str, Handler]:
        """The plugins' commands: a session's handlers, a device kind's given its rig, else not_found."""
        out = self.running.handlers(services, self.plugins)
        for name, kind in plugins.device_kinds(self.plugins).items():
            if name in self.rigs.more:
                out.update(kind.device_handlers(self.rigs.more[name], services))
        return out

    def _services(self) -> Services:
        """The narrow view every handler group shares of this daemon."""
        cfg = self.config
        data, auth_top = Path(cfg.daemon.data_dir), Path(cfg.security.authorized_keys_dir)
        private = (*files.PRIVATE_DIRS, *(() if auth_top.is_absolute() else auth_top.parts[:1]))
        return Services(storage=self.storage, data_dir=data, private_dirs=private, auth_dir=data / auth_top,
                        save_capture=self.save_capture, calib=self.calib, latch=self.latch,
                        device_info=self.rigs.info, table=self.table)

    def start(self) -> None:
        """Start every owner thread: the bus first, then the devices."""
        for t in (self.telemetry, self.frames, self.server):
            t.start()
        # late joiners' snapshot holds it too
        self.telemetry.publish(Topic.ROBOT_LATCH, self.latch.snapshot())
        for rig in self.rigs:
            rig.runner.start()

    def _worker_cmd(self) -> list[str]:
        ep = next((e for e in self.server.endpoints if e.startswith("ipc://")), self.server.endpoints[0])
        return [sys.executable, "-m", "daemon.worker", "--endpoint", ep, "--parent-pid", str(os.getpid()),
                "--data-dir", str(Path(self.config.daemon.data_dir).resolve())]

    def stop(self) -> None:
        self.rigs.robot.runner.stop()  # first: a moving base halts (park) before anything is torn down
        self.worker.stop()
        for rig in self.rigs:
            rig.runner.stop()
        bound: list[str] = []
        for t in (self.server, self.frames, self.telemetry):
            t.stop()
            bound += t.endpoints
        self.timeouts.stop()  # nothing is left to wait for what is not due
        self.storage.shutdown(wait=True)
        self.latch.close()  # after the command server: no STOP can come later
        if self.security is not None:
            self.security.stop()
        self.ctx.term()  # every socket was closed by its owner with LINGER 0
        remove_socket_files(bound)
        self.running.close()  # libzmq leaves them; we hold the directory lock, so they are ours

    # ------------------------------------------------------------------ the daemon's reports

    def state(self) -> dict[str, Any]:
        """Clone snapshot for late joiners, with the devices' states."""
        return {**self.telemetry.snapshot(), "devices": self._devices(), "latch": self.latch.snapshot()}

    def _devices(self) -> dict[str, dict[str, Any]]:
        return {rig.kind: rig.runner.snapshot() for rig in self.rigs}

    def save_capture(self, parts: dict[str, Any], label: str, dataset: str | None = None) -> Path:
        """Store a capture (called in the storage thread, never in a device or bus thread)."""
        from daemon.bus.storage import save_capture

        return save_capture(Path(self.config.daemon.data_dir), parts, label, dataset,
                            meta={"daemon_version": __version__, "sim": self.simulated,
                                  "abs_H_trk": self.abs_H_trk})

    def hello(self) -> dict[str, Any]:
        return {"name": "ritad", "version": __version__, "schema": SCHEMA_VERSION, "pid": os.getpid(),
                "sim": self.simulated, "command_endpoints": self.server.endpoints,
                "telemetry_endpoints": self.telemetry.endpoints, "frame_endpoints": self.frames.endpoints,
                "devices": self._urls(),  # as configured (a plugin may have rewritten what the rigs open)
                "curve_server_key": None if self.security is None else self.security.public.decode(),
                **self.running.hello()}

    @property
    def simulated(self) -> bool:
        """A plugin simulates a device (its hello says so): datasets and hello carry it."""
        return bool(self.running.hello().get("sim"))

    def health(self) -> dict[str, Any]:
        return {"uptime_s": round(time.monotonic() - self.started, 3), "version": __version__,
                "devices": self._devices(),
                "telemetry": self.telemetry.counters(), "frames": self.frames.counters(),
                "commands": {"requests": self.server.requests, "errors": self.server.errors,
                             "pending": self.server.pending},
                "worker": {"pid": self.worker.pid, "seen_s_ago": self.calib.worker_age()},
                "latch": self.latch.snapshot(), "alive": self.alive()}

    def alive(self) -> bool:
        now = time.monotonic()
        threads_ok = all(now - t.heartbeat < 5.0 and t.is_alive()
                         for t in (self.server, self.telemetry, self.frames))
        return threads_ok and all(rig.runner.alive() for rig in self.rigs)

    # ------------------------------------------------------------------ supervisor

    def supervise(self, notifier: Notifier) -> None:
        interval = self.config.daemon.health_interval_s
        wd = notifier.watchdog_interval
        next_health = next_wd = time.monotonic()
        last_status = ""
        while not self.stop_event.is_set():
            now = time.monotonic()
            if now >= next_health:
                self.worker.tend()
                h = self.health()
                self.telemetry.publish(Topic.DAEMON_HEALTH, h)
                status = ", ".join(f"{k} {v['state']}" for k, v in h["devices"].items())
                if status != last_status:
                    notifier.status(status)
                    last_status = status
                next_health = now + interval
            if wd is not None and now >= next_wd:
                if self.alive():  # a hung owner thread stops the pings, so systemd restarts us
                    notifier.watchdog()
                else:
                    log.error("watchdog withheld: an owner thread is not responding")
                next_wd = now + wd
            self.stop_event.wait(min(0.1, interval))


