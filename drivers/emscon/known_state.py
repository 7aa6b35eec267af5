"""What every connect sets so that no state another client left survives (``EmsconTracker.open``).

A tracker controller keeps its settings across clients: a program such as an inspection package
may leave a station orientation or a transformation applied, and then every point arrives in that
program's frame with nothing saying so. Public clients set both to the identity (beckjac/emscon_ros
src/main.cpp: SetStationOrientationParams(0, 0, 0, 0, 0, 0), SetTransformationParams(0, 0, 0, 0, 0,
0, 1)); this driver also switches both off (SystemSettingsDataT bApplyTransformationParams,
bApplyStationOrientationParams: "If FALSE the station orientation will be 0.0 ...", Leica's
ES_C_API_Def.h as published in beckjac/emscon_ros include/emscon_ros/ES_C_API_Def.h).
"""
from __future__ import annotations

import logging
from typing import Any

from drivers.base import DeviceError, DeviceLost
from drivers.emscon.client import EmsconClient
from drivers.emscon.enums import ES_Command, ES_SystemParameter, ES_WeatherMonitorStatus, enum_name

log = logging.getLogger(__name__)
#: ES_SP_TcpDataPacketRate's range, packets per second (ES_C_API_Def.h: "Between 3 and 10 packets per
#: second (LTD706 and later!)"); the most packets give the clock map the most samples
PACKET_RATE_RANGE, DEFAULT_PACKET_RATE = (3, 10), 10
#: SystemSettingsDataT flags every connect sets: no frame another client left, events on
KNOWN_SETTINGS = {"apply_transformation_params": 0, "apply_station_orientation_params": 0,
                  "send_unsolicited_messages": 1}
#: identity station orientation (position 0, rotations 0) and transformation (scale 1)
IDENTITY_ORIENTATION = {"val1": 0.0, "val2": 0.0, "val3": 0.0, "rot1": 0.0, "rot2": 0.0, "rot3": 0.0}
IDENTITY_TRANSFORMATION = {**IDENTITY_ORIENTATION, "scale": 1.0}


def clear_frames(c: EmsconClient) -> None:
    """Points in the tracker's own frame whatever another client left: identity station orientation
    and transformation, neither applied; unsolicited messages on (beam breaks, lock changes)."""
    c.request(ES_Command.SetStationOrientationParams, **IDENTITY_ORIENTATION)
    c.request(ES_Command.SetTransformationParams, **IDENTITY_TRANSFORMATION)
    settings = {k: int(v) for k, v in c.request(ES_Command.GetSystemSettings).values.items()}
    if any(settings.get(k) != v for k, v in KNOWN_SETTINGS.items()):
        c.request(ES_Command.SetSystemSettings, **{**settings, **KNOWN_SETTINGS})


def set_packet_rate(c: EmsconClient, rate: int, where: str) -> int | None:
    """Stream packets per second (ES_SP_TcpDataPacketRate), as the server reads it back; None when the
    server has no such parameter (before LTD706): its own rate stands, in the same documented range."""
    try:
        c.request(ES_Command.SetLongSystemParameter, system_param=ES_SystemParameter.TcpDataPacketRate,
                  parameter=rate)
        got = c.request(ES_Command.GetLongSystemParameter, system_param=ES_SystemParameter.TcpDataPacketRate)
    except DeviceLost:
        raise
    except DeviceError as exc:
        log.warning("tracker %s: stream packet rate not set (%s); the server's own rate (3-10/s) stands",
                    where, exc)
        return None
    return int(got["parameter"])


def read_back(c: EmsconClient) -> dict[str, Any]:
    """What the controller holds now, as ``ritactl commission`` checks it: the apply flags, station
    orientation and transformation (identity and off after every connect), the weather monitor's status and
    the environment the refraction uses, and the stream packet rate (None: no such parameter)."""
    settings = c.request(ES_Command.GetSystemSettings).values
    status = c.request(ES_Command.GetSystemStatus).values
    try:
        rate: int | None = int(c.request(ES_Command.GetLongSystemParameter,
                                         system_param=ES_SystemParameter.TcpDataPacketRate)["parameter"])
    except DeviceLost:
        raise
    except DeviceError:
        rate = None
    return {"apply_station_orientation_params": int(settings["apply_station_orientation_params"]),
            "apply_transformation_params": int(settings["apply_transformation_params"]),
            "station_orientation": dict(c.request(ES_Command.GetStationOrientationParams).values),
            "transformation": dict(c.request(ES_Command.GetTransformationParams).values),
            "weather_monitor_status": enum_name(ES_WeatherMonitorStatus, status["weather_monitor_status"]),
            "environment": dict(c.request(ES_Command.GetEnvironmentParams).values),
            "packet_rate": rate}
