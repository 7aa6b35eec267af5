"""``ritad --check-config`` and ritad's exit codes: what a start with a config file would find, without
binding anything or opening a device (safe beside a running ritad)."""
from __future__ import annotations

import enum
import sys
from pathlib import Path

from daemon.bus import station
from daemon.bus.names import KINDS
from daemon.ritad import config as config_mod


class RitadExit(enum.IntEnum):
    """ritad's exit codes (docs/operations.md, "Exit codes (ritad)")."""

    OK = 0  #: clean stop, or --check-config found the file valid
    CANNOT_START = 1  #: a bind or the server key failed at start
    CONFIG = 2  #: bad configuration (the message names the file and key); not worth a restart
    ALREADY_RUNNING = 3  #: another ritad holds the runtime or data directory lock


def check_config(cfg: config_mod.Config) -> int:
    """``--check-config``: the file passed every check ritad makes before it binds, each device's
    adapter accepts its URL; the key files exist."""
    from daemon.ritad.keycheck import key_problems

    try:
        device_warnings = config_mod.check_devices(cfg)
    except config_mod.ConfigError as exc:
        print(f"ritad: configuration error: {exc}", file=sys.stderr)
        return RitadExit.CONFIG
    errors, warnings = key_problems(cfg)
    try:
        _, where = station.abs_H_trk(cfg.tracker.abs_H_trk, Path(cfg.daemon.data_dir))
    except station.StationError as exc:
        print(f"ritad: {exc}", file=sys.stderr)
        return RitadExit.CONFIG
    warnings = device_warnings + warnings
    for e in errors:
        print(f"ritad: {cfg.source}: {e}", file=sys.stderr)
    if errors:
        return RitadExit.CANNOT_START  # what a start with this file would exit with
    d = cfg.daemon
    print(f"ritad: {cfg.source}: configuration OK")
    for key in ("command_endpoints", "telemetry_endpoints", "frame_endpoints"):
        print(f"  daemon.{key} = {getattr(d, key)}")
    for kind in KINDS:
        print(f"  devices.{kind} = {getattr(cfg.devices, kind)!r}")
    print(f"  data_dir = {d.data_dir}, start_worker = {d.start_worker}, curve = {cfg.security.curve}")
    if cfg.plugins:
        print(f"  plugin sections: {', '.join(f'[{n}]' for n in sorted(cfg.plugins))}")
    print(f"  tracker station abs_H_trk: {where}")
    for w in warnings:
        print(f"  WARNING: {w}")
    if insecure := insecure_tcp(cfg):
        print(f"  WARNING: insecure_tcp = true: {', '.join(insecure)} accept clients without CURVE")
    return RitadExit.OK


def insecure_tcp(cfg: config_mod.Config) -> list[str]:
    if cfg.security.curve:
        return []
    d = cfg.daemon
    eps = d.command_endpoints + d.telemetry_endpoints + d.frame_endpoints
    return [e for e in eps if e.startswith("tcp://")]
