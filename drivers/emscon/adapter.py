"""``EmsconTracker``: the daemon's Tracker adapter for a Leica AT901 over emScon.

URL: ``emscon://host[:700]?timeout=30&init_timeout=90&meas_time_ms=1000&...``

Options: ``timeout`` (s, every command and motion), ``init_timeout`` (s, Initialize),
``connect_timeout`` (s), ``meas_time_ms`` (stationary measurement time), ``use_adm``
(0/1), ``temperature_c``/``pressure_mbar``/``humidity_rh`` (sent with
SetEnvironmentParams when all three are given), ``reflector`` (name or id, selected
with SetReflector), ``search_radius_mm`` (SetSearchParams), ``packet_rate`` (stream packets per
second, ES_SP_TcpDataPacketRate, 3-10; default 10).

``open()`` runs the whole init sequence, so a reconnect re-applies units (mm, deg,
°C, mbar), RHR coordinates, stationary mode and its parameters, and clears what another client
may have left: station orientation and transformation are set to the identity and not applied
(public clients set both to the identity: beckjac/emscon_ros src/main.cpp, scale 1).
Stream batches and events are delivered by ``pump`` as ``tracker.point`` / ``tracker.event``
messages; a stream the beam broke (ErrorResponse or MeasStatus_NotReady) is restarted by ``pump``
once the tracker reports the reflector locked again, at the same rate.
"""
from __future__ import annotations

import logging
import math
import time
from typing import Any

from drivers.base import (DeviceError, DeviceSettings, DeviceLost, DeviceURL, Emit, Tracker, TrackerPoint,
                          no_emit)
from drivers.emscon.client import EmsconClient, EmsconStatusError
from drivers.emscon.codec import Packet
from drivers.emscon.enums import (
    ES_AngleUnit, ES_Command, ES_CoordinateSystemType, ES_HumidityUnit, ES_LengthUnit, ES_LTSensorType,
    ES_MeasMode,
    ES_PressureUnit, ES_ResultStatus, ES_SystemStatusChange, ES_TemperatureUnit,
    ES_TrackerProcessorStatus, ES_TrackerStatus, enum_name)
from drivers.emscon.known_state import (DEFAULT_PACKET_RATE, PACKET_RATE_RANGE, clear_frames, read_back,
                                        set_packet_rate)

log = logging.getLogger(__name__)
DEFAULT_PORT = 700
MAX_RATE_HZ = 1000.0  # until GetTrackerInfo's max_data_rate is known
MIN_RATE_HZ = 0.001  # one point per 1000 s: the time separation (ms) must fit an int32
MAX_AIM_MM = 1e6  # 1 km, far beyond any tracker's range: larger is a typo, not a target
#: keyed by int: a packet's change is the plain int it carried (an IntEnum hashes as its value)
_MEAS_STATUS: dict[int, str] = {ES_SystemStatusChange.MeasStatus_NotReady: "NotReady",
                                ES_SystemStatusChange.MeasStatus_Busy: "Busy",
                                ES_SystemStatusChange.MeasStatus_Ready: "Ready"}


#: statuses that mean "no reflector locked": the operator must aim and find first
_NOT_LOCKED = ("MeasurementStatusNotReady",)
AIM_AND_FIND = "aim and find first: `ritactl tracker aim X Y Z` then `ritactl tracker find`"


def _actionable(exc: DeviceError) -> DeviceError:
    """Say what to do instead of only the emScon status name (the code stays ``tracker_<Status>``)."""
    name = getattr(exc, "status_name", None)
    if name not in _NOT_LOCKED:
        return exc
    exc.args = (f"no reflector locked ({name}): {AIM_AND_FIND}",)  # same type, code and status
    return exc


def flag(text: str) -> bool:
    if text.lower() in ("1", "true", "yes", "on"):
        return True
    if text.lower() in ("0", "false", "no", "off"):
        return False
    raise ValueError(text)


flag.__name__ = "flag (0/1)"


class EmsconTracker(Tracker):
    """A Leica laser tracker reached through the emScon TPI."""

    OPTIONS = frozenset({"timeout", "init_timeout", "connect_timeout", "meas_time_ms", "use_adm", "reflector",
                         "search_radius_mm", "temperature_c", "pressure_mbar", "humidity_rh", "packet_rate"})

    def __init__(self, url: DeviceURL, *, emit: Emit = no_emit,
                 settings: DeviceSettings = None) -> None:
        super().__init__(url, emit=emit, settings=settings)
        o = url.option
        self.timeout: float = o("timeout", 30.0, float)
        self.init_timeout: float = o("init_timeout", 90.0, float)
        self.connect_timeout: float = o("connect_timeout", 5.0, float)
        self.meas_time_ms: int = o("meas_time_ms", 1000, int)
        self.use_adm: bool = o("use_adm", False, flag)
        self.reflector: str | None = o("reflector", None, str)
        self.search_radius_mm: float | None = o("search_radius_mm", None, float)
        self.packet_rate: int = o("packet_rate", DEFAULT_PACKET_RATE, int)
        if not PACKET_RATE_RANGE[0] <= self.packet_rate <= PACKET_RATE_RANGE[1]:
            lo, hi = PACKET_RATE_RANGE
            raise ValueError(f"device URL {url.raw!r}: option packet_rate={self.packet_rate} outside "
                             f"{lo}-{hi} packets/s (ES_SP_TcpDataPacketRate)")
        env = [o(k, None, float) for k in ("temperature_c", "pressure_mbar", "humidity_rh")]
        if any(v is not None for v in env) and not all(v is not None for v in env):
            raise ValueError(f"device URL {url.raw!r}: give all of temperature_c, pressure_mbar, "
                             f"humidity_rh or none of them")
        self.environment = tuple(env) if env[0] is not None else None
        for name, value in (("timeout", self.timeout), ("init_timeout", self.init_timeout),
                            ("connect_timeout", self.connect_timeout), ("meas_time_ms", self.meas_time_ms)):
            if not value > 0:
                raise ValueError(f"device URL {url.raw!r}: option {name}={value!r} must be > 0")
        self._client: EmsconClient | None = None
        self._streaming = False
        self._interrupted = False  # the beam broke during the stream: pump restarts it once locked
        self._resume_refused = False  # a restart failed: wait for the next MeasStatus_Ready
        self._sep_ms = 0
        self._rate_hz: float | None = None
        self._last_aim: tuple[float, float, float] | None = None
        self._tracker_status = "Unknown"
        self._info: dict[str, Any] = {}
        self._seq = 0
        self.counters = {"points": 0, "packets": 0, "protocol_errors": 0, "events": 0, "opens": 0,
                         "stream_restarts": 0}
        self._client_base = {"protocol_errors": 0}

    # ------------------------------------------------------------------ connection

    def endpoint(self) -> tuple[str, int]:
        """Host and port to connect to (the sim adapter overrides this)."""
        if not self.url.host:
            raise ValueError(f"device URL {self.url.raw!r} has no host (e.g. emscon://192.168.0.1:700)")
        return self.url.host, self.url.port or DEFAULT_PORT

    def open(self) -> None:
        self.close()
        host, port = self.endpoint()
        client = EmsconClient(host, port, connect_timeout=self.connect_timeout, timeout=self.timeout,
                              on_event=self._on_event, on_stream=self._on_stream)
        self._client = client
        client.connect()
        try:
            self._init_sequence(client)
        except BaseException:
            self.close()
            raise
        self.counters["opens"] += 1

    def _init_sequence(self, c: EmsconClient) -> None:
        """Bring the tracker to a known state after every connect: units, initialise if needed, modes,
        coordinates, settings."""
        c.request(ES_Command.SetUnits, length_unit=ES_LengthUnit.Millimeter,
                  angle_unit=ES_AngleUnit.Degree, temperature_unit=ES_TemperatureUnit.Celsius,
                  pressure_unit=ES_PressureUnit.Mbar, humidity_unit=ES_HumidityUnit.RH)
        st = c.request(ES_Command.GetSystemStatus)
        if st["tracker_processor_status"] != ES_TrackerProcessorStatus.Initialized:
            c.request(ES_Command.Initialize, timeout=self.init_timeout)
        # StopMeasurement first: after a dropped connection the server may still stream
        self._try_stop(c)
        c.request(ES_Command.SetMeasurementMode, meas_mode=ES_MeasMode.Stationary)
        c.request(ES_Command.SetStationaryModeParams, meas_time_ms=self.meas_time_ms,
                  use_adm=int(self.use_adm))
        c.request(ES_Command.SetCoordinateSystemType, coord_sys_type=ES_CoordinateSystemType.RHR)
        clear_frames(c)
        if self.environment is not None:
            t, p, h = self.environment
            c.request(ES_Command.SetEnvironmentParams, temperature=t, pressure=p, humidity=h)
        if self.search_radius_mm is not None:
            c.request(ES_Command.SetSearchParams, search_radius=self.search_radius_mm,
                      timeout_ms=int(self.timeout * 1000))
        if self.reflector is not None:
            self._select_reflector(c, self.reflector)
        info = c.request(ES_Command.GetTrackerInfo).values
        self._info = {"packet_rate": set_packet_rate(c, self.packet_rate, self.url.raw),
                      "packet_rate_asked": self.packet_rate,
                      "tracker_name": info["tracker_name"],
                      "tracker_type": enum_name(ES_LTSensorType, info["tracker_type"]),
                      "serial_number": info["serial_number"], "max_data_rate": info["max_data_rate"],
                      "firmware": f"{st['major_version']}.{st['minor_version']}.{st['build_number']}"}
        ts = c.request(ES_Command.GetTrackerStatus)
        self._tracker_status = enum_name(ES_TrackerStatus, ts["tracker_status"])
        self._streaming = self._interrupted = False

    def _try_stop(self, c: EmsconClient) -> None:
        try:
            c.request(ES_Command.StopMeasurement, timeout=min(self.timeout, 5.0))
        except DeviceLost:
            raise
        except DeviceError as exc:
            if not c.connected:  # no answer in time: the client hung up to resynchronise, say so now
                raise DeviceLost(f"tracker {self.url.raw}: {c.lost_reason or exc}") from exc
            # "nothing to stop" is fine

    def _select_reflector(self, c: EmsconClient, wanted: str) -> None:
        known = c.get_reflectors()
        for r in known:
            if r["name"] == wanted or str(r["reflector_id"]) == wanted:
                c.request(ES_Command.SetReflector, reflector_id=r["reflector_id"])
                return
        names = [f"{r['reflector_id']}:{r['name']}" for r in known]
        raise DeviceError(f"tracker has no reflector {wanted!r} (known: {names})",
                          code="tracker_no_reflector")

    def close(self) -> None:
        c, self._client = self._client, None
        if c is None:
            return
        if self._streaming and c.connected:
            try:
                c.request(ES_Command.StopMeasurement, timeout=2.0)
            except Exception:  # close must not raise
                pass
        self._streaming = False
        self._client_base["protocol_errors"] += c.counters["protocol_errors"]
        c.close()

    def _conn(self) -> EmsconClient:
        c = self._client
        if c is None or not c.connected:
            reason = c.lost_reason if c is not None else "not open"
            raise DeviceLost(f"tracker {self.url.raw}: not connected ({reason or 'closed'})")
        return c

    # ------------------------------------------------------------------ jobs

    def measure(self) -> TrackerPoint:
        if self._streaming:
            raise DeviceError("tracker is streaming; stop_stream() before a stationary measurement",
                              code="tracker_streaming")
        c = self._conn()
        try:
            res = c.measure(timeout=self.timeout + self.meas_time_ms / 1000.0)
        except EmsconStatusError as exc:
            raise _actionable(exc) from exc
        v = res.values
        now, mono = time.time_ns(), time.monotonic_ns()
        point = TrackerPoint(v["val1"], v["val2"], v["val3"], (v["std1"], v["std2"], v["std3"]),
                             v["temperature"], v["pressure"], v["humidity"], self._tracker_status, now, mono)
        self._publish([point.x], [point.y], [point.z], [int(res.status)], None, now, mono,
                      mode="stationary", std=[list(point.std)])
        return point

    def aim(self, point_mm: tuple[float, float, float]) -> None:
        x, y, z = (float(v) for v in point_mm)
        if not all(math.isfinite(v) for v in (x, y, z)):
            raise ValueError(f"aim: point {point_mm!r} is not finite")
        if max(abs(x), abs(y), abs(z)) > MAX_AIM_MM:
            raise ValueError(f"aim: point {point_mm!r} is more than {MAX_AIM_MM:g} mm away")
        self._conn().request(ES_Command.GoPosition, val1=x, val2=y, val3=z, use_adm=int(self.use_adm))
        self._last_aim = (x, y, z)

    def find_reflector(self, approx_distance_mm: float | None = None) -> None:
        if approx_distance_mm is None:
            if self._last_aim is None:
                raise ValueError("find needs to know roughly where to look: aim first "
                                 "(`ritactl tracker aim X Y Z`, tracker frame, mm) or give the distance "
                                 "(`ritactl tracker find --distance MM`)")
            approx_distance_mm = math.dist((0.0, 0.0, 0.0), self._last_aim)
        if not (math.isfinite(approx_distance_mm) and approx_distance_mm > 0):
            raise ValueError(f"find_reflector: approx_distance_mm={approx_distance_mm!r} must be > 0")
        try:
            self._conn().request(ES_Command.FindReflector, approx_distance=float(approx_distance_mm))
        except EmsconStatusError as exc:
            exc.args = (f"{exc.args[0]}: no reflector within the search radius of the beam; aim closer "
                        "(`ritactl tracker aim X Y Z`, tracker frame, mm) or hold the reflector in the beam",)
            raise

    def start_stream(self, rate_hz: float) -> float:
        if not (math.isfinite(rate_hz) and rate_hz >= MIN_RATE_HZ):
            raise ValueError(f"start_stream: rate_hz={rate_hz!r} must be >= {MIN_RATE_HZ:g}")
        top = float(self._info.get("max_data_rate") or MAX_RATE_HZ)
        if rate_hz > top:
            log.warning("tracker %s: requested stream rate %g Hz above the tracker's max_data_rate %g Hz: "
                        "streaming at %g Hz", self.url.raw, rate_hz, top, top)
            rate_hz = top
        c = self._conn()
        if self._streaming:
            self.stop_stream()
        # the nearest whole ms, but never faster than the tracker's maximum
        self._sep_ms = max(1, round(1000.0 / rate_hz), math.ceil(1000.0 / top - 1e-9))
        self._begin_stream(c)
        self._streaming, self._interrupted, self._rate_hz = True, False, 1000.0 / self._sep_ms
        return self._rate_hz

    def _begin_stream(self, c: EmsconClient) -> None:
        """Continuous-time mode at ``_sep_ms`` and StartMeasurement; back to stationary if refused."""
        c.request(ES_Command.SetMeasurementMode, meas_mode=ES_MeasMode.ContinuousTime)
        try:
            c.request(ES_Command.SetContinuousTimeModeParams, time_separation_ms=self._sep_ms,
                      number_of_points=0, use_region=0, region_type=0)
            c.request(ES_Command.StartMeasurement)
        except DeviceLost:
            raise
        except DeviceError as exc:
            # e.g. no reflector locked: go back to stationary so measure() still works
            c.request(ES_Command.SetMeasurementMode, meas_mode=ES_MeasMode.Stationary)
            raise _actionable(exc) from exc

    def stop_stream(self) -> None:
        if not self._streaming:
            return
        c = self._conn()
        self._streaming = self._interrupted = False
        self._try_stop(c)  # after a beam break there may be nothing left to stop
        c.request(ES_Command.SetMeasurementMode, meas_mode=ES_MeasMode.Stationary)

    def pump(self, timeout: float) -> None:
        c = self._conn()
        c.poll(timeout)
        locked = self._tracker_status == "Ready" and not self._resume_refused
        if self._streaming and self._interrupted and locked:
            self._resume_stream(c)

    def _resume_stream(self, c: EmsconClient) -> None:
        """The beam broke during the stream and the reflector is locked again: start it anew."""
        self._try_stop(c)
        try:
            self._begin_stream(c)
        except DeviceLost:
            raise
        except DeviceError as exc:  # lost again before it started: the next lock tries again
            self._resume_refused = True
            self._event("stream_resume_failed", reason=str(exc))
            return
        self._interrupted = False
        self.counters["stream_restarts"] += 1
        self._event("stream_resumed", rate_hz=self._rate_hz)

    def _interrupt(self, why: str) -> None:
        """A beam break while streaming: the server stops sending; ``pump`` restarts once locked."""
        if self._streaming and not self._interrupted:
            self._interrupted = True
            self._event("stream_interrupted", reason=why)

    def status(self) -> dict[str, Any]:
        c = self._client
        proto = self._client_base["protocol_errors"] + (c.counters["protocol_errors"] if c else 0)
        return {"connected": bool(c and c.connected), "tracker_status": self._tracker_status,
                "streaming": self._streaming, "stream_interrupted": self._interrupted,
                "rate_hz": self._rate_hz if self._streaming else None,
                "last_aim": list(self._last_aim) if self._last_aim else None,
                "counters": {**self.counters, "protocol_errors": proto}}

    def info(self) -> dict[str, Any]:
        return {"url": self.url.raw, **self._info}

    def readback(self) -> dict[str, Any]:
        """The controller's frames, environment and packet rate, read back now (``tracker.readback``)."""
        return read_back(self._conn())

    # ------------------------------------------------------------------ async input

    def _publish(self, x: list[float], y: list[float], z: list[float], status: list[int],
                 device_time: list[list[int]] | None, now: int, mono: int, **extra: Any) -> None:
        n = len(x)
        self.emit("tracker.point", {"n": n, "x": x, "y": y, "z": z, "status": status,
                                    "device_time": device_time, "host_time_ns": now,
                                    "host_monotonic_ns": mono, "seq": self._seq, **extra})
        self._seq += n
        self.counters["points"] += n

    def _on_stream(self, p: Packet) -> None:
        now, mono = time.time_ns(), time.monotonic_ns()
        self.counters["packets"] += 1
        if p.status != 0:
            self._event("stream_error", status=int(p.status),
                        status_name=enum_name(ES_ResultStatus, p.status))
        r = p.records
        if r is None or len(r) == 0:
            return
        self._interrupted = False  # records again: the server resumed the stream by itself
        self._publish(r["val1"].tolist(), r["val2"].tolist(), r["val3"].tolist(), r["status"].tolist(),
                      [r["time1"].tolist(), r["time2"].tolist()], now, mono, mode="continuous",
                      temperature_c=p["temperature"], pressure_mbar=p["pressure"], humidity_rh=p["humidity"])

    def _on_event(self, p: Packet) -> None:
        if p.kind == "status_change":
            if p.change in _MEAS_STATUS:
                self._tracker_status = _MEAS_STATUS[p.change]
                self._resume_refused = False  # a new lock state: a refused restart may be tried again
            if p.change == ES_SystemStatusChange.MeasStatus_NotReady:
                self._interrupt("MeasStatus_NotReady")
            self._event("status_change", change=int(p.change or 0),
                        change_name=enum_name(ES_SystemStatusChange, p.change or 0))
        elif p.kind == "error":
            if p.command == ES_Command.StartMeasurement:
                self._interrupt(enum_name(ES_ResultStatus, p.status))
            self._event("error", command=int(p.command or 0),
                        command_name=enum_name(ES_Command, p.command or 0),
                        status=int(p.status), status_name=enum_name(ES_ResultStatus, p.status))
        else:
            self._event("unexpected" if p.kind != "reflector_pos" else "reflector_pos",
                        packet=p.describe(), values={k: (int(v) if isinstance(v, int) else v)
                                                     for k, v in p.values.items()
                                                     if isinstance(v, (int, float, str))})

    def _event(self, event: str, **payload: Any) -> None:
        self.counters["events"] += 1
        self.emit("tracker.event", {"event": event, "host_time_ns": time.time_ns(), **payload})
