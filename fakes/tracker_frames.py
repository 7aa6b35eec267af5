"""The fake AT901's station orientation, transformation and long system parameters, and its beam breaks.

Documented behaviours (Leica's ES_C_API_Def.h, TPI/SDK V3.6, as published in beckjac/emscon_ros
include/emscon_ros/ES_C_API_Def.h):

* SetStationOrientationParams / SetTransformationParams (commands 12-15) store a StationOrientationDataT
  (dVal1-3, dRot1-3) and a TransformationDataT (the same plus dScale); the controller keeps them for
  the next client. SystemSettingsDataT's bApplyStationOrientationParams / bApplyTransformationParams
  say whether results are given in that frame ("If FALSE the station orientation will be 0.0, ...").
  ``foreign_frame`` starts the fake with both applied and not the identity, as another client may leave
  them. How the controller composes the six or seven numbers is not public: this fake rotates about
  X, then Y, then Z (angles in the current angle unit), scales and shifts; any non-identity frame
  moves the points, which is all a test of the driver needs. ``frame_held`` is a defect for ``ritactl
  commission``'s test, not a documented behaviour: another client on the controller holds its frame (sets it
  and applies it again whenever a client changes a frame or the settings), so no connect can clear it.
* ES_SP_TcpDataPacketRate (400): "Between 3 and 10 packets per second (LTD706 and later!)", set with
  SetLongSystemParameter (120) and read with GetLongSystemParameter (121). Outside 3-10 the fake
  answers Parameter2OutOfRangeNOK (the value is the command's second parameter); a parameter id it
  does not model answers WrongParameter1. Its power-on rate (``packet_rate_hz``) is not documented.
* A beam break during a continuous measurement: an ErrorResponse for StartMeasurement (beckjac/emscon_ros
  src/main.cpp: error packets arrive "e.g. on beam break") and MeasStatus_NotReady; the stream ends.
  A reflector brought back into the beam is locked again with MeasStatus_Ready; the stream stays off
  until the client starts it again (whether a real server resumes by itself is not documented; the
  driver handles both).
"""
from __future__ import annotations

import math
from typing import Any, Protocol

import numpy as np

from drivers.emscon.codec import encode_error, encode_status_change
from drivers.emscon.enums import ES_Command as C
from drivers.emscon.enums import ES_ResultStatus as RS
from drivers.emscon.enums import ES_SystemStatusChange as SSC

TCP_DATA_PACKET_RATE = 400  # ES_SP_TcpDataPacketRate
PACKET_RATES = range(3, 11)  # 3-10 packets per second
#: a frame another client might leave: a station 2 m away and turned 30 degrees, a shifted transformation
FOREIGN_ORIENTATION = (2000.0, -500.0, 150.0, 0.0, 0.0, 30.0)
FOREIGN_TRANSFORMATION = (100.0, 50.0, -20.0, 0.0, 0.0, -5.0, 1.0)
ORIENTATION_KEYS = ("val1", "val2", "val3", "rot1", "rot2", "rot3")
TRANSFORMATION_KEYS = ORIENTATION_KEYS + ("scale",)
Reply = tuple[int, dict[str, Any], list[bytes]]


class _Host(Protocol):
    """What the mixin needs of FakeTrackerServer."""

    model: Any
    packet_rate_hz: float
    session: Any
    frame_held: bool

    def preset_foreign_frame(self) -> None: ...


def _rotation(rx: float, ry: float, rz: float) -> np.ndarray:
    """Rotation about X, then Y, then Z (radians)."""
    cx, sx = math.cos(rx), math.sin(rx)
    cy, sy = math.cos(ry), math.sin(ry)
    cz, sz = math.cos(rz), math.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _apply(xyz_mm: np.ndarray, frame: tuple[float, ...], deg_per_unit: float) -> np.ndarray:
    """``scale · R · p + t`` of one frame (t in mm, angles in the client's angle unit)."""
    t, rot = np.array(frame[:3]), [math.radians(a * deg_per_unit) for a in frame[3:6]]
    scale = frame[6] if len(frame) > 6 else 1.0
    return scale * (xyz_mm @ _rotation(*rot).T) + t


class FrameCommands:
    """Command handlers and state for frames and system parameters (mixed into FakeTrackerServer)."""

    def preset_foreign_frame(self: _Host) -> None:
        """Start as another client left the controller: both frames set and applied."""
        st = self.model.state
        st.orientation, st.transformation = FOREIGN_ORIENTATION, FOREIGN_TRANSFORMATION
        st.settings.update(apply_station_orientation_params=1, apply_transformation_params=1)

    def in_client_frame(self: _Host, xyz_mm: np.ndarray) -> np.ndarray:
        """Points (mm, tracker frame) as the client receives them: in whatever frame is applied."""
        st = self.model.state
        deg = 1.0 / st.angle_unit()
        out = np.asarray(xyz_mm, dtype=float)
        if st.settings["apply_station_orientation_params"]:
            out = _apply(out, st.orientation, deg)
        if st.settings["apply_transformation_params"]:
            out = _apply(out, st.transformation, deg)
        return out

    def held_again(self: _Host) -> None:
        """``frame_held``: the other client sets its frame back after any change."""
        if self.frame_held:
            self.preset_foreign_frame()

    async def _c_SetStationOrientationParams(self: _Host, s: Any, v: dict) -> Reply:
        self.model.state.orientation = tuple(float(v[k]) for k in ORIENTATION_KEYS)
        FrameCommands.held_again(self)
        return 0, {}, [encode_status_change(SSC.StationOrientationParamsChanged)]

    async def _c_GetStationOrientationParams(self: _Host, s: Any, v: dict) -> Reply:
        return 0, dict(zip(ORIENTATION_KEYS, self.model.state.orientation)), []

    async def _c_SetTransformationParams(self: _Host, s: Any, v: dict) -> Reply:
        if not v["scale"] > 0:
            return RS.WrongParameter7, {}, []
        self.model.state.transformation = tuple(float(v[k]) for k in TRANSFORMATION_KEYS)
        FrameCommands.held_again(self)
        return 0, {}, [encode_status_change(SSC.TransformationParamsChanged)]

    async def _c_GetTransformationParams(self: _Host, s: Any, v: dict) -> Reply:
        return 0, dict(zip(TRANSFORMATION_KEYS, self.model.state.transformation)), []

    async def _c_SetLongSystemParameter(self: _Host, s: Any, v: dict) -> Reply:
        if v["system_param"] != TCP_DATA_PACKET_RATE:
            return RS.WrongParameter1, {}, []
        if v["parameter"] not in PACKET_RATES:
            return RS.Parameter2OutOfRangeNOK, {}, []
        self.packet_rate_hz = float(v["parameter"])
        return 0, {}, []

    async def _c_GetLongSystemParameter(self: _Host, s: Any, v: dict) -> Reply:
        if v["system_param"] != TCP_DATA_PACKET_RATE:
            return RS.WrongParameter1, {}, []
        return 0, {"system_param": TCP_DATA_PACKET_RATE, "parameter": round(self.packet_rate_hz)}, []

    async def break_beam(self: _Host) -> None:
        """The beam is interrupted: no lock; a running stream ends with an ErrorResponse."""
        self.model.state.locked = None
        s = self.session
        if s is not None:
            if s.stream is not None and not s.stream.done():
                s.stream.cancel()
                s.stream = None
                await s.send_quiet(encode_error(C.StartMeasurement, RS.MeasurementStatusNotReady))
            await s.send_quiet(encode_status_change(SSC.MeasStatus_NotReady))

    async def restore_beam(self: _Host, name: str) -> None:
        """The reflector is back in the beam and locked again (MeasStatus_Ready)."""
        self.model.lock(name)
        if self.session is not None:
            await self.session.send_quiet(encode_status_change(SSC.MeasStatus_Ready))
