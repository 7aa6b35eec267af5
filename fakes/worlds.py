"""The world registry: how the ``sim:`` devices of one ritad come to share one world.

ritad never imports fakes. Its registry resolves ``sim:`` device URLs to the fake
adapters through entry points, and the simulator's plugin (fakes/plugin.py) calls
``fakes.installer.start`` with the config's ``[sim]`` section and data dir. That builds
the world, plays the installer into the data dir and registers the world here under a
name; the plugin adds ``world=<name>`` to each ``sim:`` URL,
and every fake adapter finds its world with :func:`world_for`. A ``sim:`` URL without
``world=`` (a fake used on its own in a test or script) gets a fresh world of its own.
"""
from __future__ import annotations

import threading
import weakref
from typing import Any, Mapping

from drivers.base import DeviceURL
from fakes.world import World, WorldParams

#: the URL option that names a registered world
OPTION = "world"

_WORLDS: "weakref.WeakValueDictionary[str, World]" = weakref.WeakValueDictionary()
_LOCK = threading.Lock()


def register(world: World, name: str | None = None) -> str:
    """Register ``world`` (replacing any world of that name) and return its name."""
    name = name or f"w{id(world):x}"
    with _LOCK:
        _WORLDS[name] = world
    return name


def sim_url(world: World, query: str = "") -> DeviceURL:
    """A ``sim:`` URL naming ``world`` (registered on the way): a test's fake in a world it made.

    The registry holds worlds weakly (a finished test's world and its renderers go), so
    the caller keeps ``world`` alive until the adapter is built.
    """
    name = register(world)
    return DeviceURL.parse(f"sim:?{OPTION}={name}" + (f"&{query}" if query else ""))


def world_for(url: DeviceURL) -> World:
    """The world a fake adapter lives in: the registered one its URL names, else a fresh one."""
    name = url.option(OPTION, None)
    if name is None:
        return World()
    with _LOCK:
        world = _WORLDS.get(name)
    if world is None:
        raise ValueError(f"device URL {url.raw!r}: no simulated world named {name!r} is running")
    return world


def params_from(sim: Mapping[str, Any]) -> WorldParams:
    """World parameters from a config's ``[sim]`` section (WorldParams fields plus ``profile``)."""
    from fakes import profiles

    sim = dict(sim)
    profile = sim.pop("profile", profiles.DEFAULT)
    fields = set(WorldParams.__dataclass_fields__)
    unknown = sorted(set(sim) - fields)
    if unknown:
        raise ValueError(f"[sim]: unknown world parameter(s) {', '.join(unknown)}")
    return profiles.apply(profile, WorldParams(**sim))


__all__ = ["OPTION", "params_from", "register", "sim_url", "world_for"]
