"""Device interfaces shared by every adapter and fake.

Each device kind (camera, tracker, robot) has one small ABC. The daemon owns one instance per kind
and calls it from exactly one thread (its ``DeviceRunner``; ``wake`` aside), so adapters need no
locking of their own. Asynchronous data (tracker stream points, free-run frames, robot DONE/FAULT
events, tracker events) is pushed through the ``emit`` callback the daemon hands over at
construction; ``emit`` is thread-safe and never blocks (the daemon drops and counts when full).

Adapters are chosen by URL (``emscon://host:700``, ``genicam:///x.cti?serial=…``,
``serial:///dev/ttyUSB0``, ``sim:``) through :mod:`daemon.ritad.registry`.

Units: millimetres, degrees (API), seconds; times are ``time.time_ns()`` (wall) and ``time.monotonic_ns()``.
"""
from __future__ import annotations

import enum
import time
from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, ClassVar
from urllib.parse import parse_qs, urlsplit

import numpy as np

from drivers.camera_settings import CameraSettings
from drivers.motion_gate import MotionGate

def no_emit(topic: str, payload: Payload) -> None:
    """Default sink used when a device runs outside the daemon (tests, scripts)."""


class DeviceState(str, enum.Enum):
    DISCONNECTED = "DISCONNECTED"
    CONNECTING = "CONNECTING"
    READY = "READY"
    BUSY = "BUSY"
    FAULT = "FAULT"


class DeviceError(Exception):
    """A device refused or failed an operation; the connection is still usable.

    ``code`` is a stable machine-readable string (sent on the bus as the error code).
    """

    code = "device_error"

    def __init__(self, message: str, *, code: str | None = None) -> None:
        super().__init__(message)
        if code:
            self.code = code


class DeviceLost(DeviceError):
    """The connection is gone (socket closed, port vanished, camera unplugged).

    The daemon's runner reacts by closing the adapter and reconnecting with backoff.
    """

    code = "device_lost"


class DeviceTimeout(DeviceError):
    """A bounded wait expired."""

    code = "device_timeout"


@dataclass(frozen=True)
class DeviceURL:
    """A parsed device URL: ``scheme://host:port/path?key=value``."""

    raw: str
    scheme: str
    host: str
    port: int | None
    path: str
    query: dict[str, str]

    @classmethod
    def parse(cls, raw: str) -> "DeviceURL":
        parts = urlsplit(raw)
        if not parts.scheme:
            raise ValueError(f"device URL {raw!r} has no scheme (e.g. 'sim:', 'emscon://host:700')")
        query: dict[str, str] = {}
        for key, values in parse_qs(parts.query, keep_blank_values=True).items():
            if len(values) != 1:
                raise ValueError(f"device URL {raw!r}: option {key!r} given {len(values)} times")
            query[key] = values[0]
        try:
            port = parts.port
        except ValueError as exc:
            raise ValueError(f"device URL {raw!r}: bad port ({exc})") from None
        return cls(raw, parts.scheme.lower(), parts.hostname or "", port, parts.path, query)

    def option(self, key: str, default: Any, kind: Callable[[str], Any] = str) -> Any:
        """Typed query option; a bad value raises ValueError naming the URL and key."""
        if key not in self.query:
            return default
        try:
            return kind(self.query[key])
        except (TypeError, ValueError):
            raise ValueError(
                f"device URL {self.raw!r}: option {key}={self.query[key]!r} is not a valid {kind.__name__}"
            ) from None


class Device(ABC):
    """Base of every adapter: open/close plus a ``pump`` for asynchronous input.

    ``pump(timeout)`` is called by the owner thread whenever it has no job to run.
    It reads whatever the device sent (stream data, events) and hands it to ``emit``;
    it must return within ``timeout`` seconds. Raise :class:`DeviceLost` from any
    method when the connection is gone.
    """

    kind: ClassVar[str] = "device"
    #: the URL options this adapter reads; any other is refused by name, as a misspelt one
    #: would otherwise leave its default silently in force
    OPTIONS: ClassVar[frozenset[str]] = frozenset()

    @classmethod
    def url_options(cls, url: DeviceURL) -> frozenset[str]:
        """The options ``url`` may carry (an adapter that hands some to a library adds the library's)."""
        return cls.OPTIONS

    @classmethod
    def check_url(cls, url: DeviceURL) -> None:
        """ValueError naming every option of ``url`` this adapter does not know, and the known ones."""
        known = cls.url_options(url)
        unknown = sorted(set(url.query) - known)
        if unknown:
            raise ValueError(f"{cls.kind} URL {url.raw!r}: unknown option{'s' if len(unknown) > 1 else ''} "
                             f"{', '.join(map(repr, unknown))} (known: {', '.join(sorted(known)) or 'none'})")

    def __init__(self, url: DeviceURL, *, emit: Emit = no_emit,
                 settings: DeviceSettings = None) -> None:
        self.check_url(url)
        self.url = url
        self.emit = emit
        self.settings = settings

    @abstractmethod
    def open(self) -> None:
        """Connect and apply the desired settings; raise DeviceError/DeviceLost on failure."""

    @abstractmethod
    def close(self) -> None:
        """Release everything; must not raise and must be safe to call twice."""

    def pump(self, timeout: float) -> None:
        """Service asynchronous input for at most ``timeout`` s (default: nothing to do)."""
        time.sleep(timeout)

    def wake(self) -> None:
        """Work is queued (another thread calls this): a pump may return early. Never blocks or raises."""

    def park(self) -> None:
        """Leave the device safe before its owner exits (a moving robot halts); the connection may be gone."""

    def info(self) -> dict[str, Any]:
        """Static facts for ``status`` (model, serial, firmware...)."""
        return {"url": self.url.raw}

    def __enter__(self) -> "Device":
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --------------------------------------------------------------------------- tracker


@dataclass
class TrackerPoint:
    """One reflector position in the tracker's frame (mm), with its context."""

    x: float
    y: float
    z: float
    std: tuple[float, float, float] = (0.0, 0.0, 0.0)
    temperature_c: float | None = None
    pressure_mbar: float | None = None
    humidity_rh: float | None = None
    tracker_status: str = ""
    host_time_ns: int = field(default_factory=time.time_ns)
    host_monotonic_ns: int = field(default_factory=time.monotonic_ns)
    device_time_us: int | None = None  # continuous records only

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["std"] = list(self.std)
        return d


class StreamingDevice(Device):
    """What tracker and camera share: a stream that can be stopped, and a status dict."""

    @abstractmethod
    def stop_stream(self) -> None:
        """Stop streaming (no error if not streaming)."""

    @abstractmethod
    def status(self) -> dict[str, Any]:
        """Streaming flag and counters, plus the kind's own (tracker: state strings;
        camera: applied settings and warnings)."""


class Tracker(StreamingDevice):
    """Laser tracker: stationary measurements, pointing, lock-on and streaming."""

    kind = "tracker"

    @abstractmethod
    def measure(self) -> TrackerPoint:
        """One stationary measurement of the locked reflector."""

    @abstractmethod
    def aim(self, point_mm: tuple[float, float, float]) -> None:
        """Turn the beam toward an approximate position (tracker frame, mm)."""

    @abstractmethod
    def find_reflector(self, approx_distance_mm: float | None = None) -> None:
        """Search and lock onto the reflector nearest to where the beam points."""

    @abstractmethod
    def start_stream(self, rate_hz: float) -> float:
        """Start continuous measurement; points go to ``emit('tracker.point', {...})``.

        Returns the rate streamed, in Hz: the device may clamp or round the one asked for."""

    def readback(self) -> dict[str, Any]:
        """What the controller holds now (frames, environment, packet rate), read from it: the commissioning
        check's evidence. A tracker that cannot read them back says so."""
        raise DeviceError(f"{type(self).__name__} cannot read its settings back", code="not_supported")


# --------------------------------------------------------------------------- camera


#: what ritad hands an adapter to apply on open: a camera's desired settings, the robot's motion gate
#: (a latched STOP is the first command of every connect: drivers/motion_gate.py); the tracker gets None
DeviceSettings = CameraSettings | MotionGate | None


@dataclass
class Frame:
    """A frame whose pixels the daemon owns (copied out of any driver buffer)."""

    pixels: np.ndarray
    frame_id: int
    camera_serial: str
    pixel_format: str
    exposure_us: float | None = None
    device_time_ns: int | None = None
    host_time_ns: int = field(default_factory=time.time_ns)
    host_monotonic_ns: int = field(default_factory=time.monotonic_ns)
    incomplete_count: int = 0
    extra: dict[str, Any] = field(default_factory=dict)
    #: for the daemon's clock map, not in the header: the payload's least time on the wire (bytes over
    #: the link rate, ns), and the camera's PTP state when last polled (``ptp`` of the status) or None
    transfer_ns: int = 0
    ptp: dict[str, Any] | None = None
    #: the exposure's mid-time on the host's clock (UTC ns), its sigma and how it was found
    #: ("ptp", "clockmap" or "host"): set by the daemon (daemon/ritad/device_clock.py), None before
    t_ns: int | None = None
    t_sigma_ns: int | None = None
    t_source: str | None = None

    def header(self) -> dict[str, Any]:
        """Frame metadata as sent on the bus and stored next to the image."""
        p = self.pixels
        timed = {} if self.t_source is None else {
            "t_ns": self.t_ns, "t_sigma_ns": self.t_sigma_ns, "t_source": self.t_source}
        return {
            "frame_id": self.frame_id,
            "camera_serial": self.camera_serial,
            "pixel_format": self.pixel_format,
            "shape": list(p.shape),
            "dtype": p.dtype.str,
            "exposure_us": self.exposure_us,
            "device_time_ns": self.device_time_ns,
            "host_time_ns": self.host_time_ns,
            "host_monotonic_ns": self.host_monotonic_ns,
            "incomplete_count": self.incomplete_count,
            **timed,
            **self.extra,
        }


#: what ``emit`` carries: a telemetry message (a msgpack-able dict, as it goes on the wire), or a
#: :class:`Frame` for the frame socket (``emit("camera.frame", frame)``)
Payload = dict[str, Any] | Frame
#: ``emit(topic, payload)``: publish; thread-safe, never blocks
Emit = Callable[[str, Payload], None]


class Camera(StreamingDevice):
    """Area camera: software-triggered single frames and free-run streaming.

    The bookkeeping every camera keeps: whether free run is wanted (it survives a
    reconnect: ``open`` restarts it) and running, and the settings last applied with
    the warnings that produced, for ``status``.
    """

    kind = "camera"

    def __init__(self, url: DeviceURL, *, emit: Emit = no_emit, settings: DeviceSettings = None) -> None:
        super().__init__(url, emit=emit, settings=settings)
        self._want_stream = False
        self._streaming = False
        self._applied: dict[str, Any] = {}
        self._warnings: list[str] = []

    @abstractmethod
    def trigger(self, timeout: float = 5.0) -> Frame:
        """Fire a software trigger and return that frame (copied, daemon-owned)."""

    @abstractmethod
    def start_stream(self) -> None:
        """Free run: frames go to ``emit('camera.frame', frame)`` from ``pump``."""


# --------------------------------------------------------------------------- robot


@dataclass
class RobotState:
    """Robot base status as reported by its controller."""

    state: str  # IDLE / MOVING / FAULT
    x_mm: float
    y_mm: float
    heading_deg: float
    roll_deg: float | None = None
    pitch_deg: float | None = None
    battery_v: float | None = None
    fault: str = ""
    host_time_ns: int = field(default_factory=time.time_ns)
    #: the base's clock at the STATUS (µs, its own origin; protocol 2 with CLOCK, else None)
    t_us: int | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class Robot(Device):
    """Differential-drive base: straight moves, turns on the spot, stop, status.

    ``move``/``turn`` return once the controller accepted the command; completion is
    reported by ``emit('robot.event', {'event': 'DONE'|'FAULT', ...})`` from ``pump``
    and by ``status().state`` returning to IDLE. ``stop`` must be honoured at once.
    """

    kind = "robot"

    @abstractmethod
    def move(self, distance_mm: float, speed_mm_s: float) -> None:
        """Drive straight (negative = backwards)."""

    @abstractmethod
    def turn(self, angle_deg: float, speed_deg_s: float) -> None:
        """Turn on the spot (positive = counter-clockwise seen from above)."""

    @abstractmethod
    def stop(self) -> None:
        """Stop now."""

    @abstractmethod
    def status(self) -> RobotState:
        """Poll the controller's state."""

    def streams(self) -> list[str]:
        """The telemetry topics of the samples the base streams (``robot.odometry``, ``robot.incl``)."""
        return []
