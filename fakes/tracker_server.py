"""asyncio emScon server for the fake AT901: command handlers, timing and streaming.

One client at a time: a new connection replaces the old one (a real server answers
MultiConnectionsNotAllowed instead). Motions, initialisation and measurements take
simulated time scaled by ``time_scale``.
"""
from __future__ import annotations

import asyncio
import math
import time
from typing import Any

import numpy as np

from drivers.emscon.codec import (COMMANDS, MEAS_VALUE, Packet, encode_answer, encode_error, encode_result,
                                  encode_status_change)
from drivers.emscon.enums import ES_Command as C
from drivers.emscon.enums import ES_CoordinateSystemType, ES_LTSensorType, ES_MeasMode
from drivers.emscon.enums import ES_ResultStatus as RS
from drivers.emscon.enums import ES_SystemStatusChange as SSC
from drivers.emscon.enums import ES_TrackerProcessorStatus as TPS
from drivers.emscon.enums import ES_TrackerStatus
from fakes.tracker_frames import FrameCommands
from fakes.tracker_model import REFLECTORS, TrackerModel
from fakes.tracker_session import Faults, Session, bare_answer, Dropped

MAX_RECORDS = 20000  # per MultiMeasResult packet (well under the 1 MiB framer limit)
COMPUTE_STEP_S = 0.005  # a stream's records are computed this often between packets
MAX_BEHIND_S = 1.0  # a stream stalled longer than this (a suspended host) resumes its cadence from now


class FakeTrackerServer(FrameCommands):
    """The fake emScon server; owns the tracker model, listens on ``host:port``.

    ``packet_rate_hz``: stream packets per second until a client sets ES_SP_TcpDataPacketRate;
    ``max_data_rate``: GetTrackerInfo's iMaxDataRate (a faster time separation is refused);
    ``foreign_frame``: start with another client's station orientation and transformation applied;
    ``frame_held``: that client holds them (a defect no connect can clear: fakes/tracker_frames.py).
    """

    def __init__(self, world: Any, *, sigma_mm: float | None = None, time_scale: float = 0.05,
                 packet_rate_hz: float = 8.0, flood_batch: int = 0, faults: Faults | None = None,
                 host: str = "127.0.0.1", max_data_rate: int = 1000, foreign_frame: bool = False,
                 frame_held: bool = False) -> None:
        if not time_scale >= 0:
            raise ValueError(f"time_scale={time_scale!r} must be >= 0")
        if not 0 < packet_rate_hz <= 100:
            raise ValueError(f"packet_rate_hz={packet_rate_hz!r} must be in (0, 100]")
        self.model = TrackerModel(world, sigma_mm)
        self.time_scale = time_scale
        self.packet_rate_hz = packet_rate_hz
        self.max_data_rate = int(max_data_rate)
        self.frame_held = frame_held
        if foreign_frame or frame_held:
            self.preset_foreign_frame()
        self.flood_batch = int(flood_batch)  # >0: stream full packets as fast as TCP allows (benchmarks)
        self.faults = faults or Faults()
        self.host = host
        self.port = 0
        self.t0 = time.monotonic()
        self.session: Session | None = None
        self.commands_seen: list[int] = []
        self._server: asyncio.base_events.Server | None = None

    # ------------------------------------------------------------------ lifecycle

    async def start(self, port: int | None = None) -> int:
        """Listen (on the previous port when restarting); return the bound port."""
        want = self.port if port is None else port
        self._server = await asyncio.start_server(self._accept, self.host, want, reuse_address=True)
        self.port = self._server.sockets[0].getsockname()[1]
        return self.port

    async def stop(self) -> None:
        """Stop listening and drop the client (like a controller going away)."""
        if self._server is not None:
            self._server.close()
            if self.session is not None:
                self.session.abort()
            await self._server.wait_closed()
            self._server = None
        elif self.session is not None:
            self.session.abort()

    async def _accept(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self.session is not None:
            self.session.abort()
        sess = self.session = Session(self, reader, writer)
        await sess.run()

    async def event(self, change: int) -> None:
        """Send a SystemStatusChange to the client (when unsolicited messages are on)."""
        s = self.session
        if s is not None and self.model.state.settings["send_unsolicited_messages"]:
            await s.send_quiet(encode_status_change(change))

    async def async_error(self, command: int, status: int) -> None:
        """Send an unsolicited ErrorResponse (e.g. a beam break)."""
        if self.session is not None:
            await self.session.send_quiet(encode_error(command, status))

    async def _sleep(self, seconds: float) -> None:
        if seconds * self.time_scale > 0:
            await asyncio.sleep(seconds * self.time_scale)

    # ------------------------------------------------------------------ commands

    async def execute(self, s: Session, req: Packet) -> None:
        cmd = int(req.command or 0)
        self.commands_seen.append(cmd)
        if self.faults.delay_ms > 0:
            await asyncio.sleep(self.faults.delay_ms / 1000.0)
        if cmd in self.faults.fail:
            await s.send(encode_answer(cmd, self.faults.fail[cmd]))
            return
        handler = getattr(self, f"_c_{C(cmd).name}", None) if cmd in COMMANDS else None
        if handler is None:
            await s.send(encode_answer(cmd, RS.NotImplemented) if cmd in COMMANDS else
                         bare_answer(cmd, RS.NotImplemented))
            return
        status, values, after = await handler(s, req.values)
        status = self.faults.ok.get(cmd, status) if status == 0 else status  # accepted, out of range
        ok = status == 0 or cmd in self.faults.ok
        if not ok or not after or not self.faults.result_first:
            await s.send(encode_answer(cmd, status, **values) if ok else encode_answer(cmd, status))
            for data in after:
                await s.send(data)
        else:
            for data in after:
                await s.send(data)
            await s.send(encode_answer(cmd, status, **values))

    def _need_init(self) -> int:
        return 0 if self.model.state.initialized else RS.TrackerNotInitialized

    async def _c_GetSystemStatus(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        st = self.model.state
        return 0, {"last_result_status": 0,
                   "tracker_processor_status": TPS.Initialized if st.initialized else TPS.CompensationSet,
                   "laser_status": 3, "adm_status": 2, "major_version": 3, "minor_version": 6,
                   "build_number": 0, "weather_monitor_status": st.settings["weather_monitor_status"],
                   "flags_value": 0, "tracker_serial_number": 901001}, []

    async def _c_GetTrackerStatus(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        st = self.model.state
        ready = st.initialized and st.locked is not None
        return 0, {"tracker_status": ES_TrackerStatus.Ready if ready else ES_TrackerStatus.NotReady}, []

    async def _c_GetTrackerInfo(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        return 0, {"tracker_type": ES_LTSensorType.AT901_LR, "tracker_name": "AT901-LR (simulated)",
                   "serial_number": 901001, "compensation_id": 1, "has_adm": 1, "has_overview_camera": 1,
                   "has_nivel": 0, "max_distance": 80000.0 * self.model.state.length_unit(),
                   "min_distance": 0.0, "max_data_rate": self.max_data_rate, "number_of_faces": 2,
                   "hz_angle_range": 480.0, "vt_angle_range": 290.0, "fw_major": 3, "fw_minor": 6}, []

    async def _c_SetUnits(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        if v["length_unit"] not in range(6) or v["angle_unit"] not in range(3):
            return RS.WrongParameter, {}, []
        self.model.state.units = {k: int(x) for k, x in v.items()}
        return 0, {}, [encode_status_change(SSC.UnitsChanged)]

    async def _c_GetUnits(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        return 0, dict(self.model.state.units), []

    async def _c_Initialize(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        await self._sleep(20.0)
        self.model.state.initialized = True
        self.model.point_to(-np.array([0.0, 1.0, 1.0]))
        return 0, {}, [encode_status_change(SSC.InitializationStatusChanged),
                       encode_status_change(SSC.MeasStatus_NotReady)]

    async def _c_SetEnvironmentParams(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        t, p, h = v["temperature"], v["pressure"], v["humidity"]
        if not (-10 <= t <= 50 and 500 <= p <= 1200 and 0 <= h <= 100):
            return RS.MeteoDataOutOfRange, {}, []
        self.model.state.environment = (t, p, h)
        return 0, {}, [encode_status_change(SSC.EnvironmentParamsChanged)]

    async def _c_GetEnvironmentParams(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        t, p, h = self.model.state.environment
        return 0, {"temperature": t, "pressure": p, "humidity": h}, []

    async def _c_SetMeasurementMode(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        if s.stream is not None and not s.stream.done():
            return RS.InternalProcessActive, {}, []
        if v["meas_mode"] not in (ES_MeasMode.Stationary, ES_MeasMode.ContinuousTime):
            return RS.NotImplemented, {}, []
        self.model.state.meas_mode = int(v["meas_mode"])
        return 0, {}, [encode_status_change(SSC.MeasurementModeChanged)]

    async def _c_SetStationaryModeParams(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        if not 1 <= v["meas_time_ms"] <= 100_000:
            return RS.Parameter1OutOfRangeNOK, {}, []
        self.model.state.meas_time_ms, self.model.state.use_adm = int(v["meas_time_ms"]), int(v["use_adm"])
        return 0, {}, []

    async def _c_SetContinuousTimeModeParams(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        if not 1000.0 / self.max_data_rate <= v["time_separation_ms"] <= 3_600_000:
            return RS.Parameter1OutOfRangeNOK, {}, []
        if v["use_region"]:
            return RS.NotImplemented, {}, []
        st = self.model.state
        st.time_separation_ms, st.number_of_points = int(v["time_separation_ms"]), int(v["number_of_points"])
        return 0, {}, []

    async def _c_SetCoordinateSystemType(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        if v["coord_sys_type"] != ES_CoordinateSystemType.RHR:
            return RS.NotImplemented, {}, []
        self.model.state.coord_sys_type = int(v["coord_sys_type"])
        return 0, {}, [encode_status_change(SSC.CoordinateSystemTypeChanged)]

    async def _c_GetSystemSettings(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        return 0, dict(self.model.state.settings), []

    async def _c_SetSystemSettings(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        self.model.state.settings = {k: int(x) for k, x in v.items()}
        self.held_again()
        return 0, {}, [encode_status_change(SSC.SystemSettingsChanged)]

    async def _c_SetSearchParams(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        r_mm = v["search_radius"] / self.model.state.length_unit()
        if not 0 < r_mm <= 5000 or v["timeout_ms"] < 0:
            return RS.WrongParameter, {}, []
        self.model.state.search_radius_mm, self.model.state.search_timeout_ms = r_mm, int(v["timeout_ms"])
        return 0, {}, []

    async def _c_GetReflectors(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        rows = [encode_answer(C.GetReflectors, 0, total_reflectors=len(REFLECTORS), reflector_id=i,
                              target_type=t, surface_offset=off * self.model.state.length_unit(), name=n)
                for i, n, t, off in REFLECTORS]
        for row in rows[:-1]:  # every row is an answer; execute() sends the last one
            await s.send(row)
        i, n, t, off = REFLECTORS[-1]
        return 0, {"total_reflectors": len(REFLECTORS), "reflector_id": i, "target_type": t,
                   "surface_offset": off * self.model.state.length_unit(), "name": n}, []

    async def _c_SetReflector(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        if v["reflector_id"] not in [r[0] for r in REFLECTORS]:
            return RS.WrongParameter1, {}, []
        self.model.state.reflector_id = int(v["reflector_id"])
        return 0, {}, [encode_status_change(SSC.ReflectorChanged)]

    async def _c_GetReflector(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        return 0, {"reflector_id": self.model.state.reflector_id}, []

    async def _c_GetDirection(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        if self._need_init():
            return self._need_init(), {}, []
        self.model.locked_position()
        hz, vt = self.model.hz_vt_deg()
        k = self.model.state.angle_unit()
        return 0, {"hz_angle": hz * k, "vt_angle": vt * k}, []

    async def _motion(self, angle_deg: float) -> None:
        await self._sleep(0.2 + angle_deg / 90.0)  # ~90 deg/s plus settling

    def _lock_changes(self, before: str | None) -> list[bytes]:
        now = self.model.state.locked
        if (before is None) == (now is None):
            return []
        return [encode_status_change(SSC.MeasStatus_Ready if now else SSC.MeasStatus_NotReady)]

    def _target(self, v: dict) -> np.ndarray | None:
        xyz = np.array([v["val1"], v["val2"], v["val3"]], dtype=float) / self.model.state.length_unit()
        return xyz if np.all(np.isfinite(xyz)) and np.linalg.norm(xyz) > 1.0 else None

    async def _aim(self, v: dict) -> tuple[int, np.ndarray | None, str | None]:
        """Turn the beam to the command's target: (status, target, lock before); nonzero = not moved."""
        if self._need_init():
            return self._need_init(), None, None
        target = self._target(v)
        if target is None:
            return RS.WrongParameter, None, None
        before = self.model.state.locked
        await self._motion(self.model.point_to(target))
        return 0, target, before

    async def _c_GoPosition(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        status, target, before = await self._aim(v)
        if status or target is None:
            return status, {}, []
        name = self.model.nearest_to_point(target)  # GoPosition also locks onto a reflector there
        if name is not None:
            self.model.lock(name)
        return 0, {}, self._lock_changes(before)

    async def _c_PointLaser(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        status, _, before = await self._aim(v)
        return (status, {}, []) if status else (0, {}, self._lock_changes(before))

    async def _c_GoBirdBath(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        if self._need_init():
            return self._need_init(), {}, []
        before = self.model.state.locked
        await self._motion(self.model.point_to(-np.array([0.0, 1.0, 1.0])))
        return 0, {}, self._lock_changes(before)

    async def _c_FindReflector(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        if self._need_init():
            return self._need_init(), {}, []
        if not (math.isfinite(v["approx_distance"]) and v["approx_distance"] > 0):
            return RS.Parameter1OutOfRangeNOK, {}, []
        before = self.model.state.locked
        name = self.model.nearest_to_beam(v["approx_distance"] / self.model.state.length_unit())
        if name is None:
            self.model.state.locked = None
            await self._sleep(self.model.state.search_timeout_ms / 1000.0)
            return RS.ModuleTimedOut, {}, []
        await self._motion(1.0)
        self.model.lock(name)
        return 0, {}, self._lock_changes(before)

    async def _c_StopMeasurement(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        if s.stream is not None:
            s.stream.cancel()
            s.stream = None
        return 0, {}, []

    async def _c_StartMeasurement(self, s: Session, v: dict) -> tuple[int, dict, list[bytes]]:
        st = self.model.state
        if self._need_init():
            return self._need_init(), {}, []
        if s.stream is not None and not s.stream.done():
            return RS.InternalProcessActive, {}, []
        if self.model.locked_position() is None:
            return RS.MeasurementStatusNotReady, {}, []
        if st.meas_mode == ES_MeasMode.ContinuousTime:
            s.stream = asyncio.ensure_future(self._stream(s))
            return 0, {}, []
        await self._sleep(st.meas_time_ms / 1000.0)
        p = self.model.measure_point()
        if p is None:
            return RS.NoStationaryResult, {}, []
        p = self.in_client_frame(p)
        k, sig = st.length_unit(), self.model.sigma_mm * st.length_unit()
        t, pr, h = st.environment
        res = encode_result("single", 0, meas_mode=st.meas_mode, val1=p[0] * k, val2=p[1] * k,
                            val3=p[2] * k, std1=sig, std2=sig, std3=sig, std_total=sig * math.sqrt(3),
                            apriori_std1=sig, apriori_std2=sig, apriori_std3=sig,
                            apriori_std_total=sig * math.sqrt(3), temperature=t, pressure=pr, humidity=h)
        return 0, {}, [res]

    def _records(self, n: int, t_next: float, dt: float) -> np.ndarray | None:
        rec = self.model.measure_records(n, t_next - self.t0, dt, self.t0)
        if rec is not None:  # in the frame the client left applied (the identity unless one was set)
            k = self.model.state.length_unit()
            xyz = self.in_client_frame(np.column_stack([rec["val1"], rec["val2"], rec["val3"]]) / k) * k
            rec["val1"], rec["val2"], rec["val3"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        return rec

    async def _packet(self, t_next: float, dt: float, left: int, end: float) -> np.ndarray | None:
        """One packet's records, due by the time it is sent (``end``, its slot on the server's clock). They
        are computed a few ms at a time as they fall due (a moving robot's pose costs tens of µs a record),
        so the packet leaves right after its last record's time, as a device's would, not a packet's
        computation later."""
        parts: list[np.ndarray] = []
        t, got = t_next, 0
        while True:
            now = time.monotonic()
            n = math.floor((min(now, end) - t) / dt) + 1  # records due by now
            n = n if left < 0 else min(n, left - got)
            if n > 0:
                rec = self._records(min(n, MAX_RECORDS - got), t, dt)
                if rec is None:
                    return None
                parts.append(rec)
                t, got = t + len(rec) * dt, got + len(rec)
            if now >= end or got >= MAX_RECORDS or (left >= 0 and got >= left):
                return np.concatenate(parts) if parts else np.zeros(0, MEAS_VALUE)
            await asyncio.sleep(min(COMPUTE_STEP_S, max(0.0, end - time.monotonic())))

    async def _stream(self, s: Session) -> None:
        """Continuous-time mode: batches of records at the packet rate until stopped."""
        st = self.model.state
        dt = st.time_separation_ms / 1000.0
        t_next = slot = time.monotonic()
        left = st.number_of_points or -1
        env = dict(zip(("temperature", "pressure", "humidity"), st.environment))
        try:
            while left != 0:
                if self.flood_batch > 0:
                    n = self.flood_batch if left < 0 else min(self.flood_batch, left)
                    await asyncio.sleep(0)
                    rec = self._records(min(n, MAX_RECORDS), t_next, dt)
                else:
                    # packets on a fixed cadence of the server's clock, as a device's timer sends them:
                    # after a stall (a busy host) the packets due go out back to back, each with its own
                    # records; one of more than MAX_BEHIND_S restarts the cadence
                    slot += 1.0 / self.packet_rate_hz
                    slot = slot if time.monotonic() - slot < MAX_BEHIND_S else time.monotonic()
                    rec = await self._packet(t_next, dt, left, slot)
                if rec is None:  # beam lost: tell the client the way a real server does
                    await s.send(encode_error(C.StartMeasurement, RS.MeasurementStatusNotReady))
                    return
                if not len(rec):
                    continue
                t_next += len(rec) * dt
                await s.send(encode_result("multi", 0, rec, meas_mode=ES_MeasMode.ContinuousTime, **env))
                left = left - len(rec) if left > 0 else left
            await s.send(encode_status_change(SSC.MeasurementCountReached))
        except (Dropped, ConnectionError, RuntimeError):
            s.abort()

