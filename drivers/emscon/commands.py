"""emScon TPI command layouts: each command's request and answer fields (Leica's ES_C_API_Def.h, V3.6).

The table the codec packs and unpacks with (``drivers.emscon.codec``); field names are the
header's without their type prefix. Layouts of commands 12-15 (station orientation and
transformation) and 120/121 (long system parameters) as in Leica's header published in
``beckjac/emscon_ros`` (include/emscon_ros/ES_C_API_Def.h).
"""
from __future__ import annotations

from drivers.emscon.enums import ES_Command

Fields = tuple[tuple[str, str], ...]  # (name, code): "i" int32, "d" double, "s" UTF-16 [32]


def parse_fields(spec: str) -> Fields:
    """Parse ``"a:i b:d"`` into a field tuple (keeps the tables below compact)."""
    pairs = [item.split(":") for item in spec.split()]
    return tuple((name, code) for name, code in pairs)


_UNITS = parse_fields("length_unit:i angle_unit:i temperature_unit:i pressure_unit:i humidity_unit:i")
ENV_FIELDS = parse_fields("temperature:d pressure:d humidity:d")
_SETTINGS = parse_fields(
    "weather_monitor_status:i apply_transformation_params:i apply_station_orientation_params:i "
    "keep_last_position:i send_unsolicited_messages:i send_reflector_position_data:i try_measurement_mode:i "
    "has_nivel:i has_video_camera:i")
XYZ_FIELDS = parse_fields("val1:d val2:d val3:d")
#: StationOrientationDataT and TransformationDataT (ES_C_API_Def.h): the identity is all zeros, scale 1
_ORIENTATION = XYZ_FIELDS + parse_fields("rot1:d rot2:d rot3:d")
_TRANSFORMATION = _ORIENTATION + parse_fields("scale:d")

#: command -> (request fields after the 12-byte prefix, answer fields after the 16-byte prefix)
COMMANDS: dict[ES_Command, tuple[Fields, Fields]] = {
    ES_Command.ExitApplication: ((), ()),
    ES_Command.GetSystemStatus: ((), parse_fields(
        "last_result_status:i tracker_processor_status:i laser_status:i adm_status:i major_version:i "
        "minor_version:i build_number:i weather_monitor_status:i flags_value:i tracker_serial_number:i")),
    ES_Command.GetTrackerStatus: ((), parse_fields("tracker_status:i")),
    ES_Command.SetUnits: (_UNITS, ()),
    ES_Command.GetUnits: ((), _UNITS),
    ES_Command.Initialize: ((), ()),
    ES_Command.SwitchLaser: (parse_fields("is_on:i"), ()),
    ES_Command.SetStationOrientationParams: (_ORIENTATION, ()),
    ES_Command.GetStationOrientationParams: ((), _ORIENTATION),
    ES_Command.SetTransformationParams: (_TRANSFORMATION, ()),
    ES_Command.GetTransformationParams: ((), _TRANSFORMATION),
    ES_Command.SetEnvironmentParams: (ENV_FIELDS, ()),
    ES_Command.GetEnvironmentParams: ((), ENV_FIELDS),
    ES_Command.SetMeasurementMode: (parse_fields("meas_mode:i"), ()),
    ES_Command.GetMeasurementMode: ((), parse_fields("meas_mode:i")),
    ES_Command.SetCoordinateSystemType: (parse_fields("coord_sys_type:i"), ()),
    ES_Command.GetCoordinateSystemType: ((), parse_fields("coord_sys_type:i")),
    ES_Command.SetStationaryModeParams: (parse_fields("meas_time_ms:i use_adm:i"), ()),
    ES_Command.GetStationaryModeParams: ((), parse_fields("meas_time_ms:i use_adm:i")),
    ES_Command.SetContinuousTimeModeParams: (
        parse_fields("time_separation_ms:i number_of_points:i use_region:i region_type:i"), ()),
    ES_Command.SetReflector: (parse_fields("reflector_id:i"), ()),
    ES_Command.GetReflector: ((), parse_fields("reflector_id:i")),
    ES_Command.GetReflectors: ((), parse_fields(
        "total_reflectors:i reflector_id:i target_type:i surface_offset:d name:s")),
    ES_Command.SetSearchParams: (parse_fields("search_radius:d timeout_ms:i"), ()),
    ES_Command.SetSystemSettings: (_SETTINGS, ()),
    ES_Command.GetSystemSettings: ((), _SETTINGS),
    ES_Command.StartMeasurement: ((), ()),
    ES_Command.StopMeasurement: ((), ()),
    ES_Command.GoBirdBath: ((), ()),
    ES_Command.GoPosition: (XYZ_FIELDS + parse_fields("use_adm:i"), ()),
    ES_Command.PointLaser: (XYZ_FIELDS, ()),
    ES_Command.FindReflector: (parse_fields("approx_distance:d"), ()),
    ES_Command.GetDirection: ((), parse_fields("hz_angle:d vt_angle:d")),
    ES_Command.SetLongSystemParameter: (parse_fields("system_param:i parameter:i"), ()),
    ES_Command.GetLongSystemParameter: (parse_fields("system_param:i"),
                                        parse_fields("system_param:i parameter:i")),
    ES_Command.GetTrackerInfo: ((), parse_fields(
        "tracker_type:i tracker_name:s serial_number:i compensation_id:i has_adm:i "
        "has_overview_camera:i has_nivel:i nivel_mount_offset:d max_distance:d min_distance:d "
        "max_data_rate:i number_of_faces:i hz_angle_range:d vt_angle_range:d accuracy_model:i "
        "fw_major:i fw_minor:i")),
}
