"""URL scheme → adapter class registry, imported lazily.

The config names each device by URL; the scheme picks the adapter class, which is
imported only when it is used, so a robot without a camera SDK still starts and the
operator's laptop never imports OpenCV or harvesters. Third parties can add schemes
through the ``rita.adapters`` entry-point group (name ``kind.scheme``, value
``module:Class``).

Simulation enters the same way, by name only: ``sim:`` resolves to the fakes'
adapters, and :func:`start_sim_world` calls the fakes' world factory, so nothing in
ritad imports ``fakes`` (tests/system/test_layers.py).
"""
from __future__ import annotations

import importlib
from importlib.metadata import entry_points
from typing import Any
from urllib.parse import quote

from drivers.base import Device, DeviceURL, Emit

#: kind -> scheme -> "module:Class"
ADAPTERS: dict[str, dict[str, str]] = {
    "camera": {
        "genicam": "drivers.genicam:GenICamCamera",
        "sim": "fakes.camera:SimCamera",
    },
    "tracker": {
        "emscon": "drivers.emscon.adapter:EmsconTracker",
        "sim": "fakes.tracker:SimTracker",
    },
    "robot": {
        "serial": "drivers.robot:SerialRobot",
        "socket": "drivers.robot:SerialRobot",
        "loop": "drivers.robot:SerialRobot",
        "rfc2217": "drivers.robot:SerialRobot",
        "sim": "fakes.robot:SimRobot",
    },
}

#: builds the shared simulated world from the config's [sim] section and plays the installer (fakes/installer.py, fakes/worlds.py)
SIM_WORLD_FACTORY = "fakes.installer:start"
#: the simulated world's error profiles, name -> builder ([sim] profile; fakes/profiles.py)
SIM_PROFILES = "fakes.profiles:PROFILES"
SIM_SURVEY_FACTORY = "fakes.survey_views:install"  # sim.survey_images: (world, data_dir, views, size) -> paths
SIM_SCHEME = "sim"

#: top-level module -> what to install when it is missing
INSTALL_HINTS = {
    "harvesters": "pip install harvesters genicam",
    "genicam": "pip install genicam",
    "cv2": "pip install opencv-python-headless",
    "serial": "pip install pyserial",
    "numpy": "pip install numpy",
}


class AdapterError(Exception):
    """The URL names no known adapter, or the adapter's dependencies are missing."""


def _entry_point_adapters() -> dict[str, dict[str, str]]:
    extra: dict[str, dict[str, str]] = {}
    for ep in entry_points(group="rita.adapters"):
        kind, _, scheme = ep.name.partition(".")
        extra.setdefault(kind, {})[scheme] = ep.value
    return extra


def schemes(kind: str) -> dict[str, str]:
    table = dict(ADAPTERS.get(kind, {}))
    table.update(_entry_point_adapters().get(kind, {}))
    return table


def _load(target: str, what: str) -> Any:
    """Import ``module:name`` lazily; a missing third-party package says what to install."""
    module_name, _, attr = target.partition(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        top = (exc.name or "").split(".")[0]
        hint = INSTALL_HINTS.get(top)
        if hint is None:
            raise
        raise AdapterError(f"{what} needs the Python package {top!r}, which is not installed: "
                           f"{hint}") from exc
    return getattr(module, attr)


def adapter_class(kind: str, url: DeviceURL) -> type[Device]:
    """Resolve ``url`` to an adapter class for device ``kind``."""
    table = schemes(kind)
    if not table:
        raise AdapterError(f"unknown device kind {kind!r} (known: {', '.join(sorted(ADAPTERS))})")
    target = table.get(url.scheme)
    if target is None:
        raise AdapterError(
            f"{kind} URL {url.raw!r}: unknown scheme {url.scheme!r} (known: {', '.join(sorted(table))})")
    cls = _load(target, f"{kind} URL {url.raw!r}")
    if not (isinstance(cls, type) and issubclass(cls, Device)):
        raise AdapterError(f"{target} is not a Device adapter")
    return cls


def open_device(kind: str, url: str, *, emit: Emit, settings: Any = None) -> Device:
    """Construct (not open) the adapter for ``url``."""
    parsed = DeviceURL.parse(url)
    return adapter_class(kind, parsed)(parsed, emit=emit, settings=settings)


def build_device(kind: str, url: str) -> Device:
    """The adapter for ``url`` built as ritad builds it, never opened: ``--check-config``'s test of the
    URL's options (a misspelt one, a bad value). ValueError names the URL; AdapterError a missing package."""
    return open_device(kind, url, emit=lambda topic, payload: None)


def is_sim(url: str) -> bool:
    return DeviceURL.parse(url).scheme == SIM_SCHEME


def start_sim_world(sim: dict[str, Any], data_dir: str) -> tuple[str, Any]:
    """Build the simulated world the ``sim:`` devices share; returns (name, world).

    The world is opaque to ritad: it is handed to the sim-only commands (``sim.truth``)
    and named in each ``sim:`` URL (:func:`in_world`).
    """
    return _load(SIM_WORLD_FACTORY, "a sim: device")(sim, data_dir)


def sim_profiles() -> list[str]:
    """Names of the simulated world's error profiles (loaded by name: ritad never imports fakes)."""
    return list(_load(SIM_PROFILES, "[sim] profile"))


def sim_survey_renderer() -> Any:
    """The simulated survey camera's writer (``sim.survey_images``), imported by name like the world."""
    return _load(SIM_SURVEY_FACTORY, "sim.survey_images")


def in_world(url: str, world: str) -> str:
    """``url`` with ``world=<name>`` added when it is a ``sim:`` URL (others unchanged)."""
    parsed = DeviceURL.parse(url)
    if parsed.scheme != SIM_SCHEME or "world" in parsed.query:
        return url
    sep = "&" if "?" in url else "?"
    return f"{url}{sep}world={quote(world, safe='')}"
