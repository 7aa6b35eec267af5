"""ritad: the acquisition daemon (entry point and supervisor).

Start-up order: load config → lock the runtime and data directories (one instance each) → start
the plugins (the simulator's world) → bind the bus → start the device runners → READY=1. Devices
connect in the background (their state is in ``daemon.health``), so a missing tracker never blocks the bus. The main thread is the supervisor: it publishes health
every second, pings the systemd watchdog only while every owner thread is responsive
(a device waiting to reconnect is), and shuts down on SIGTERM/SIGINT.
"""
from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import tempfile
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import zmq

try:  # the base install is the laptop client; the daemon needs the robot's packages
    import numpy  # noqa: F401
except ModuleNotFoundError as _exc:
    sys.exit(f"ritad: the robot's packages are not installed (no module {_exc.name!r}): "
             f"pip install 'rita[robot]' (docs/operations.md, Install)")

from daemon import __version__  # noqa: E402
from daemon.ritad import config as config_mod, files, plugins  # noqa: E402
from daemon.ritad.calib_jobs import CalibJobs  # noqa: E402
from daemon.ritad.check import RitadExit, check_config, insecure_tcp  # noqa: E402
from daemon.ritad.commands import build_handlers  # noqa: E402
from daemon.ritad.instance import AlreadyRunning, InstanceLock, lock_dirs, remove_socket_files  # noqa: E402
from daemon.ritad.logs import setup_logging  # noqa: E402
from daemon.ritad.notify import Notifier  # noqa: E402
from daemon.bus.protocol import SCHEMA_VERSION  # noqa: E402
from daemon.ritad.publisher import FramePublisher, TelemetryPublisher  # noqa: E402
from daemon.bus import station  # noqa: E402
from daemon.ritad.registry import open_device  # noqa: E402
from daemon.ritad.motion import MotionWaiters  # noqa: E402
from daemon.ritad.runner import DeviceRunner  # noqa: E402
from daemon.ritad.server import CommandServer  # noqa: E402
from daemon.ritad.services import Services  # noqa: E402
from daemon.ritad.stop_latch import LATCH_FILE, StopLatch  # noqa: E402
from daemon.ritad.timelines import Timelines  # noqa: E402
from daemon.ritad.worker_supervisor import WorkerSupervisor  # noqa: E402
from drivers.base import Device, DeviceSettings, Frame, Payload  # noqa: E402
from daemon.bus.names import KINDS, Topic  # noqa: E402

if TYPE_CHECKING:  # imported where used: only a CURVE daemon loads zmq.auth
    from daemon.bus.auth import Security

log = logging.getLogger("ritad")


class Daemon:
    """Everything ritad runs; ``start()`` binds and launches, ``stop()`` tears down."""

    def __init__(self, cfg: config_mod.Config) -> None:
        self.config = cfg
        self.started = time.monotonic()
        self.plugins = plugins.installed()
        self.running = plugins.Running()
        self.device_urls = cfg.device_urls()
        self.abs_H_trk: list[list[float]] = station.IDENTITY
        self.ctx = zmq.Context()
        self.telemetry: TelemetryPublisher
        self.frames: FramePublisher
        self.server: CommandServer
        self.runners: dict[str, DeviceRunner] = {}
        self.security: Security | None = None
        self.storage = ThreadPoolExecutor(max_workers=1, thread_name_prefix="storage")
        self.motions = MotionWaiters(lambda fn: self.job("robot", fn))
        self.timelines = Timelines(lambda kind: self.runners[kind].clock if kind in self.runners else None)
        self.stop_event = threading.Event()
        publish = lambda topic, data: self.telemetry.publish(topic, data)  # noqa: E731 - telemetry starts later
        self.latch = StopLatch(publish, Path(cfg.daemon.data_dir) / LATCH_FILE)  # persists across restarts
        # data_dir lets calib.resume find jobs a previous ritad ran
        self.calib = CalibJobs(publish, data_dir=Path(cfg.daemon.data_dir), latch=self.latch)
        self.worker = WorkerSupervisor(self._worker_cmd, Path(cfg.daemon.data_dir) / "worker.log",
                                       enabled=cfg.daemon.start_worker)

    # ------------------------------------------------------------------ wiring

    def emit(self, topic: str, payload: Payload) -> None:
        """The sink handed to every device (thread-safe, never blocks)."""
        if isinstance(payload, Frame):
            self.frames.publish(self.runners["camera"].clock.stamp_frame(payload))
            return
        if topic == Topic.ROBOT_EVENT:
            self.motions.on_event(payload)
        payload = self.timelines.observe(topic, payload)  # the device clocks and the streams (timelines.py)
        self.telemetry.publish(topic, payload)

    def _factory(self, kind: str) -> Callable[[], Device]:
        url = self.device_urls[kind]
        settings: DeviceSettings = (self.config.camera if kind == "camera"  # the robot's gate: STOP first
                                    else self.latch.gate if kind == "robot" else None)
        return lambda: open_device(kind, url, emit=self.emit, settings=settings)

    def _start_plugins(self, data: Path) -> None:
        """The plugins the config wants (the simulator for sim: URLs), then the tracker station they may install."""
        self.running = plugins.start(self.plugins, self.config.plugins, data, self.device_urls)
        self.device_urls = self.running.urls(self.device_urls)
        self.abs_H_trk, source = station.abs_H_trk(self.config.tracker.abs_H_trk, data)
        log.info("tracker station abs_H_trk from %s", source)

    def start(self) -> None:
        cfg = self.config.daemon
        data = Path(cfg.data_dir)
        data.mkdir(parents=True, exist_ok=True)
        self._start_plugins(data)
        if self.config.security.curve:
            from daemon.bus.auth import Security

            sec = self.config.security
            auth_dir = Path(sec.authorized_keys_dir)
            self.security = Security(data / "keys", auth_dir if auth_dir.is_absolute() else data / auth_dir)
            self.security.start(self.ctx)  # ZAP first: a CURVE server without it accepts any key
        s = self.security
        self.telemetry = TelemetryPublisher(self.ctx, cfg.telemetry_endpoints, hwm=cfg.telemetry_hwm, security=s)
        self.frames = FramePublisher(self.ctx, cfg.frame_endpoints, hwm=cfg.frame_hwm, security=s)
        services = self.services()
        handlers = build_handlers(services, self.running.handlers(services, self.plugins))
        self.server = CommandServer(self.ctx, cfg.command_endpoints, handlers,
                                    cfg.max_message_bytes, security=s,
                                    plain_role=self.config.security.ipc_role,
                                    on_command=lambda d: self.telemetry.publish(Topic.DAEMON_COMMAND, d))
        for t in (self.telemetry, self.frames, self.server):
            t.start()
        self.telemetry.publish(Topic.ROBOT_LATCH, self.latch.snapshot())  # late joiners' snapshot holds it too
        owes_halt = lambda: self.latch.gate.pending  # noqa: E731 - the robot reconnects at once while owed
        for kind in KINDS:
            self.runners[kind] = runner = DeviceRunner(kind, self._factory(kind), self.telemetry.publish,
                                  backoff_min=cfg.reconnect_min_s, backoff_max=cfg.reconnect_max_s,
                                  heartbeat_timeout=cfg.heartbeat_timeout_s, open_timeout=cfg.open_timeout_s,
                                  owes_halt=owes_halt if kind == "robot" else lambda: False)
            runner.start()

    def _worker_cmd(self) -> list[str]:
        ep = next((e for e in self.server.endpoints if e.startswith("ipc://")), self.server.endpoints[0])
        return [sys.executable, "-m", "daemon.worker", "--endpoint", ep, "--parent-pid", str(os.getpid()),
                "--data-dir", str(Path(self.config.daemon.data_dir).resolve())]

    def stop(self) -> None:
        if "robot" in self.runners:  # first: a moving base halts (park) before anything is torn down
            self.runners["robot"].stop()
        self.worker.stop()
        for runner in self.runners.values():
            runner.stop()
        bound: list[str] = []
        for t in (getattr(self, "server", None), getattr(self, "frames", None), getattr(self, "telemetry", None)):
            if t is not None:
                t.stop()
                bound += t.endpoints
        self.storage.shutdown(wait=True)
        self.latch.close()  # after the command server: no STOP can come later
        if self.security is not None:
            self.security.stop()
        self.ctx.term()  # every socket was closed by its owner with LINGER 0
        remove_socket_files(bound)
        self.running.close()  # libzmq leaves them; we hold the directory lock, so they are ours

    # ------------------------------------------------------------------ services for handlers

    def services(self) -> Services:
        """The narrow view bus handlers get of this daemon."""
        cfg = self.config
        data, auth_top = Path(cfg.daemon.data_dir), Path(cfg.security.authorized_keys_dir)
        private = (*files.PRIVATE_DIRS, *(() if auth_top.is_absolute() else auth_top.parts[:1]))
        return Services(job=self.job, motion=self.motions.start, storage=self.storage,
                        data_dir=data, private_dirs=private, auth_dir=data / auth_top, save_capture=self.save_capture,
                        abs_H_trk=self.abs_H_trk, stream_rate_hz=cfg.tracker.stream_rate_hz,
                        robot=cfg.robot, calib=self.calib, stamp_frame=lambda f: self.runners["camera"].clock.stamp_frame(f),
                        device_info=lambda kind: self.runners[kind].info, hello=self.hello, health=self.health,
                        state=self.state, latest_frame=lambda: self.frames.last_frame, latch=self.latch,
                        abort_motions=self.motions.abort, clock_status=lambda kind: self.runners[kind].clock.status(),
                        at_time=self.timelines.at)

    def state(self) -> dict[str, Any]:
        """Clone snapshot for late joiners, with the devices' states."""
        return {**self.telemetry.snapshot(), "devices": {k: r.snapshot() for k, r in self.runners.items()},
                "latch": self.latch.snapshot()}

    def job(self, kind: str, fn: Callable[[Any], Any], *, timeout: float = 60.0) -> Future:
        return self.runners[kind].submit(fn, timeout=timeout)

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
                "devices": {k: getattr(self.config.devices, k) for k in KINDS},
                "curve_server_key": None if self.security is None else self.security.public.decode(),
                **self.running.hello()}

    @property
    def simulated(self) -> bool:
        """A plugin simulates a device (its hello says so): datasets and hello carry it."""
        return bool(self.running.hello().get("sim"))

    def health(self) -> dict[str, Any]:
        return {"uptime_s": round(time.monotonic() - self.started, 3), "version": __version__,
                "devices": {k: r.snapshot() for k, r in self.runners.items()},
                "telemetry": self.telemetry.counters(), "frames": self.frames.counters(),
                "commands": {"requests": self.server.requests, "errors": self.server.errors,
                             "pending": self.server.pending},
                "worker": {"pid": self.worker.pid, "seen_s_ago": self.calib.worker_age()},
                "latch": self.latch.snapshot(), "alive": self.alive()}

    def alive(self) -> bool:
        now = time.monotonic()
        threads_ok = all(now - t.heartbeat < 5.0 and t.is_alive() for t in (self.server, self.telemetry, self.frames))
        return threads_ok and all(r.alive() for r in self.runners.values())

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


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="ritad", description="Rita acquisition daemon",
                                 epilog="exit codes: 0 ok, 1 cannot start, 2 configuration or usage error, "
                                        "3 another ritad runs in the same runtime or data directory")
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--config", help="TOML config file (see systemd/ritad.toml)")
    src.add_argument("--sim", action="store_true", help="run on the simulated world (built-in config)")
    src.add_argument("--check-config", metavar="FILE",
                     help="validate FILE (keys, values, endpoints, device URLs and their options) and exit; binds "
                          "nothing, opens no device, safe beside a running ritad")
    ap.add_argument("--runtime-dir", help="--sim: directory for the ipc endpoints (default: a temp dir)")
    ap.add_argument("--data-dir", help="override daemon.data_dir")
    ap.add_argument("--seed", type=int, default=1, help="--sim: world seed")
    ap.add_argument("--profile", help="--sim: error profile of the simulated world (ideal, paper, paper+imu; "
                                      "default ideal); with --config use [sim] profile")
    ap.add_argument("--log-level", type=str.upper, choices=("DEBUG", "INFO", "WARNING", "ERROR"),
                    help="override daemon.log_level")
    ap.add_argument("--version", action="version", version=f"ritad {__version__}")
    args = ap.parse_args(argv)
    if args.profile is not None and not args.sim:
        ap.error("--profile applies to --sim only; with --config set [sim] profile")  # exit 2
    return args


def load_config(args: argparse.Namespace) -> config_mod.Config:
    if args.sim:
        runtime = args.runtime_dir or os.environ.get("RITA_RUNTIME_DIR") or tempfile.mkdtemp(prefix="ritad-sim-")
        return config_mod.sim_config(runtime, args.data_dir, seed=args.seed, profile=args.profile or "ideal")
    cfg = config_mod.load(args.config or args.check_config)
    if args.data_dir:
        cfg.daemon.data_dir = args.data_dir
    return cfg


def serve(daemon: Daemon, notifier: Notifier) -> int:
    """Bind, run until SIGTERM/SIGINT, tear down."""
    try:
        daemon.start()
    except station.StationError as exc:  # a surveyed pose that is not one: fix the file, a restart won't
        log.error("cannot start: %s", exc)
        daemon.stop()
        return RitadExit.CONFIG
    except (zmq.ZMQError, OSError, ValueError) as exc:
        log.error("cannot start: %s", exc)  # on stderr (the journal) once: logging writes there
        d = daemon.config.daemon
        remove_socket_files(d.command_endpoints + d.telemetry_endpoints + d.frame_endpoints)  # ours: we hold the lock
        return RitadExit.CANNOT_START
    from daemon.ritad.logs import BusLogHandler

    logging.getLogger().addHandler(BusLogHandler(daemon.telemetry.publish))
    for sig in (signal.SIGTERM, signal.SIGINT):
        # set the event from another thread: Event.set() in a handler that interrupts the main
        # thread's own Event.wait() would deadlock on the Event's (non-reentrant) lock
        signal.signal(sig, lambda *_: threading.Thread(target=daemon.stop_event.set, daemon=True).start())
    eps = daemon.server.endpoints
    log.info("ritad %s ready: commands on %s (config %s)", __version__, ", ".join(eps), daemon.config.source)
    print(f"ritad ready: {' '.join(eps)}", flush=True)
    notifier.ready(f"bus on {eps[0]}")
    try:
        daemon.supervise(notifier)
    finally:
        notifier.stopping()
        log.info("stopping")
        daemon.stop()
        notifier.close()
    log.info("stopped")
    return RitadExit.OK


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        cfg = load_config(args)
    except config_mod.ConfigError as exc:
        print(f"ritad: configuration error: {exc}", file=sys.stderr)
        return RitadExit.CONFIG
    if args.check_config:
        return check_config(cfg)
    setup_logging(args.log_level or cfg.daemon.log_level)
    lock = InstanceLock(lock_dirs(cfg))
    try:
        lock.acquire()  # before anything binds: a second ritad must not take the first one's ipc sockets
    except AlreadyRunning as exc:
        log.error("not started: %s", exc)
        return RitadExit.ALREADY_RUNNING
    except OSError as exc:
        log.error("cannot start: lock: %s", exc)
        return RitadExit.CANNOT_START
    if insecure := insecure_tcp(cfg):
        log.warning("insecure_tcp = true: %s accept any client without CURVE; anyone who reaches these ports "
                    "can move the robot (docs/operations.md, Keys)", ", ".join(insecure))
    try:
        return serve(Daemon(cfg), Notifier())
    finally:
        lock.release()


if __name__ == "__main__":
    sys.exit(main())
