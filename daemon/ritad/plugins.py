"""Plugins: bus commands, a config section and a lifecycle that ritad does not know by name.

A plugin is an object registered in the ``rita.adapters`` entry-point group under the
name ``plugin.NAME`` (value ``module:OBJECT``), beside the device adapters. The simulator
is one (``plugin.sim``); ritad names none. What a plugin provides:

- ``name`` and ``commands``: :class:`daemon.bus.command_table.Command` entries, each named
  ``NAME.<verb>``, validated, role-checked and logged as the product's are;
- ``check_config(table, where)``: its ``[NAME]`` config section checked (a ``ValueError``
  naming the key; ritad adds the file) and returned with defaults filled in;
- ``start(section, data_dir, urls)``: a :class:`Session` when the configured device URLs
  want it, else None. A session may rewrite device URLs (before any device opens), hands
  ritad the handlers of its commands, adds keys to ``hello`` and is closed at stop;
- or, for a device kind of its own, ``device_handlers(rig, services)`` (:class:`DeviceKind`).

A plugin writes what ritad should read as files in the data dir, as an installer would
(e.g. calibration/tracker_station.json): it never changes ritad's config.
"""
from __future__ import annotations

import logging
from concurrent.futures import Executor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Mapping, Protocol, runtime_checkable

from daemon.bus.command_table import Command, CommandTable, markdown_table
from daemon.ritad.registry import load_target, schemes
from daemon.ritad.server import Handler, Request

log = logging.getLogger("ritad.plugins")
KIND = "plugin"  # the entry-point name prefix: plugin.NAME


class PluginError(RuntimeError):
    """An installed plugin cannot be loaded or declares commands it may not; the message names it."""


class PluginServices(Protocol):
    """What a session's handlers may use of ritad: :class:`daemon.ritad.services.Services` provides it
    (it is not imported here: ritad's config imports this module)."""

    @property
    def data_dir(self) -> Path: ...
    @property
    def storage(self) -> Executor: ...  # the storage thread: file work never holds up a device or the bus
    @property
    def device_info(self) -> Callable[[str], dict[str, Any]]: ...


class Session(Protocol):
    def urls(self, urls: dict[str, str]) -> dict[str, str]: ...
    def handlers(self, services: PluginServices) -> dict[str, Handler]: ...
    def hello(self) -> dict[str, Any]: ...
    def close(self) -> None: ...


class Plugin(Protocol):
    name: str
    commands: tuple[Command, ...]

    def check_config(self, table: Mapping[str, Any], where: str) -> dict[str, Any]: ...
    def start(self, section: Mapping[str, Any], data_dir: Path,
              urls: Mapping[str, str]) -> Session | None: ...


@runtime_checkable
class DeviceKind(Plugin, Protocol):
    """A plugin that is a device kind of its own (a thermometer beside the product's three): ritad runs
    its device in a rig (daemon/ritad/rigs.py: runner, device clock, sink) and hands that rig to the
    handlers of the kind's commands. The device's URL is ``url`` in the kind's config section, its
    adapters are ``rita.adapters`` entry points named ``NAME.SCHEME``; without a URL the kind is
    absent and its commands answer not_found."""

    def device_handlers(self, rig: Any, services: PluginServices) -> dict[str, Handler]: ...


def device_kinds(plugins: Mapping[str, Plugin]) -> dict[str, DeviceKind]:
    """The plugins that are device kinds."""
    return {name: p for name, p in plugins.items() if isinstance(p, DeviceKind)}


def installed(table: CommandTable | None = None) -> dict[str, Plugin]:
    """Every installed plugin, imported and its commands registered in ``table`` (a daemon's own; without
    one, in a table of their own: checked, as a daemon would refuse them)."""
    table = table if table is not None else CommandTable()
    out: dict[str, Plugin] = {}
    for name, target in sorted(schemes(KIND).items()):
        try:
            plugin = load_target(target, f"plugin {name!r}")
        except Exception as exc:  # a broken third-party install: name it, never a traceback
            raise PluginError(f"plugin {name!r} ({target}) cannot be loaded: "
                              f"{type(exc).__name__}: {exc}") from exc
        if getattr(plugin, "name", None) != name:
            raise PluginError(f"entry point plugin.{name} = {target} names a plugin called "
                               f"{getattr(plugin, 'name', None)!r}")
        try:
            table.register(name, tuple(plugin.commands))
        except ValueError as exc:
            raise PluginError(str(exc)) from None
        out[name] = plugin
    return out


@dataclass
class Running:
    """The plugins of one ritad: their sessions in start order (closed in reverse)."""

    sessions: dict[str, Session] = field(default_factory=dict)

    def urls(self, urls: dict[str, str]) -> dict[str, str]:
        for s in self.sessions.values():
            urls = s.urls(urls)
        return urls

    def handlers(self, services: PluginServices, plugins: Mapping[str, Plugin]) -> dict[str, Handler]:
        """Each registered plugin command's handler: its session's, or not_found without one."""
        from daemon.bus.protocol import CommandError, ErrorCode

        out: dict[str, Handler] = {}
        for name, plugin in plugins.items():
            session = self.sessions.get(name)
            given = session.handlers(services) if session is not None else {}
            for c in plugin.commands:
                def absent(req: Request, _name: str = name) -> Any:
                    raise CommandError(ErrorCode.NOT_FOUND,
                                       f"{req.cmd}: plugin {_name!r} is not running in this daemon "
                                       f"(no device of its URLs is configured)")
                out[c.name] = given.get(c.name, absent)
        return out

    def hello(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for s in self.sessions.values():
            out.update(s.hello())
        return out

    def close(self) -> None:
        for name, s in reversed(list(self.sessions.items())):
            try:
                s.close()
            except Exception:  # one plugin's failed close must not keep ritad from stopping
                log.exception("plugin %s: close failed", name)


def start(plugins: Mapping[str, Plugin], sections: Mapping[str, Mapping[str, Any]], data_dir: Path,
          urls: Mapping[str, str]) -> Running:
    running = Running()
    for name, plugin in plugins.items():
        session = plugin.start(sections.get(name, {}), data_dir, urls)
        if session is not None:
            running.sessions[name] = session
            log.info("plugin %s started", name)
    return running


def markdown() -> str:
    """The installed plugins' command tables (docs/protocol.md)."""
    return "".join(f"\n`{name}` plugin:\n\n{markdown_table(tuple(p.commands))}"
                   for name, p in installed().items())


if __name__ == "__main__":
    import sys

    if sys.argv[1:] != ["--markdown"]:
        sys.exit("usage: python -m daemon.ritad.plugins --markdown")
    sys.stdout.write(markdown())
