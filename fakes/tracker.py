"""Fake Leica AT901: an emScon TCP server over the simulated world, and the ``sim:`` adapter.

The server speaks the same bytes as a real emScon server (it reuses
``drivers.emscon.codec``), keeps the real state rules (nothing but status queries
before Initialize → TrackerNotInitialized; a request while a command runs →
ServerBusy) and measures ``World.reflectors_trk()`` (the robot's reflector, which
follows the robot pose, and the three plate nests) with Gaussian noise of
``sigma_mm`` per coordinate from ``world.rng("tracker.noise")``.

How it differs from a real AT901:

* Only RHR coordinates, Stationary and ContinuousTime modes; no regions, probes, 6DoF,
  cameras, nivel, refraction, reflector-position packets or command queue (those
  answer NotImplemented). Units are honoured for lengths and angles only.
* Time is simulated and scaled by ``time_scale`` (default 0.05: a 1 s measurement
  takes 50 ms, Initialize 1 s instead of ~20 s); no warm-up, no weather monitor.
* Lock-on is geometric: GoPosition locks onto a reflector within the search radius
  (default 50 mm) of the target point; FindReflector onto the one nearest the beam
  line within that radius, else ModuleTimedOut. The beam never breaks by itself and
  follows any robot motion (no speed limit); std values are just ``sigma_mm``.
* No target → MeasurementStatusNotReady (the status a real server picks is not
  documented publicly); status numbers for other failures are plausible choices.
* A new connection replaces the old one (a real server refuses it with
  MultiConnectionsNotAllowed). Continuous records carry seconds/microseconds since
  server start in lTime1/lTime2 (as beckjac/emscon_ros src/main.cpp reads them; Leica's header
  does not say: an assumption ``ritactl commission`` checks).
* Fault knobs (``Faults``): drop after N packets, delay answers, split packets into
  single bytes, send garbage, force a status for a command, result before answer, answer a
  command with an OutOfRangeOK status (``ok``).
* Documented device behaviours, each switchable per test (``fakes/tracker_frames.py``): another
  client's station orientation and transformation left applied (``foreign_frame``), the stream's
  packet rate as ES_SP_TcpDataPacketRate sets it (3-10/s; ``packet_rate_hz`` until then),
  ``max_data_rate``, and a beam break mid-stream (``break_beam`` / ``restore_beam``).

Run alone: ``python -m fakes.tracker --host 127.0.0.1 --port 0`` prints ``port N``.
"""
from __future__ import annotations

import argparse
import asyncio
import sys
import threading
from typing import Any

from drivers.base import DeviceURL, Emit, no_emit
from drivers.emscon.adapter import EmsconTracker, flag
from drivers.emscon.enums import ES_Command, ES_ResultStatus
from fakes.tracker_server import Faults, FakeTrackerServer
from fakes import worlds
from fakes.world import World, WorldParams

__all__ = ["Faults", "FakeTrackerServer", "FakeTrackerThread", "SimTracker", "main"]


class FakeTrackerThread:
    """Runs a :class:`FakeTrackerServer` on its own asyncio loop in a daemon thread.

    ``stop()`` kills the server (listener and client connection) without losing the
    tracker state; ``start()`` brings it back on the same port.
    """

    def __init__(self, server: FakeTrackerServer, timeout: float = 10.0) -> None:
        self.server = server
        self.timeout = timeout
        self.loop = asyncio.new_event_loop()
        self.thread = threading.Thread(target=self.loop.run_forever, name="fake-tracker", daemon=True)
        self.thread.start()

    @property
    def port(self) -> int:
        return self.server.port

    @property
    def faults(self) -> Faults:
        return self.server.faults

    def call(self, coro: Any) -> Any:
        """Run a coroutine on the server loop and wait for its result."""
        return asyncio.run_coroutine_threadsafe(coro, self.loop).result(self.timeout)

    def start(self, port: int | None = None) -> int:
        return self.call(self.server.start(port))

    def stop(self) -> None:
        self.call(self.server.stop())

    def restart(self, reset_state: bool = False) -> int:
        """Kill and restart on the same port (``reset_state``: also reboot the tracker)."""
        self.stop()
        if reset_state:
            self.server.model.reset()
        return self.start()

    def send_event(self, change: int) -> None:
        self.call(self.server.event(change))

    def send_error(self, command: int, status: int) -> None:
        self.call(self.server.async_error(command, status))

    def break_beam(self) -> None:
        self.call(self.server.break_beam())

    def restore_beam(self, name: str) -> None:
        self.call(self.server.restore_beam(name))

    def close(self) -> None:
        """Stop the server and the loop thread (for test teardown)."""
        if self.loop.is_closed():
            return
        try:
            self.stop()
        finally:
            self.loop.call_soon_threadsafe(self.loop.stop)
            self.thread.join(self.timeout)
            if not self.thread.is_alive():
                self.loop.close()


def _fail_map(text: str) -> dict[int, int]:
    """Parse ``"StartMeasurement=TrackerNotInitialized,63=41"`` into {command: status}."""
    out: dict[int, int] = {}
    for item in filter(None, text.split(",")):
        cmd, sep, status = item.partition("=")
        if not sep:
            raise ValueError(f"fail entry {item!r} is not COMMAND=STATUS")
        out[_lookup(ES_Command, cmd)] = _lookup(ES_ResultStatus, status)
    return out


def _lookup(enum_cls: Any, text: str) -> int:
    text = text.strip()
    if text.lstrip("-").isdigit():
        return int(text)
    try:
        return int(enum_cls[text])
    except KeyError:
        raise ValueError(f"{text!r} is not a {enum_cls.__name__} name or number") from None


_fail_map.__name__ = "COMMAND=STATUS list"


class SimTracker(EmsconTracker):
    """``sim:`` tracker: starts a fake server in a thread, then talks emScon to it.

    URL options (besides EmsconTracker's): ``sigma_mm``, ``time_scale``,
    ``packet_rate_hz``, ``flood_batch`` (stream packets of N records back to back, as fast
    as TCP allows, for throughput benchmarks), ``drop_after``, ``delay_ms``, ``split``,
    ``garbage_after``, ``result_first``, ``fail`` (``Cmd=Status,...``), ``ok`` (``Cmd=Status,...``, an
    OutOfRangeOK answer that still takes effect), ``max_data_rate``, ``foreign_frame`` (0/1), ``frame_held``
    (0/1: a defect, another client holds its frame),
    ``search_radius_mm``.
    """

    OPTIONS = EmsconTracker.OPTIONS | {"sigma_mm", "time_scale", "packet_rate_hz", "flood_batch",
                                       "drop_after", "delay_ms", "split", "garbage_after", "result_first",
                                       "fail", worlds.OPTION, "ok", "max_data_rate", "foreign_frame",
                                       "frame_held"}

    def __init__(self, url: DeviceURL, *, emit: Emit = no_emit, settings: Any = None) -> None:
        super().__init__(url, emit=emit, settings=settings)
        self.world = worlds.world_for(url)
        o = url.option
        self.sim_options = {"sigma_mm": o("sigma_mm", None, float),
                            "time_scale": o("time_scale", 0.05, float),
                            "packet_rate_hz": o("packet_rate_hz", 8.0, float),
                            "flood_batch": o("flood_batch", 0, int),
                            "max_data_rate": o("max_data_rate", 1000, int),
                            "foreign_frame": o("foreign_frame", False, flag),
                            "frame_held": o("frame_held", False, flag)}
        if self.sim_options["flood_batch"] < 0:
            raise ValueError(f"tracker URL {url.raw!r}: flood_batch={self.sim_options['flood_batch']} "
                             "must be >= 0")
        self.sim_faults = Faults(drop_after=o("drop_after", 0, int), delay_ms=o("delay_ms", 0.0, float),
                                 split=o("split", False, flag), garbage_after=o("garbage_after", 0, int),
                                 result_first=o("result_first", False, flag), fail=o("fail", {}, _fail_map),
                                 ok=o("ok", {}, _fail_map))
        self.server: FakeTrackerThread | None = None

    def endpoint(self) -> tuple[str, int]:
        if self.server is None:
            fake = FakeTrackerServer(self.world, faults=self.sim_faults, **self.sim_options)
            self.server = FakeTrackerThread(fake)
            self.server.start(0)
        return "127.0.0.1", self.server.port

    def info(self) -> dict[str, Any]:
        """The adapter's, plus the simulated time's scale (a recording's metadata states it)."""
        return {**super().info(), "simulated": True, "time_scale": self.sim_options["time_scale"]}

    def shutdown(self) -> None:
        """Close the adapter and stop the fake server thread (tests, daemon exit)."""
        self.close()
        if self.server is not None:
            self.server.close()
            self.server = None


def main(argv: list[str] | None = None) -> int:
    """Command line: serve a fake AT901 until killed."""
    ap = argparse.ArgumentParser(prog="python -m fakes.tracker", description=__doc__.splitlines()[0])
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=0, help="0 = any free port (printed)")
    ap.add_argument("--seed", type=int, default=1, help="world seed")
    ap.add_argument("--sigma-mm", type=float, default=None)
    ap.add_argument("--time-scale", type=float, default=0.05)
    ap.add_argument("--packet-rate-hz", type=float, default=8.0)
    ap.add_argument("--flood-batch", type=int, default=0, help="stream N-record packets back to back")
    ap.add_argument("--drop-after", type=int, default=0)
    ap.add_argument("--delay-ms", type=float, default=0.0)
    ap.add_argument("--split", action="store_true")
    ap.add_argument("--garbage-after", type=int, default=0)
    ap.add_argument("--fail", type=_fail_map, default={}, help="e.g. FindReflector=ModuleTimedOut")
    a = ap.parse_args(argv)
    faults = Faults(a.drop_after, a.delay_ms, a.split, a.garbage_after, fail=a.fail)
    server = FakeTrackerServer(World(WorldParams(seed=a.seed)), sigma_mm=a.sigma_mm,
                               time_scale=a.time_scale, packet_rate_hz=a.packet_rate_hz,
                               flood_batch=a.flood_batch, faults=faults, host=a.host)

    async def serve() -> None:
        port = await server.start(a.port)
        print(f"port {port}", flush=True)
        await asyncio.Event().wait()

    try:
        asyncio.run(serve())
    except KeyboardInterrupt:
        pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
