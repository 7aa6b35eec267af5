"""ritad configuration: one TOML file loaded into typed dataclasses.

Unknown keys and bad values are errors that name the key and the file. Each device
is chosen by a URL (see :mod:`daemon.ritad.registry`) and every one is required.
A top-level section named after an installed plugin (daemon/ritad/plugins.py; e.g. ``[sim]``
of the simulator, whose ``sim:`` URLs select its fakes) is checked by that plugin.
``sim_config()`` is the built-in simulation configuration used by ``ritad --sim``.
"""
from __future__ import annotations

import dataclasses
import os
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from daemon.bus.names import KINDS, ROLES
from daemon.bus import station
from daemon.ritad.registry import AdapterError, build_device, schemes
from drivers.base import DeviceURL
from drivers.camera_settings import CameraSettings
from drivers.gige import MIN_PACKET_BYTES

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

#: a config section: one of the dataclasses below
_Section = TypeVar("_Section", bound="DataclassInstance")


class ConfigError(ValueError):
    """A bad configuration value; the message names the file and the key."""


#: keys that were accepted once and are now refused with a pointer to what replaced them
REMOVED_KEYS = {
    "security.server_secret_key":
        "the server key is read from $CREDENTIALS_DIRECTORY/ritad-server.key_secret "
        "(systemd LoadCredential=) or else <data_dir>/keys/server.key_secret; "
        "delete this key (see docs/operations.md, Keys)",
}


#: shown in the error for a missing device URL
EXAMPLE_URLS = {"camera": "genicam:///opt/ArenaSDK_Linux_x64/lib64/GenTL_LUCID.cti?serial=...",
                "tracker": "emscon://192.168.0.10:700", "robot": "serial:///dev/ttyUSB0"}


@dataclass
class DaemonSection:
    command_endpoints: list[str] = field(default_factory=lambda: ["ipc:///run/ritad/cmd"])
    telemetry_endpoints: list[str] = field(default_factory=lambda: ["ipc:///run/ritad/telemetry"])
    frame_endpoints: list[str] = field(default_factory=lambda: ["ipc:///run/ritad/frames"])
    data_dir: str = "/var/lib/ritad"
    health_interval_s: float = 1.0
    max_message_bytes: int = 1 << 20
    frame_hwm: int = 2
    telemetry_hwm: int = 10000
    log_level: str = "INFO"
    #: start the calibration worker process beside the daemon
    start_worker: bool = False
    #: device reconnect backoff: first wait and ceiling (doubles after every failed attempt)
    reconnect_min_s: float = 0.5
    reconnect_max_s: float = 30.0
    #: a device owner thread whose heartbeat is older than this counts as hung (watchdog withheld);
    #: runners beat at least every 0.5 s, also while they wait in backoff
    heartbeat_timeout_s: float = 10.0
    #: time limit of one device open() (TCP connect + init); longer counts as a hung owner thread
    open_timeout_s: float = 120.0


@dataclass
class DevicesSection:
    """Every device URL is required: a forgotten line must not silently become a simulation."""

    camera: str = ""
    tracker: str = ""
    robot: str = ""


@dataclass
class TrackerSection:
    stream_rate_hz: float = 1000.0
    #: ACS pose of the tracker frame (4x4 row-major); unset: the station file the installer wrote
    #: (calibration/tracker_station.json in the data dir, daemon/bus/station.py), else identity
    abs_H_trk: list[list[float]] | None = None


@dataclass
class RobotSection:
    max_distance_mm: float = 2000.0
    max_speed_mm_s: float = 200.0
    max_turn_speed_deg_s: float = 45.0


@dataclass
class SecuritySection:
    curve: bool = False
    #: directory of allowed client public keys (*.key); relative to data_dir when not absolute
    authorized_keys_dir: str = "authorized_keys"
    #: allow tcp endpoints without CURVE (anyone on the network can drive the robot); warned at every start
    insecure_tcp: bool = False
    #: role of clients without a CURVE key: local ipc clients (the worker among them: it needs operator)
    #: and, with insecure_tcp, everyone on the tcp endpoints. CURVE keys carry their own role.
    ipc_role: str = "operator"


@dataclass
class Config:
    daemon: DaemonSection = field(default_factory=DaemonSection)
    devices: DevicesSection = field(default_factory=DevicesSection)
    camera: CameraSettings = field(default_factory=CameraSettings)
    tracker: TrackerSection = field(default_factory=TrackerSection)
    robot: RobotSection = field(default_factory=RobotSection)
    security: SecuritySection = field(default_factory=SecuritySection)
    #: the sections of installed plugins, as each plugin's check_config returned them
    plugins: dict[str, dict[str, Any]] = field(default_factory=dict)
    source: str = "<built-in>"

    def device_urls(self) -> dict[str, str]:
        return {k: getattr(self.devices, k) for k in KINDS}


# --------------------------------------------------------------------------- loading


def _check_value(value: Any, hint: Any, where: str) -> Any:
    """Validate ``value`` against a type hint; ints are accepted where floats are."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        args = typing.get_args(hint)
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _check_value(value, arg, where)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0] if errors else f"{where}: bad value {value!r}")
    if origin is list:
        (item,) = typing.get_args(hint)
        if not isinstance(value, list):
            raise ConfigError(f"{where}: expected a list, got {type(value).__name__} {value!r}")
        return [_check_value(v, item, f"{where}[{i}]") for i, v in enumerate(value)]
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {type(value).__name__} {value!r}")
        return float(value)
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {type(value).__name__} {value!r}")
        return value
    if hint in (str, bool):
        if not isinstance(value, hint):
            raise ConfigError(f"{where}: expected {hint.__name__}, got {type(value).__name__} {value!r}")
        return value
    raise ConfigError(f"{where}: unsupported type {hint}")


def _build(cls: type[_Section], data: dict[str, Any], src: str, prefix: str = "") -> _Section:
    """Build dataclass ``cls`` from a TOML table; errors read ``file: section.key: ...``."""
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls) if f.name not in ("source", "plugins")}
    for key in data:
        if prefix + key in REMOVED_KEYS:
            raise ConfigError(f"{src}: {prefix}{key} is no longer supported: {REMOVED_KEYS[prefix + key]}")
    unknown = sorted(set(data) - names)
    if unknown:
        where = f"[{prefix.rstrip('.')}]" if prefix else "top level"
        raise ConfigError(f"{src}: unknown key(s) {', '.join(prefix + u for u in unknown)} in {where} "
                          f"(known: {', '.join(sorted(names))})")
    kwargs = {}
    for key, value in data.items():
        hint = hints[key]
        if isinstance(hint, type) and dataclasses.is_dataclass(hint):
            if not isinstance(value, dict):
                raise ConfigError(f"{src}: {prefix}{key} must be a table [{prefix}{key}], got {value!r}")
            kwargs[key] = _build(hint, value, src, f"{prefix}{key}.")
        else:
            try:
                kwargs[key] = _check_value(value, hint, f"{prefix}{key}")
            except ConfigError as exc:
                raise ConfigError(f"{src}: {exc}") from None
    return cls(**kwargs)


def _validate(cfg: Config) -> None:
    src = cfg.source
    for kind in KINDS:
        url = getattr(cfg.devices, kind)
        if not url:
            raise ConfigError(f"{src}: devices.{kind} is missing: every device needs a URL in [devices] "
                              f"(e.g. {kind} = \"{EXAMPLE_URLS[kind]}\"; \"sim:\" for the simulated one)")
        try:
            parsed = DeviceURL.parse(url)
        except ValueError as exc:
            raise ConfigError(f"{src}: devices.{kind}: {exc}") from None
        known = schemes(kind)  # names only: the adapter module is imported when the device opens
        if parsed.scheme not in known:
            raise ConfigError(f"{src}: devices.{kind}: unknown scheme {parsed.scheme!r} in {url!r} "
                              f"(known: {', '.join(sorted(known))})")
    d = cfg.daemon
    for key in ("command_endpoints", "telemetry_endpoints", "frame_endpoints"):
        eps = getattr(d, key)
        if not eps:
            raise ConfigError(f"{src}: daemon.{key} must name at least one endpoint")
        for ep in eps:
            if not ep.startswith(("tcp://", "ipc://", "inproc://")):
                raise ConfigError(f"{src}: daemon.{key}: {ep!r} is not a tcp://, ipc:// or "
                                  f"inproc:// endpoint")
            if ep.startswith("tcp://") and not cfg.security.curve and not cfg.security.insecure_tcp:
                raise ConfigError(f"{src}: daemon.{key}: {ep!r} is a tcp endpoint without CURVE: anyone who "
                                  f"reaches the port could move the robot. Set [security] curve = true "
                                  f"(docs/operations.md, Keys), use ipc only, or accept the risk with "
                                  f"[security] insecure_tcp = true")
    positive = {"daemon.health_interval_s": d.health_interval_s,
                "daemon.max_message_bytes": d.max_message_bytes,
                "daemon.frame_hwm": d.frame_hwm, "daemon.telemetry_hwm": d.telemetry_hwm,
                "daemon.reconnect_min_s": d.reconnect_min_s,
                "daemon.heartbeat_timeout_s": d.heartbeat_timeout_s,
                "daemon.open_timeout_s": d.open_timeout_s,
                "tracker.stream_rate_hz": cfg.tracker.stream_rate_hz,
                "robot.max_distance_mm": cfg.robot.max_distance_mm,
                "robot.max_speed_mm_s": cfg.robot.max_speed_mm_s,
                "robot.max_turn_speed_deg_s": cfg.robot.max_turn_speed_deg_s}
    for key, value in positive.items():
        if not value > 0:
            raise ConfigError(f"{src}: {key} must be > 0, got {value}")
    if d.heartbeat_timeout_s < 1.0:  # runners beat every 0.5 s: less than two beats would be noise
        raise ConfigError(f"{src}: daemon.heartbeat_timeout_s must be >= 1.0, got {d.heartbeat_timeout_s}")
    if d.reconnect_max_s < d.reconnect_min_s:
        raise ConfigError(f"{src}: daemon.reconnect_max_s ({d.reconnect_max_s}) must be >= "
                          f"daemon.reconnect_min_s ({d.reconnect_min_s})")
    if d.log_level.upper() not in ("DEBUG", "INFO", "WARNING", "ERROR"):
        raise ConfigError(f"{src}: daemon.log_level {d.log_level!r} is not DEBUG/INFO/WARNING/ERROR")
    _validate_camera(cfg.camera, src)
    if cfg.tracker.abs_H_trk is not None:
        try:
            cfg.tracker.abs_H_trk = station.checked(cfg.tracker.abs_H_trk, "tracker.abs_H_trk")
        except station.StationError as exc:
            raise ConfigError(f"{src}: {exc}") from None


def _validate_camera(c: CameraSettings, src: str) -> None:
    """The [camera] values a device cannot judge (its ranges are checked when it opens)."""
    if c.trigger not in ("software", "free"):
        raise ConfigError(f"{src}: camera.trigger {c.trigger!r} must be 'software' or 'free'")
    if isinstance(c.packet_size, str) and c.packet_size != "auto":
        raise ConfigError(f'{src}: camera.packet_size {c.packet_size!r} must be "auto" or a number of bytes')
    if isinstance(c.packet_size, int) and not c.packet_size >= MIN_PACKET_BYTES:
        raise ConfigError(f"{src}: camera.packet_size must be >= {MIN_PACKET_BYTES} bytes, "
                          f"got {c.packet_size}")
    if c.throughput_limit_bytes_s is not None and c.throughput_limit_bytes_s < 0:
        raise ConfigError(f"{src}: camera.throughput_limit_bytes_s must be >= 0 (0 = no limit), "
                          f"got {c.throughput_limit_bytes_s}")
    if c.stream_buffers is not None and c.stream_buffers < 1:
        raise ConfigError(f"{src}: camera.stream_buffers must be >= 1, got {c.stream_buffers}")


def check_devices(cfg: Config) -> list[str]:
    """``--check-config``: build each device's adapter from its URL, opening nothing.

    A misspelt or bad URL option is a ConfigError naming it. Not part of :func:`load`: a start
    imports each adapter in its own device thread, so a robot without the camera SDK still
    starts; here a missing package is a warning (the list returned), as it does not stop ritad.
    """
    warnings = []
    for kind in ("camera", "tracker", "robot"):
        url = getattr(cfg.devices, kind)
        try:
            build_device(kind, url)
        except ValueError as exc:
            raise ConfigError(f"{cfg.source}: devices.{kind}: {exc}") from None
        except AdapterError as exc:
            if not isinstance(exc.__cause__, ModuleNotFoundError):
                raise ConfigError(f"{cfg.source}: devices.{kind}: {exc}") from None
            warnings.append(f"devices.{kind}: URL options not checked: {exc}")
        except Exception as exc:  # an adapter that cannot even be built: name it, no traceback
            raise ConfigError(f"{cfg.source}: devices.{kind}: {url!r}: {type(exc).__name__}: {exc}") from None
    return warnings


def _validate_security(cfg: Config) -> None:
    role = cfg.security.ipc_role
    if role not in ROLES:
        raise ConfigError(f"{cfg.source}: security.ipc_role {role!r} is not one of {', '.join(ROLES)}")
    if cfg.daemon.start_worker and role == "viewer":
        raise ConfigError(f'{cfg.source}: security.ipc_role = "viewer" with daemon.start_worker = true: '
                          f"the calibration worker connects over ipc and needs operator")


def _plugin_sections(data: dict[str, Any], source: str) -> tuple[dict[str, Any], dict[str, dict[str, Any]]]:
    """``data`` without the installed plugins' sections, and those sections as their plugins checked them."""
    from daemon.ritad.plugins import PluginError, installed  # imports the plugins: ritad only

    product = {f.name for f in dataclasses.fields(Config)}
    rest, sections = dict(data), {}
    try:
        found = installed()
    except PluginError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    for name, plugin in found.items():
        if name in product:
            raise ConfigError(f"plugin {name!r} claims the product's config section [{name}]")
        table = rest.pop(name, {})
        if not isinstance(table, dict):
            raise ConfigError(f"{source}: {name} must be a table [{name}], got {table!r}")
        try:
            sections[name] = plugin.check_config(table, f"[{name}]")
        except ValueError as exc:
            raise ConfigError(f"{source}: {exc}") from None
    return rest, sections


def from_dict(data: dict[str, Any], source: str = "<dict>") -> Config:
    rest, sections = _plugin_sections(data, source)
    cfg = _build(Config, rest, source)
    cfg.source = source
    cfg.plugins = sections
    _validate(cfg)
    _validate_security(cfg)
    return cfg


def load(path: str | os.PathLike[str]) -> Config:
    """Load and validate a TOML config file."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{path}: config file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    return from_dict(data, str(path))


def sim_config(runtime_dir: str | os.PathLike[str], data_dir: str | os.PathLike[str] | None = None,
               seed: int = 1, profile: str = "ideal") -> Config:
    """The built-in simulation config: every device ``sim:``, ipc endpoints in ``runtime_dir``."""
    rt = Path(runtime_dir)
    return from_dict({
        "daemon": {"command_endpoints": [f"ipc://{rt}/cmd"],
                   "telemetry_endpoints": [f"ipc://{rt}/telemetry"],
                   "frame_endpoints": [f"ipc://{rt}/frames"],
                   "data_dir": str(data_dir or rt / "data"), "start_worker": True},
        "devices": {"camera": "sim:", "tracker": "sim:", "robot": "sim:"},
        "sim": {"seed": seed, "profile": profile},
    }, source="<built-in sim config>")
