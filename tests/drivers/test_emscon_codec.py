"""Golden layout tests and round trips for the emScon codec and framer.

The expected sizes and offsets are typed in from Leica's ES_C_API_Def.h (V3.6) as gcc lays
it out under ``#pragma pack(4)`` (measured with a small C program), not computed from the codec.
"""
from __future__ import annotations

import struct

import numpy as np
import pytest

from drivers.emscon import codec as C
from drivers.emscon.codec import (COMMANDS, MEAS_VALUE, MEAS_VALUE2, RESULTS, TO_CLIENT, TO_SERVER,
                                  ProtocolError, decode, encode, encode_answer, encode_error,
                                  encode_request, encode_result, encode_status_change, fields_struct)
from drivers.emscon.enums import ES_Command as Cmd
from drivers.emscon.enums import ES_DataType, ES_ResultStatus, ES_SystemStatusChange
from drivers.emscon.framer import Framer

# command -> (CT size, RT size), gcc with pack(4)
SIZES = {
    Cmd.GetSystemStatus: (12, 56), Cmd.GetTrackerStatus: (12, 20), Cmd.SetUnits: (32, 16),
    Cmd.GetUnits: (12, 36), Cmd.Initialize: (12, 16), Cmd.SetEnvironmentParams: (36, 16),
    Cmd.GetEnvironmentParams: (12, 40), Cmd.SetMeasurementMode: (16, 16),
    Cmd.SetCoordinateSystemType: (16, 16), Cmd.SetStationaryModeParams: (20, 16),
    Cmd.SetContinuousTimeModeParams: (28, 16), Cmd.SetReflector: (16, 16), Cmd.GetReflectors: (12, 100),
    Cmd.SetSearchParams: (24, 16), Cmd.SetSystemSettings: (48, 16), Cmd.GetSystemSettings: (12, 52),
    Cmd.StartMeasurement: (12, 16), Cmd.StopMeasurement: (12, 16), Cmd.GoBirdBath: (12, 16),
    Cmd.GoPosition: (40, 16), Cmd.PointLaser: (36, 16), Cmd.FindReflector: (20, 16),
    Cmd.GetDirection: (12, 32), Cmd.GetTrackerInfo: (12, 164),
}

OFFSETS = {  # (command, "ct"/"rt") -> {field: offset}
    (Cmd.GetSystemStatus, "rt"): {"last_result_status": 16, "tracker_processor_status": 20,
                                  "laser_status": 24, "adm_status": 28, "major_version": 32,
                                  "minor_version": 36, "build_number": 40, "weather_monitor_status": 44,
                                  "flags_value": 48, "tracker_serial_number": 52},
    (Cmd.SetUnits, "ct"): {"length_unit": 12, "angle_unit": 16, "temperature_unit": 20,
                           "pressure_unit": 24, "humidity_unit": 28},
    (Cmd.SetEnvironmentParams, "ct"): {"temperature": 12, "pressure": 20, "humidity": 28},
    (Cmd.SetStationaryModeParams, "ct"): {"meas_time_ms": 12, "use_adm": 16},
    (Cmd.SetContinuousTimeModeParams, "ct"): {"time_separation_ms": 12, "number_of_points": 16,
                                              "use_region": 20, "region_type": 24},
    (Cmd.GetReflectors, "rt"): {"total_reflectors": 16, "reflector_id": 20, "target_type": 24,
                                "surface_offset": 28, "name": 36},
    (Cmd.GoPosition, "ct"): {"val1": 12, "val2": 20, "val3": 28, "use_adm": 36},
    (Cmd.PointLaser, "ct"): {"val1": 12, "val2": 20, "val3": 28},
    (Cmd.FindReflector, "ct"): {"approx_distance": 12},
    (Cmd.GetDirection, "rt"): {"hz_angle": 16, "vt_angle": 24},
    (Cmd.SetSearchParams, "ct"): {"search_radius": 12, "timeout_ms": 20},
    (Cmd.GetTrackerInfo, "rt"): {"tracker_type": 16, "tracker_name": 20, "serial_number": 84,
                                 "compensation_id": 88, "has_adm": 92, "has_overview_camera": 96,
                                 "has_nivel": 100, "nivel_mount_offset": 104, "max_distance": 112,
                                 "min_distance": 120, "max_data_rate": 128, "number_of_faces": 132,
                                 "hz_angle_range": 136, "vt_angle_range": 144, "accuracy_model": 152,
                                 "fw_major": 156, "fw_minor": 160},
}

SINGLE = {"meas_mode": 12, "is_try_mode": 16, "val1": 20, "val2": 28, "val3": 36, "std1": 44,
          "std2": 52, "std3": 60, "std_total": 68, "pointing_error1": 76, "pointing_error2": 84,
          "pointing_error3": 92, "apriori_std1": 100, "apriori_std2": 108, "apriori_std3": 116,
          "apriori_std_total": 124, "temperature": 132, "pressure": 140, "humidity": 148}
SINGLE2 = {"val1": 20, "std1": 44, "std_total": 68, "covar12": 76, "covar13": 84, "covar23": 92,
           "pointing_error_h": 100, "pointing_error_v": 108, "pointing_error_d": 116,
           "apriori_std1": 124, "apriori_std_total": 148, "apriori_covar12": 156,
           "apriori_covar23": 172, "temperature": 180, "pressure": 188, "humidity": 196}
MULTI_HEAD = {"number_of_results": 12, "meas_mode": 16, "is_try_mode": 20, "temperature": 24,
              "pressure": 32, "humidity": 40}


@pytest.mark.parametrize("cmd", list(SIZES), ids=lambda c: c.name)
def test_command_sizes(cmd: Cmd) -> None:
    ct, rt = SIZES[cmd]
    assert len(encode_request(cmd)) == ct
    assert len(encode_answer(cmd, 0)) == rt
    assert struct.unpack_from("<i", encode_request(cmd))[0] == ct


def field_offsets(prefix_size: int, fields) -> dict[str, int]:
    """Byte offset of each field in the struct the codec packs: the size of the fields before it."""
    prefix = "i" * (prefix_size // 4)
    return {name: fields_struct(prefix, fields[:i]).size for i, (name, _) in enumerate(fields)}


@pytest.mark.parametrize("key", list(OFFSETS), ids=lambda k: f"{k[0].name}-{k[1]}")
def test_command_offsets(key: tuple[Cmd, str]) -> None:
    cmd, side = key
    fields = COMMANDS[cmd][0 if side == "ct" else 1]
    assert field_offsets(12 if side == "ct" else 16, fields) == OFFSETS[key]


def test_result_layouts() -> None:
    assert len(encode_result("single")) == 156
    assert len(encode_result("single2")) == 204
    assert len(encode_result("reflector_pos")) == 36
    assert len(encode_result("nivel")) == 40
    assert field_offsets(12, RESULTS[ES_DataType.SingleMeasResult]) == SINGLE
    got2 = field_offsets(12, RESULTS[ES_DataType.SingleMeasResult2])
    assert {k: got2[k] for k in SINGLE2} == SINGLE2
    assert field_offsets(12, RESULTS[ES_DataType.MultiMeasResult]) == MULTI_HEAD
    assert MEAS_VALUE.itemsize == 36 and MEAS_VALUE2.itemsize == 92
    assert [MEAS_VALUE.fields[n][1] for n in ("status", "time1", "time2", "val1", "val2", "val3")] == \
        [0, 4, 8, 12, 20, 28]
    assert MEAS_VALUE2.fields["apriori_std1"][1] == 36 and MEAS_VALUE2.fields["apriori_covar23"][1] == 84
    for n in (0, 1, 7):
        assert len(encode_result("multi", records=np.zeros(n, MEAS_VALUE))) == 48 + 36 * n
        assert len(encode_result("multi2", records=np.zeros(n, MEAS_VALUE2))) == 48 + 92 * n


def test_generic_packets_are_little_endian() -> None:
    assert (encode_error(Cmd.FindReflector, ES_ResultStatus.ModuleTimedOut)
            == struct.pack("<iiii", 16, 1, 63, 41))
    assert encode_status_change(ES_SystemStatusChange.MeasStatus_Ready) == struct.pack("<iii", 12, 8, 27)
    assert encode_request(Cmd.FindReflector, approx_distance=1.5) == struct.pack("<iiid", 20, 0, 63, 1.5)
    assert encode_answer(Cmd.Initialize, ES_ResultStatus.ServerBusy) == struct.pack("<iiii", 16, 0, 7, 1)


def _requests() -> list[bytes]:
    rng = np.random.default_rng(5)
    out = []
    for cmd, (ct, _) in COMMANDS.items():
        vals = {n: ("Refl ö" if c == "s" else int(rng.integers(-1000, 1000)) if c == "i"
                    else float(rng.normal(0, 1e3))) for n, c in ct}
        out.append(encode_request(cmd, **vals))
    return out


def _to_client() -> list[bytes]:
    rng = np.random.default_rng(6)
    out = []
    for cmd, (_, rt) in COMMANDS.items():
        vals = {n: ("AT901 name" if c == "s" else int(rng.integers(0, 9)) if c == "i"
                    else float(rng.normal(0, 1e3))) for n, c in rt}
        out.append(encode_answer(cmd, 0, **vals))
        out.append(encode_answer(cmd, ES_ResultStatus.TrackerNotInitialized))
    rec = np.zeros(5, MEAS_VALUE)
    rec["val1"], rec["time1"], rec["status"] = rng.normal(size=5), np.arange(5), [0, 1, 2, 3, 4]
    rec2 = np.zeros(3, MEAS_VALUE2)
    rec2["apriori_covar13"] = rng.normal(size=3)
    out += [encode_result("single", 0, val1=1.25, std_total=0.02, humidity=45.0, meas_mode=0),
            encode_result("single2", 0, val3=-3.5, apriori_covar23=1e-6, is_try_mode=1),
            encode_result("multi", 0, rec, temperature=21.5, meas_mode=1),
            encode_result("multi2", 0, rec2, pressure=990.0),
            encode_result("reflector_pos", 0, val1=1.0, val2=2.0, val3=3.0),
            encode_result("nivel", 0, nivel_status=1, x_tilt=1e-4, nivel_temperature=22.0),
            encode_error(Cmd.StartMeasurement, 10009), encode_status_change(151),
            encode_status_change(12345)]  # unknown change value: kept as an int
    return out


@pytest.mark.parametrize("direction,builder", [(TO_SERVER, _requests), (TO_CLIENT, _to_client)])
def test_round_trip_every_packet(direction: str, builder) -> None:
    for raw in builder():
        p = decode(raw, direction)
        assert encode(p) == raw, p.describe()


def test_decoded_values() -> None:
    p = decode(encode_answer(Cmd.GetReflectors, 0, total_reflectors=3, reflector_id=2, target_type=5,
                             surface_offset=19.05, name="RRR 1.5in"), TO_CLIENT)
    assert p.kind == "answer" and p.command == Cmd.GetReflectors
    assert p["name"] == "RRR 1.5in" and p["total_reflectors"] == 3 and p["surface_offset"] == 19.05
    s = decode(encode_result("single", 0, val1=1.5, val2=-2.5, val3=3.5), TO_CLIENT)
    assert (s["val1"], s["val2"], s["val3"]) == (1.5, -2.5, 3.5) and s.kind == "single"
    e = decode(encode_error(Cmd.GoPosition, 39), TO_CLIENT)
    assert e.kind == "error" and e.status == ES_ResultStatus.TrackerNotInitialized
    assert "TrackerNotInitialized" in e.describe()


def test_strings_utf16_cut_at_nul() -> None:
    raw = bytearray(encode_answer(Cmd.GetReflectors, 0, name="AB"))
    raw[36 + 6: 36 + 10] = "XY".encode("utf-16-le")  # junk after the terminating NUL
    assert decode(bytes(raw), TO_CLIENT)["name"] == "AB"
    with pytest.raises(ValueError, match="longer than 32"):
        encode_answer(Cmd.GetReflectors, 0, name="x" * 33)
    assert decode(encode_answer(Cmd.GetReflectors, 0, name="y" * 32), TO_CLIENT)["name"] == "y" * 32


def test_encode_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="bogus"):
        encode_request(Cmd.SetUnits, bogus=1)
    with pytest.raises(ValueError, match="32-bit"):
        encode_request(Cmd.SetStationaryModeParams, meas_time_ms=1 << 40)
    with pytest.raises(ValueError, match="result kind"):
        encode_result("nonsense")


@pytest.mark.parametrize("raw,direction,match", [
    (struct.pack("<i", 4), TO_CLIENT, "shorter than the 8-byte"),
    (struct.pack("<ii", 4, 0), TO_CLIENT, "does not match the 8"),
    (struct.pack("<iii", 12, 0, 7), TO_CLIENT, "shorter than BasicCommandRT"),
    (struct.pack("<iiii", 20, 0, 7, 0) + b"\0" * 4, TO_CLIENT, "Initialize answer"),
    (struct.pack("<iiii", 16, 0, 1, 0), TO_CLIENT, "GetSystemStatus answer"),  # OK status needs 56 B
    (struct.pack("<iiii", 20, 1, 7, 0) + b"\0" * 4, TO_CLIENT, "ErrorResponse"),
    (struct.pack("<iii", 16, 8, 1) + b"\0" * 4, TO_CLIENT, "SystemStatusChange"),
    (encode_result("multi", records=np.zeros(2, MEAS_VALUE))[:-1], TO_CLIENT, "does not match"),
    (encode_result("multi", records=np.zeros(2, MEAS_VALUE)) + b"\0" * 36, TO_CLIENT, "does not match"),
    (struct.pack("<iiiiiidddd", 48 + 36, 3, 0, 2, 1, 0, 0, 0, 0, 0)[:48] + b"\0" * 36, TO_CLIENT,
     "holds 1 records"),
    (struct.pack("<iii", 12, 5, 0), TO_CLIENT, "unsupported data type"),
    (struct.pack("<iii", 12, 77, 0), TO_CLIENT, "unsupported data type"),
    (struct.pack("<iii", 16, 0, 7) + b"\0" * 4, TO_SERVER, "Initialize request"),
    (struct.pack("<iii", 12, 2, 7), TO_SERVER, "only Command"),
    (struct.pack("<iii", 16, 0, 999) + b"\0" * 4, TO_SERVER, "unknown command 999"),
])
def test_decode_rejects(raw: bytes, direction: str, match: str) -> None:
    with pytest.raises(ProtocolError, match=match):
        decode(raw, direction)


def test_multi_size_not_48_plus_36n() -> None:
    raw = struct.pack("<iii", 48 + 35, 3, 0) + b"\0" * (48 + 35 - 12)
    with pytest.raises(ProtocolError, match=r"48 \+ 36"):
        decode(raw, TO_CLIENT)


def test_framer_split_and_merged() -> None:
    stream = b"".join(_to_client())
    expected = [decode(r, TO_CLIENT).describe() for r in _to_client()]
    for step in (1, 3, 7, 64, len(stream)):
        f = Framer(TO_CLIENT)
        got = []
        for i in range(0, len(stream), step):
            got += [p.describe() for p in f.feed(stream[i:i + step])]
        assert got == expected and f.pending == 0


@pytest.mark.parametrize("size", [0, 7, -1, (1 << 20) + 1, 0x7FFFFFFF])
def test_framer_bad_size_is_sticky(size: int) -> None:
    f = Framer(TO_CLIENT)
    good = encode_status_change(1)
    assert len(f.feed(good)) == 1
    with pytest.raises(ProtocolError, match=str(size)):
        f.feed(struct.pack("<i", size) + b"\0" * 8)
    with pytest.raises(ProtocolError):
        f.feed(good)  # the stream cannot be resynchronised


def test_framer_accepts_large_multi() -> None:
    rec = np.zeros(20000, MEAS_VALUE)
    rec["val1"] = np.arange(20000)
    raw = encode_result("multi", 0, rec)
    assert len(raw) > 65536
    (p,) = Framer(TO_CLIENT).feed(raw)
    assert p.records is not None and p.records["val1"][-1] == 19999


def test_bad_direction() -> None:
    with pytest.raises(ValueError, match="direction"):
        Framer("sideways")
    assert C.MAX_PACKET == 1 << 20
