"""A device kind that a plugin declares (plugins.DeviceKind): ritad runs it in a rig of its own and
hands that rig to the kind's handlers; without a URL the kind is absent. The kind here is a counter
defined in this file, installed as `pip install -e .` would install its entry points."""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, ClassVar, Mapping

import pytest

from daemon.bus.command_table import Command
from daemon.bus.protocol import CommandError
from daemon.ritad.futures import chain
from daemon.ritad.rigs import Rig
from daemon.ritad.server import Handler
from drivers.base import Device
from tests.ritad_up import ritad_in_process

ENTRY_POINTS = f"""[rita.adapters]
counter.sim = {__name__}:Counter
plugin.counter = {__name__}:KIND
"""


class Counter(Device):
    """Counts its reads; ``start`` sets the first value. Emits each count as telemetry."""

    kind: ClassVar[str] = "counter"
    OPTIONS: ClassVar[frozenset[str]] = frozenset({"start", "world"})

    def open(self) -> None:
        self.count = int(self.url.query.get("start", 0))

    def close(self) -> None:
        pass

    def read(self) -> int:
        self.count += 1
        self.emit("counter.count", {"count": self.count})
        return self.count


class CounterKind:
    name = "counter"
    commands = (Command("counter.read", "the next count", result="{count}"),)

    def check_config(self, table: Mapping[str, Any], where: str) -> dict[str, Any]:
        return {"url": str(table.get("url", ""))}

    def start(self, section: Mapping[str, Any], data_dir: Path, urls: Mapping[str, str]) -> None:
        return None

    def device_handlers(self, rig: Rig, services: Any) -> dict[str, Handler]:
        return {"counter.read": lambda req: chain(rig.job(lambda c: c.read()), lambda n: {"count": n})}


KIND = CounterKind()


@pytest.fixture
def installed(tmp_path, monkeypatch):
    dist = tmp_path / "site" / "counter_kind-0.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: counter-kind\nVersion: 0\n")
    (dist / "entry_points.txt").write_text(ENTRY_POINTS)
    monkeypatch.setattr(sys, "path", [str(tmp_path / "site"), *sys.path])


def test_a_plugins_device_kind_runs_in_its_own_rig(tmp_path, installed):
    def configure(cfg):
        cfg.plugins["counter"] = {"url": "sim:?start=41"}

    with ritad_in_process(tmp_path / "rt", configure=configure) as (d, c):
        sub = c.subscriber(["counter.count"])
        assert c.call("counter.read") == {"count": 42}
        assert c.call("counter.read") == {"count": 43}
        health = c.call("status")
        assert health["devices"]["counter"]["state"] in ("READY", "BUSY")
        assert c.call("hello")["devices"]["counter"] == "sim:?start=41"
        assert d.rigs.more["counter"].runner.jobs_done == 2
        got = sub.recv(5.0)  # the adapter's telemetry went out through its rig's sink
        assert got is not None and got[0] == "counter.count" and got[1]["data"]["count"] in (42, 43)


def test_without_a_url_the_kind_is_absent_and_its_commands_say_so(tmp_path, installed):
    with ritad_in_process(tmp_path / "rt") as (d, c):
        assert "counter" not in d.rigs.more
        with pytest.raises(CommandError) as e:
            c.call("counter.read")
        assert e.value.code == "not_found"
