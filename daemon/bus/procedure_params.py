"""The guided procedures' parameters (``calib.start``'s ``params``), declared once.

The worker takes its defaults from here (``DEFAULTS``, daemon/worker/procedures.py), ritactl's
procedure verbs their option defaults, and the console builds its per-procedure form from
``schema()`` and re-validates what the page sends with ``check_params`` (the page is never
trusted). ritad checks every new job's ``params`` again with ``check_params`` before it queues
the job: the daemon is the authority, the clients' checks only answer earlier.

Kinds beyond the command table's scalar types: ``vec`` (``length`` finite numbers, e.g. an
approximate x, y) and ``file`` (a JSON definition: on the bus the object itself, as ritactl
sends the file it read; in the console a data-dir path on the robot, read and parsed there,
empty meaning the robot's installed file named by ``installed``). Values are checked by
:meth:`Arg.checked`, the command table's own path, which ``Param`` extends with those kinds.
Stdlib only, like the table.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any, Callable

from daemon.bus.command_table import PROCEDURES, REQUIRED, Arg, BadValue
from daemon.bus.protocol import CommandError, ErrorCode


@dataclass(frozen=True)
class Param(Arg):
    """A procedure parameter: an :class:`Arg` whose ``type`` may also be ``vec`` or ``file``."""

    length: int = 0          # vec: how many numbers
    installed: str = ""      # file: the robot's installed file the worker uses when none is given
    content: str = "object"  # file: "object", or "xyz_map" ({name: [x, y, z]})

    def checked(self, value: Any, noun: str = "parameter", paths: bool = True) -> Any:
        """As :meth:`Arg.checked`, plus ``vec`` and ``file``: a file is its parsed JSON object, or (``paths``)
        a data-dir path the console reads on the robot."""
        name = f"{noun} {self.name!r}"
        if self.type == "vec":
            if not isinstance(value, list) or len(value) != self.length:
                raise BadValue(f"{name} must be {self.length} numbers ({self.unit}), got {value!r:.80}")
            number = Arg(self.name, "float", self.help, unit=self.unit, lo=self.lo, hi=self.hi, lo_open=self.lo_open)
            return [number.checked(c, noun) for c in value]
        if self.type == "file":
            if paths and isinstance(value, str) and value.strip():
                return value.strip()
            if self.content == "xyz_map" and isinstance(value, dict):
                return xyz_map(name, value)
            if not isinstance(value, dict):
                where = "a data-dir file path or a JSON object" if paths else "the file's JSON object"
                raise BadValue(f"{name} must be {where}, got {value!r:.80}")
            return value
        return super().checked(value, noun)


def xyz_map(name: str, v: Any) -> dict[str, list[float]]:
    """``{name: [x, y, z]}`` with finite numbers, as floats."""
    if not isinstance(v, dict) or not v:
        raise BadValue(f"{name} must be a JSON object {{name: [x, y, z]}}, got {v!r:.80}")
    out = {}
    for key, xyz in v.items():
        if not (isinstance(xyz, list) and len(xyz) == 3 and all(isinstance(c, (int, float)) and not isinstance(c, bool)
                                                                and math.isfinite(c) for c in xyz)):
            raise BadValue(f"{name}: {key!r} must be [x, y, z] (3 numbers), got {xyz!r:.80}")
        out[str(key)] = [float(c) for c in xyz]
    return out


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
    """``bad_args`` about parameters: ``field`` names the first bad declared one (the console outlines
    that field) or is empty; ``fields`` names every bad one, unknown names included."""

    def __init__(self, message: str, field: str = "", fields: tuple[str, ...] = ()) -> None:
        super().__init__(ErrorCode.BAD_ARGS, message)
        self.field = field
        self.fields = fields or ((field,) if field else ())


def _bad(procedure: str, p: Param | None, text: str) -> ParamError:
    return ParamError(f"{procedure}: {text}", p.name if p else "")


def check_value(procedure: str, p: Param, v: Any, paths: bool = True) -> Any:
    """``v`` checked against ``p`` (:meth:`Param.checked`); ``bad_args`` names the procedure and parameter."""
    try:
        return p.checked(v, paths=paths)
    except BadValue as exc:
        raise _bad(procedure, p, str(exc)) from None


def check_params(procedure: str, params: Any, *, required: bool = True, paths: bool = True) -> dict[str, Any]:
    """The parameters checked; null or absent means the worker's default.

    ``bad_args`` names every bad parameter: wrong type, out of range, unknown, or (``required``)
    missing. ``paths``: a file parameter may be a data-dir path (the console's form); on the bus
    it is the file's JSON object, which is what the worker uses.
    """
    if procedure not in PARAMS:
        raise _bad(procedure, None, f"no such procedure (one of {', '.join(PROCEDURES)})")
    if not isinstance(params, dict):
        raise _bad(procedure, None, f"the parameters must be a JSON object, got {params!r:.80}")
    known = {p.name: p for p in PARAMS[procedure]}
    out: dict[str, Any] = {}
    bad: list[tuple[str, str]] = [(str(n), f"unknown parameter {n!r}") for n in params if n not in known]
    for name, p in known.items():
        v = params.get(name)
        try:
            if v is None or (p.type == "file" and v == ""):
                if p.required and required:
                    raise BadValue(f"parameter {name!r} is required ({p.help})")
                continue
            out[name] = p.checked(v, paths=paths)
        except BadValue as exc:
            bad.append((name, str(exc)))
    if bad:
        text = "; ".join(why for _, why in bad)
        if len(bad) > len([n for n, _ in bad if n in known]):
            text += f" (known: {', '.join(known)})"
        first = next((n for n, _ in bad if n in known), "")
        raise ParamError(f"{procedure}: {text}", first, tuple(n for n, _ in bad))
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
            try:
                obj = xyz_map(f"parameter {p.name!r}", obj)
            except BadValue as exc:
                raise _bad(procedure, p, f"{exc} (in {path})") from None
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
