"""ritad's command line: ``python -m daemon.ritad.main`` (the ``ritad`` script).

Start-up order: load config → lock the runtime and data directories (one instance each) → build the
daemon (the plugins, the bus bound, the devices' rigs: daemon/ritad/daemon.py) → start its threads
→ READY=1. The main thread then supervises until SIGTERM/SIGINT. Exit codes are ``RitadExit``.
"""
from __future__ import annotations

import argparse
import logging
import os
import signal
import sys
import tempfile
import threading

import zmq

try:  # the base install is the laptop client; the daemon needs the robot's packages
    import numpy  # noqa: F401
except ModuleNotFoundError as _exc:
    sys.exit(f"ritad: the robot's packages are not installed (no module {_exc.name!r}): "
             f"pip install 'rita[robot]' (docs/operations.md, Install)")

from daemon import __version__  # noqa: E402
from daemon.bus import station  # noqa: E402
from daemon.ritad import config as config_mod  # noqa: E402
from daemon.ritad.check import RitadExit, check_config, insecure_tcp  # noqa: E402
from daemon.ritad.daemon import Daemon  # noqa: E402
from daemon.ritad.instance import AlreadyRunning, InstanceLock, lock_dirs, remove_socket_files  # noqa: E402
from daemon.ritad.logs import setup_logging  # noqa: E402
from daemon.ritad.notify import Notifier  # noqa: E402

log = logging.getLogger("ritad")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="ritad", description="Rita acquisition daemon",
                                 epilog="exit codes: 0 ok, 1 cannot start, 2 configuration or usage error, "
                                        "3 another ritad runs in the same runtime or data directory")
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--config", help="TOML config file (see systemd/ritad.toml)")
    src.add_argument("--sim", action="store_true", help="run on the simulated world (built-in config)")
    src.add_argument("--check-config", metavar="FILE",
                     help="validate FILE (keys, values, endpoints, device URLs and their options) and exit; "
                          "binds nothing, opens no device, safe beside a running ritad")
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
        runtime = (args.runtime_dir or os.environ.get("RITA_RUNTIME_DIR")
                   or tempfile.mkdtemp(prefix="ritad-sim-"))
        return config_mod.sim_config(runtime, args.data_dir, seed=args.seed, profile=args.profile or "ideal")
    cfg = config_mod.load(args.config or args.check_config)
    if args.data_dir:
        cfg.daemon.data_dir = args.data_dir
    return cfg


def serve(cfg: config_mod.Config, notifier: Notifier) -> int:
    """Build and bind, run until SIGTERM/SIGINT, tear down."""
    try:
        daemon = Daemon(cfg)
    except station.StationError as exc:  # a surveyed pose that is not one: fix the file, a restart won't
        log.error("cannot start: %s", exc)
        return RitadExit.CONFIG
    except (zmq.ZMQError, OSError, ValueError) as exc:
        log.error("cannot start: %s", exc)  # on stderr (the journal) once: logging writes there
        d = cfg.daemon
        # ours: we hold the lock
        remove_socket_files(d.command_endpoints + d.telemetry_endpoints + d.frame_endpoints)
        return RitadExit.CANNOT_START
    daemon.start()
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
        return serve(cfg, Notifier())
    finally:
        lock.release()


if __name__ == "__main__":
    sys.exit(main())
