"""A pure-Python stand-in for the GenApi node maps :mod:`drivers.genicam_settings` talks to.

It offers just what the settings writer uses: ``get_node(name)``, and on a node
``get_access_mode()``, ``node.principal_interface_type``, ``value`` (read and write),
``min``/``max``/``inc``, ``symbolics`` and ``execute()``. Every write and command lands in
the map's ``log`` as ``(name, value)`` in order, so tests can check the order and the
count of writes. A missing node raises AttributeError from ``get_node`` (harvesters raises
a GenApi LogicalErrorException; the writer treats both as "absent").

:func:`camera_node_map` builds a PHX122S-like camera (the node names of
/work/shared/reference/genicam.md; the ranges are plausible, not the camera's own), and
:func:`stream_node_map` the GenTL data stream of a producer that offers resend, packet-size
negotiation and link counters. Either can be built without some nodes (``without=``) to test
the "missing feature" path.

Documented behaviours a test can switch on (each cited where it is modelled):

* ``left``: features another program left changed (``AcquisitionMode``, ``ReverseX``/``ReverseY``):
  the camera keeps its features until power-down or a user set load (SFNC: AcquisitionMode
  SingleFrame / MultiFrame stop after one / AcquisitionFrameCount frames; ReverseX/Y mirror the image).
* ``ptp_wins_election``: no better clock on the network, so an enabled PTP port becomes master
  (IEEE 1588's best-master election) unless ``PtpSlaveOnly`` is set, which keeps it a slave-only
  clock (in ``Listening`` until a master appears).
* ``link_speed``: ``DeviceLinkSpeed`` as the SDK reports it (SFNC: bytes/s, 125 000 000 on GigE;
  some SDKs give Mbps: ``link_speed=1000``).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

from fakes.camera_clock import CameraClock

# GenApi principal interface types and access modes, as genicam_settings reads them
INT, BOOL, CMD, FLOAT, ENUM = 2, 3, 4, 5, 9
NA, RO, RW = 1, 3, 4


@dataclass
class FakeNode:
    """One feature; ``getter``/``setter`` let a node's value depend on other nodes."""

    name: str
    kind: int
    initial: Any = None
    min: Any = None
    max: Any = None
    inc: Any = 1
    symbolics: tuple[str, ...] = ()
    access: int | Callable[[], int] = RW
    getter: Callable[[], Any] | None = None
    setter: Callable[[Any], None] | None = None
    action: Callable[[], None] | None = None
    owner: "FakeNodeMap | None" = None

    @property
    def node(self) -> "FakeNode":
        return self

    @property
    def principal_interface_type(self) -> int:
        return self.kind

    def get_access_mode(self) -> int:
        return self.access() if callable(self.access) else self.access

    @property
    def value(self) -> Any:
        return self.getter() if self.getter is not None else self.initial

    @value.setter
    def value(self, v: Any) -> None:
        # the real GenApi refuses these too; the writer must never get here with them
        if self.get_access_mode() != RW:
            raise PermissionError(f"{self.name} is not writable")
        if self.kind == ENUM and v not in self.symbolics:
            raise ValueError(f"{self.name} has no entry {v!r}")
        if self.kind in (INT, FLOAT) and not self.min <= v <= self.max:
            raise ValueError(f"{self.name}={v} outside {self.min}..{self.max}")
        if self.owner is not None:
            self.owner.log.append((self.name, v))
        if self.setter is not None:
            self.setter(v)
        else:
            self.initial = v

    def execute(self) -> None:
        if self.owner is not None:
            self.owner.log.append((self.name, "execute"))
        if self.action is not None:
            self.action()


@dataclass
class FakeNodeMap:
    """Nodes by name, and the log of every write and command in order."""

    nodes: dict[str, FakeNode] = field(default_factory=dict)
    log: list[tuple[str, Any]] = field(default_factory=list)

    def add(self, node: FakeNode) -> FakeNode:
        node.owner = self
        self.nodes[node.name] = node
        return node

    def get_node(self, name: str) -> FakeNode:
        try:
            return self.nodes[name]
        except KeyError:
            raise AttributeError(f"node map has no {name}") from None

    def __getitem__(self, name: str) -> Any:
        return self.nodes[name].value


def _imaging(nm: FakeNodeMap) -> None:
    add = nm.add
    add(FakeNode("PixelFormat", ENUM, "Mono8", symbolics=("Mono8", "Mono12p", "Mono16")))
    add(FakeNode("Width", INT, 4024, 8, 4024, 8))
    add(FakeNode("Height", INT, 3036, 2, 3036, 2))
    add(FakeNode("OffsetX", INT, 0, 0, 4016, 8))
    add(FakeNode("OffsetY", INT, 0, 0, 3034, 2))
    add(FakeNode("ExposureAuto", ENUM, "Continuous", symbolics=("Off", "Continuous")))
    add(FakeNode("ExposureTime", FLOAT, 5000.0, 20.0, 10_000_000.0))
    add(FakeNode("GainAuto", ENUM, "Continuous", symbolics=("Off", "Continuous")))
    add(FakeNode("Gain", FLOAT, 0.0, 0.0, 48.0))
    add(FakeNode("AcquisitionFrameRateEnable", BOOL, False))
    add(FakeNode("AcquisitionFrameRate", FLOAT, 9.0, 0.1, 9.7))
    add(FakeNode("TriggerSelector", ENUM, "FrameStart", symbolics=("FrameStart",)))
    add(FakeNode("TriggerMode", ENUM, "Off", symbolics=("Off", "On")))
    add(FakeNode("TriggerSource", ENUM, "Line0", symbolics=("Line0", "Software")))
    add(FakeNode("TriggerSoftware", CMD, access=RW))


def _ptp(nm: FakeNodeMap, clock: CameraClock | None, wins: bool) -> None:
    """PTP nodes: a port that locks at once with a -42 ns offset (or, when it ``wins`` the election, becomes
    master), or ``clock``'s (its state and servo); PtpSlaveOnly keeps a winning port from mastering."""
    slave_only = nm.add(FakeNode("PtpSlaveOnly", BOOL, False))
    if clock is None:
        enabled = nm.add(FakeNode("PtpEnable", BOOL, False))

        def status() -> str:
            if not enabled.value:
                return "Disabled"
            return ("Listening" if slave_only.value else "Master") if wins else "Slave"

        offset: Callable[[], Any] = lambda: -42 if status() == "Slave" else None  # noqa: E731
    else:
        enabled = nm.add(FakeNode("PtpEnable", BOOL, getter=lambda: clock.ptp_enabled,
                                  setter=lambda v: setattr(clock, "ptp_enabled", bool(v))))

        def status() -> str:
            state = clock.ptp_status()["status"]
            return "Listening" if state == "Master" and slave_only.value else state

        offset = lambda: clock.ptp_status()["offset_from_master_ns"]  # noqa: E731
    nm.add(FakeNode("PtpStatus", ENUM, access=RO, getter=status,
                    symbolics=("Disabled", "Listening", "Uncalibrated", "Slave", "Master")))
    nm.add(FakeNode("PtpOffsetFromMaster", INT, getter=offset,
                    access=lambda: RO if enabled.value and offset() is not None else NA))
    nm.add(FakeNode("PtpDataSetLatch", CMD))


def _chunks(nm: FakeNodeMap, clock: CameraClock | None) -> dict[str, Any]:
    """Chunk mode, a selector and a per-selector enable; ``values`` is what the 'held buffer' carries
    (with a ``clock``, its Timestamp is the clock's reading now)."""
    active = nm.add(FakeNode("ChunkModeActive", BOOL, False))
    selector = nm.add(FakeNode("ChunkSelector", ENUM, "Timestamp",
                               symbolics=("Timestamp", "ExposureTime", "Gain", "Width", "Height")))
    enabled: dict[str, bool] = {}
    values: dict[str, Any] = {"Timestamp": 1_000_000_123, "ExposureTime": 2000.0, "Gain": 0.0}
    nm.add(FakeNode("ChunkEnable", BOOL, getter=lambda: enabled.get(selector.value, False),
                    setter=lambda v: enabled.__setitem__(selector.value, bool(v))))
    for chunk, kind in (("Timestamp", INT), ("ExposureTime", FLOAT), ("Gain", FLOAT)):
        def access(c: str = chunk) -> int:
            return RO if active.value and enabled.get(c) else NA
        nm.add(FakeNode(f"Chunk{chunk}", kind, access=access, getter=lambda c=chunk: values[c]))
    if clock is not None:
        nm.nodes["ChunkTimestamp"].getter = lambda: clock.device_ns(clock.now_ns())
    return values


def camera_node_map(*, without: tuple[str, ...] = (), packet_max: int = 9000,
                    clock: CameraClock | None = None, left: dict[str, Any] | None = None,
                    ptp_wins_election: bool = False, link_speed: int = 125_000_000) -> FakeNodeMap:
    """A PHX122S-like camera node map; ``without`` drops the named nodes; ``clock`` (fakes/camera_clock.py)
    drives its PTP port and timestamps; ``left``, ``ptp_wins_election``, ``link_speed``: module docstring."""
    nm = FakeNodeMap()
    _imaging(nm)
    nm.add(FakeNode("AcquisitionMode", ENUM, "Continuous",
                    symbolics=("Continuous", "SingleFrame", "MultiFrame")))
    nm.add(FakeNode("ReverseX", BOOL, False))
    nm.add(FakeNode("ReverseY", BOOL, False))
    nm.add(FakeNode("DeviceLinkSpeed", INT, link_speed, access=RO))
    for name, value in (left or {}).items():
        nm.nodes[name].initial = value
    _ptp(nm, clock, ptp_wins_election)
    _chunks(nm, clock)
    nm.add(FakeNode("GevSCPSPacketSize", INT, 1500, 576, packet_max, 4))
    nm.add(FakeNode("DeviceLinkThroughputLimitMode", ENUM, "Off", symbolics=("Off", "On")))
    nm.add(FakeNode("DeviceLinkThroughputLimit", INT, 125_000_000, 31_250_000, 125_000_000, 1))
    for name in without:
        nm.nodes.pop(name)
    return nm


def stream_node_map(*, without: tuple[str, ...] = (), counters: dict[str, int] | None = None,
                    buffer_minimum: int = 2) -> FakeNodeMap:
    """A GenTL data stream with resend, packet-size negotiation, the link counters in ``counters`` and
    ``StreamAnnounceBufferMinimum`` (read-only: the fewest buffers the producer accepts)."""
    nm = FakeNodeMap()
    nm.add(FakeNode("StreamAnnounceBufferMinimum", INT, buffer_minimum, access=RO))
    nm.add(FakeNode("StreamPacketResendEnable", BOOL, False))
    nm.add(FakeNode("StreamAutoNegotiatePacketSize", BOOL, False))
    counts = counters if counters is not None else {}
    for name in ("StreamResendRequestCount", "StreamLostPacketCount", "StreamIncompleteFrameCount",
                 "StreamLostFrameCount"):
        nm.add(FakeNode(name, INT, access=RO, getter=lambda n=name: counts.get(n, 0)))
    for name in without:
        nm.nodes.pop(name)
    return nm
