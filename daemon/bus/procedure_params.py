"""The guided procedures' parameters (``calib.start``'s ``params``), declared once.

The worker takes its defaults from here (``DEFAULTS``, daemon/worker/procedures.py), ritactl's
procedure verbs their option defaults, and the console builds its per-procedure form from
``schema()`` and re-validates what the page sends with ``check_params`` (the page is never
trusted). The daemon itself passes ``params`` through unchanged, as it always did.

Kinds beyond the command table's scalar types: ``vec`` (``length`` finite numbers, e.g. an
approximate x, y) and ``file`` (a JSON definition: on the bus the object itself, as ritactl
sends the file it read; in the console a data-dir path on the robot, read and parsed there,
empty meaning the robot's installed file named by ``installed``). Stdlib only, like the table.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any, Callable

from daemon.bus.command_table import PROCEDURES, REQUIRED, Arg
from daemon.bus.protocol import CommandError, ErrorCode


@dataclass(frozen=True)
class Param(Arg):
    """A procedure parameter: an :class:`Arg` whose ``type`` may also be ``vec`` or ``file``."""

    length: int = 0          # vec: how many numbers
    installed: str = ""      # file: the robot's installed file the worker uses when none is given
    content: str = "object"  # file: "object", or "xyz_map" ({name: [x, y, z]})


_FLOAT = "float"
DISTANCE = Param("distance_mm", _FLOAT, "straight drive of each approach (referencing: between P0 and P1)",
                 unit="mm", default=200.0, lo=0, lo_open=True)
SPEED = Param("speed_mm_s", _FLOAT, "drive speed of the procedure's motions", unit="mm/s", default=100.0,
              lo=0, lo_open=True)
SIGMA_T = Param("sigma_t_mm", _FLOAT, "tracker 1σ per coordinate (nest-fit limit and uncertainty)", unit="mm",
                default=0.010, lo=0, lo_open=True)
KIND = Param("kind", "str", "mark shape", default="dot", choices=("dot", "cross"))
MARK_XY = Param("mark_xy", "vec", "approximate mark position, ACS x and y", unit="mm", default=REQUIRED, length=2)
MARK_SIZE = Param("mark_size_mm", _FLOAT, "mark size: dot radius or cross half-size", unit="mm", lo=0,
                  lo_open=True, default_text="0.4 for a dot, 0.6 for a cross")
IMU_READINGS = Param("imu_readings", "int", "inclinometer readings averaged at each standstill (issue #15 tilt)",
                     default=10, lo=1, hi=1000)
IMU_INTERVAL = Param("imu_interval_s", _FLOAT, "time between those readings: the inclinometer's output period "
                     "(closer readings repeat one sample)", unit="s", default=0.1, lo=0, hi=10)
# heading_fit is not in the default: through ritad it has not yet been shown to help (docs/accuracy.md)
COMPENSATION = Param("compensation", "str", "compensations: all, none, or a comma list of tilt, heading_fit, bias "
                     "(docs/accuracy.md)", default="tilt,bias")
APPROACH_SPEED = Param("approach_speed_mm_s", _FLOAT, "speed of the recorded final move of each approach (more "
                       "stream points and inclinometer samples along it)", unit="mm/s", lo=0, lo_open=True,
                       default_text="speed_mm_s")
STREAM_RATE = Param("stream_rate_hz", _FLOAT, "tracker stream rate on the final approach (heading_fit)", unit="Hz",
                    lo=0, hi=1000, default_text="the tracker's configured rate ([tracker] stream_rate_hz); 0: none")
#: the inputs of the compensations at mark stops (docs/operations.md, "Compensations")
ISSUE_15 = (COMPENSATION, IMU_READINGS, IMU_INTERVAL, STREAM_RATE, APPROACH_SPEED)
CALIBRATION = Param("calibration", "file", "calibration result to measure with", installed="calibration/active.json",
                    default_text="the active calibration")

PARAMS: dict[str, tuple[Param, ...]] = {
    "referencing": (
        Param("plate", "file", "plate definition (plate.json)", installed="calibration/plate.json",
              default_text="the installed plate"),
        Param("camera_model", "file", "camera model (camera_model.json)", installed="calibration/camera_model.json",
              default_text="the installed camera model"),
        Param("nests_approx_trk", "file", "approximate nests {red|green|blue: [x, y, z]}, tracker frame, mm",
              content="xyz_map", default_text="none: the worker asks for each nest"),
        Param("robot_approx_trk", "vec", "approximate robot reflector, tracker frame", unit="mm", length=3,
              default_text="none: the worker asks"),
        Param("reversal", "bool", "second referencing turned 180° (instrument reversal)", default=False),
        DISTANCE, SPEED, SIGMA_T, IMU_READINGS, IMU_INTERVAL),
    "intrinsics": (
        Param("board", "file", "the hand-held board's definition (board.json)", installed="calibration/board.json",
              default_text="the installed board"),),
    "measure-mark": (
        MARK_XY, KIND,
        Param("heading_deg", _FLOAT, "approach heading, ACS", unit="°", lo=-360, hi=360,
              default_text="the robot's current heading"),
        MARK_SIZE, CALIBRATION, DISTANCE, SPEED, SIGMA_T, *ISSUE_15),
    "experiment": (
        MARK_XY, KIND,
        Param("directions", "int", "approach directions", default=8, lo=1),
        Param("repetitions", "int", "repetitions per direction", default=5, lo=1),
        Param("seed", "int", "seed of the approach order and offsets", default=1, lo=0),
        Param("psi0_deg", _FLOAT, "heading of the first direction, ACS", unit="°", default=0.0, lo=-360, hi=360),
        Param("offset_mm", _FLOAT, "largest random offset of the mark from the image centre", unit="mm",
              default=3.0, lo=0),
        MARK_SIZE, CALIBRATION, DISTANCE, SPEED, SIGMA_T, *ISSUE_15,
        Param("store_bias", "bool", "store the fitted robot-frame bias b in the active calibration "
              "(docs/operations.md)", default=False)),
}
assert tuple(PARAMS) == PROCEDURES, "one parameter list per procedure of the command table"


def defaults() -> dict[str, Any]:
    """Every parameter's default by name (a name means one thing in every procedure)."""
    out: dict[str, Any] = {}
    for params in PARAMS.values():
        for p in params:
            if p.default is not None and not p.required:
                assert out.get(p.name, p.default) == p.default, f"{p.name}: two defaults"
                out[p.name] = p.default
    return out


DEFAULTS = defaults()


class ParamError(CommandError):
    """``bad_args`` about one parameter: ``field`` names it (the console outlines that field), or is empty."""

    def __init__(self, message: str, field: str = "") -> None:
        super().__init__(ErrorCode.BAD_ARGS, message)
        self.field = field


def _bad(procedure: str, p: Param | None, text: str) -> ParamError:
    return ParamError(f"{procedure}: {text}", p.name if p else "")


def _number(procedure: str, p: Param, v: Any, integer: bool) -> float | int:
    want = "an integer" if integer else "a number"
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (integer and not isinstance(v, int)):
        raise _bad(procedure, p, f"parameter {p.name!r} must be {want}{' (' + p.unit + ')' if p.unit else ''}, "
                                  f"got {v!r}")
    if not math.isfinite(v):
        raise _bad(procedure, p, f"parameter {p.name!r} must be finite, got {v!r}")
    if why := p.check(v):
        raise _bad(procedure, p, f"parameter {p.name!r}: {why}")
    return v if integer else float(v)


def _xyz_map(procedure: str, p: Param, v: Any) -> dict[str, list[float]]:
    if not isinstance(v, dict) or not v:
        raise _bad(procedure, p, f"parameter {p.name!r} must be a JSON object {{name: [x, y, z]}}, got {v!r:.80}")
    out = {}
    for name, xyz in v.items():
        if not (isinstance(xyz, list) and len(xyz) == 3 and all(isinstance(c, (int, float)) and not isinstance(c, bool)
                                                                and math.isfinite(c) for c in xyz)):
            raise _bad(procedure, p, f"parameter {p.name!r}: {name!r} must be [x, y, z] (3 numbers), got {xyz!r:.80}")
        out[str(name)] = [float(c) for c in xyz]
    return out


def check_value(procedure: str, p: Param, v: Any) -> Any:
    """``v`` checked against ``p``; a file parameter's value is a data-dir path (str) or the parsed object."""
    if p.type in ("float", "int"):
        return _number(procedure, p, v, p.type == "int")
    if p.type == "bool" and not isinstance(v, bool):
        raise _bad(procedure, p, f"parameter {p.name!r} must be true or false, got {v!r}")
    if p.type == "str" and (not isinstance(v, str) or (p.choices and v not in p.choices)):
        raise _bad(procedure, p, f"parameter {p.name!r}: {v!r} is not one of {', '.join(p.choices)}")
    if p.type == "vec":
        if not isinstance(v, list) or len(v) != p.length:
            raise _bad(procedure, p, f"parameter {p.name!r} must be {p.length} numbers ({p.unit}), got {v!r:.80}")
        return [_number(procedure, p, c, False) for c in v]
    if p.type == "file":
        if isinstance(v, str) and v.strip():
            return v.strip()
        if p.content == "xyz_map" and isinstance(v, dict):
            return _xyz_map(procedure, p, v)
        if not isinstance(v, dict):
            raise _bad(procedure, p, f"parameter {p.name!r} must be a data-dir file path or a JSON object, "
                                     f"got {v!r:.80}")
    return v


def check_params(procedure: str, params: Any) -> dict[str, Any]:
    """The parameters checked (``bad_args`` names the first bad one); null or absent: the worker's default."""
    if procedure not in PARAMS:
        raise _bad(procedure, None, f"no such procedure (one of {', '.join(PROCEDURES)})")
    if not isinstance(params, dict):
        raise _bad(procedure, None, f"the parameters must be a JSON object, got {params!r:.80}")
    known = {p.name: p for p in PARAMS[procedure]}
    unknown = sorted(set(params) - set(known))
    if unknown:
        raise _bad(procedure, None, f"unknown parameter {unknown[0]!r} (known: {', '.join(known)})")
    out = {}
    for name, p in known.items():
        v = params.get(name)
        if v is None or (p.type == "file" and v == ""):
            if p.required:
                raise _bad(procedure, p, f"parameter {name!r} is required ({p.help})")
            continue
        out[name] = check_value(procedure, p, v)
    return out


def load_files(procedure: str, params: dict[str, Any], read: Callable[[str], bytes]) -> dict[str, Any]:
    """``params`` (checked) with each file path replaced by the parsed JSON ``read(path)`` returns.

    ``read`` raises OSError/CommandError for a missing file; either becomes ``bad_args`` naming the parameter.
    """
    out = dict(params)
    for p in PARAMS[procedure]:
        path = out.get(p.name)
        if p.type != "file" or not isinstance(path, str):
            continue
        try:
            obj = json.loads(read(path))
        except (OSError, CommandError, ValueError) as exc:
            why = exc.args[0] if exc.args else type(exc).__name__
            raise _bad(procedure, p, f"parameter {p.name!r}: cannot use {path}: {why}") from None
        if p.content == "xyz_map":
            obj = _xyz_map(procedure, p, obj)
        elif not isinstance(obj, dict):
            raise _bad(procedure, p, f"parameter {p.name!r}: {path} is not a JSON object")
        out[p.name] = obj
    return out


def schema() -> dict[str, list[dict[str, Any]]]:
    """The form description the console page renders: per procedure, its parameters in order."""
    return {proc: [{"name": p.name, "kind": p.type, "help": p.help, "unit": p.unit, "required": p.required,
                    "default": None if p.required else p.default, "default_text": p.default_text,
                    "lo": p.lo, "hi": p.hi, "lo_open": p.lo_open, "range": p.range_text(),
                    "choices": list(p.choices), "length": p.length, "installed": p.installed}
                    for p in params] for proc, params in PARAMS.items()}


__all__ = ["DEFAULTS", "PARAMS", "Param", "ParamError", "check_params", "check_value", "load_files", "schema"]
