"""The guided procedures' parameters (``calib.start``'s ``params``): the ``Param`` kind and the shared ones.

The procedures that use them are declared in daemon/bus/procedures.py, which also checks a
job's parameters (``check_params``) for ritad, the console and ritactl.

Kinds beyond the command table's scalar types: ``vec`` (``length`` finite numbers, e.g. an
approximate x, y) and ``file`` (a JSON definition: on the bus the object itself, as ritactl
sends the file it read; in the console a data-dir path on the robot, read and parsed there,
empty meaning the robot's installed file named by ``installed``). Values are checked by
:meth:`Arg.checked`, the command table's own path, which ``Param`` extends with those kinds.
Stdlib only, like the table.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from daemon.bus.args import REQUIRED, Arg, BadValue
from daemon.bus.protocol import CommandError, ErrorCode


@dataclass(frozen=True)
class Param(Arg):
    """A procedure parameter: an :class:`Arg` whose ``type`` may also be ``vec`` or ``file``."""

    length: int = 0          # vec: how many numbers
    installed: str = ""      # file: the robot's installed file the worker uses when none is given
    content: str = "object"  # file: "object", or "xyz_map" ({name: [x, y, z]})
    aliases: tuple[str, ...] = ()  # ritactl options besides --name-with-dashes (the names older scripts use)
    default_of: str = ""     # no value given: the resolved value of this earlier parameter ...
    default_by: tuple[tuple[Any, Any], ...] = ()  # ... looked up here (value → default), when given

    def value_of(self, resolved: dict[str, Any]) -> Any:
        """The default :meth:`Procedure.resolve` applies, given the earlier parameters' ``resolved`` values
        (None: the run decides, as ``default_text`` says: an installed file, the robot's heading, ...)."""
        if self.default_of:
            of = resolved[self.default_of]
            return dict(self.default_by).get(of) if self.default_by else of
        return None if self.required else self.default

    def python_type(self) -> Any:
        """The resolved value's type (a vec is a tuple; None where the run decides)."""
        kind = {"vec": tuple[float, ...], "file": dict[str, Any], "float": float, "int": int, "bool": bool,
                "str": str}[self.type]
        return kind if self.default is not None or self.default_of else kind | None

    def checked(self, value: Any, noun: str = "parameter", paths: bool = True) -> Any:
        """As :meth:`Arg.checked`, plus ``vec`` and ``file``: a file is its parsed JSON object, or (``paths``)
        a data-dir path the console reads on the robot."""
        name = f"{noun} {self.name!r}"
        if self.type == "vec":
            if not isinstance(value, list) or len(value) != self.length:
                raise BadValue(f"{name} must be {self.length} numbers ({self.unit}), got {value!r:.80}")
            number = Arg(self.name, "float", self.help, unit=self.unit, lo=self.lo, hi=self.hi,
                         lo_open=self.lo_open)
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
        point = isinstance(xyz, list) and len(xyz) == 3 and all(
            isinstance(c, (int, float)) and not isinstance(c, bool) and math.isfinite(c) for c in xyz)
        if not point:
            raise BadValue(f"{name}: {key!r} must be [x, y, z] (3 numbers), got {xyz!r:.80}")
        out[str(key)] = [float(c) for c in xyz]
    return out


_FLOAT = "float"
DISTANCE = Param("distance_mm", _FLOAT, "straight drive of each approach (referencing: between P0 and P1)",
                 unit="mm", default=200.0, lo=0, lo_open=True, aliases=("--distance",))
SPEED = Param("speed_mm_s", _FLOAT, "drive speed of the procedure's motions", unit="mm/s", default=100.0,
              lo=0, lo_open=True)
# no default: the computation states its own (referencing 10 µm; marks the tracker's MPE at its distance)
SIGMA_T = Param("sigma_t_mm", _FLOAT,
                "tracker 1σ per coordinate (referencing: nest-fit limit and uncertainty; "
                "marks: their stated σ)", unit="mm", lo=0, lo_open=True,
                default_text="referencing 0.01; "
                             "marks: ½ the tracker's MPE at its distance (docs/accuracy.md)")
KIND = Param("kind", "str", "mark shape", default="dot", choices=("dot", "cross"))
MARK_XY = Param("mark_xy", "vec", "approximate mark position, ACS x and y", unit="mm", default=REQUIRED,
                length=2, aliases=("--mark",))
MARK_SIZE = Param("mark_size_mm", _FLOAT, "mark size: dot radius or cross half-size", unit="mm", lo=0,
                  lo_open=True, default_text="0.4 for a dot, 0.6 for a cross", default_of=KIND.name,
                  default_by=(("dot", 0.4), ("cross", 0.6)))
IMU_READINGS = Param("imu_readings", "int",
                     "inclinometer readings averaged at each standstill (the tilt compensation)",
                     default=10, lo=1, hi=1000)
IMU_INTERVAL = Param("imu_interval_s", _FLOAT,
                     "time between those readings: the inclinometer's output period "
                     "(closer readings repeat one sample)", unit="s", default=0.1, lo=0, hi=10)
COMPENSATION = Param("compensation", "str",
                     "compensations: all, none, or a comma list of names (docs/accuracy.md, "
                     "\"Compensations\")", default="tilt,heading_fit,bias,mount")
APPROACH_SPEED = Param("approach_speed_mm_s", _FLOAT,
                       "speed of the recorded final move of each approach (more "
                       "stream points and inclinometer samples along it)", unit="mm/s", lo=0, lo_open=True,
                       default_text="speed_mm_s", default_of=SPEED.name)
STREAM_RATE = Param("stream_rate_hz", _FLOAT, "tracker stream rate on the final approach (heading_fit)",
                    unit="Hz", lo=0, hi=1000,
                    default_text="the tracker's configured rate ([tracker] stream_rate_hz); 0: none")
CALIBRATION = Param("calibration", "file", "calibration result to measure with",
                    installed="calibration/active.json", default_text="the active calibration")


class ParamError(CommandError):
    """``bad_args`` about parameters: ``field`` names the first bad declared one (the console outlines
    that field) or is empty; ``fields`` names every bad one, unknown names included."""

    def __init__(self, message: str, field: str = "", fields: tuple[str, ...] = ()) -> None:
        super().__init__(ErrorCode.BAD_ARGS, message)
        self.field = field
        self.fields = fields or ((field,) if field else ())
