"""URL scheme → adapter class registry, imported lazily.

The config names each device by URL; the scheme picks the adapter class, which is
imported only when it is used, so a robot without a camera SDK still starts and the
operator's laptop never imports OpenCV or harvesters. Third parties can add schemes
through the ``rita.adapters`` entry-point group (name ``kind.scheme``, value
``module:Class``).

Simulation enters the same way, by name only: ``sim:`` resolves to the fakes'
adapters through the entry points the simulator's package declares (pyproject.toml),
and its world is a plugin (daemon/ritad/plugins.py): nothing in ritad names or imports
``fakes`` (tests/system/test_layers.py).
"""
from __future__ import annotations

import importlib
from importlib.metadata import entry_points
from typing import Any

from drivers.base import Device, DeviceSettings, DeviceURL, Emit, no_emit

#: kind -> scheme -> "module:Class"
ADAPTERS: dict[str, dict[str, str]] = {
    "camera": {
        "genicam": "drivers.genicam:GenICamCamera",
    },
    "tracker": {
        "emscon": "drivers.emscon.adapter:EmsconTracker",
    },
    "robot": {
        "serial": "drivers.robot:SerialRobot",
        "socket": "drivers.robot:SerialRobot",
        "loop": "drivers.robot:SerialRobot",
        "rfc2217": "drivers.robot:SerialRobot",
    },
}

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


def load_target(target: str, what: str) -> Any:
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
    cls = load_target(target, f"{kind} URL {url.raw!r}")
    if not (isinstance(cls, type) and issubclass(cls, Device)):
        raise AdapterError(f"{target} is not a Device adapter")
    return cls


def build_device(kind: str, url: str, *, emit: Emit | None = None, settings: DeviceSettings = None) -> Device:
    """The adapter for ``url``, constructed and not opened (its runner opens it in its own thread).

    ``--check-config`` builds one without ``emit`` to test the URL's options (a misspelt one, a bad
    value). ValueError names the URL; AdapterError a missing package."""
    parsed = DeviceURL.parse(url)
    return adapter_class(kind, parsed)(parsed, emit=emit or no_emit, settings=settings)

