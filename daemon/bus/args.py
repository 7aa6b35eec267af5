"""A bus argument or procedure parameter: its type, range, unit, default and CLI shape, and the
one value check.

:class:`Arg` is shared by the command table (daemon/bus/command_table.py) and the procedures'
parameters (daemon/bus/procedures.py, ``Param`` extends it): one check (:meth:`Arg.checked`)
for every value a client sends. Stdlib only, so the laptop client imports it without numpy.
An argument's ``cli`` says how it appears on the command line: ``POS`` (a positional value,
shown as ``metavar``), ``--flag`` (an option; for a bool, the flag sets the opposite of the
default), or None (bus only). Ranges are inclusive unless ``lo_open``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

POS = "POS"
REQUIRED: Any = type("Required", (), {"__repr__": lambda self: "REQUIRED"})()


def _num(v: float) -> str:
    """1048576, not 1.04858e+06: a limit is quoted exactly."""
    return str(int(v)) if float(v).is_integer() and abs(v) < 1e15 else f"{v:g}"


@dataclass(frozen=True)
class Arg:
    name: str                      # key in the request's ``args``
    type: str                      # float | int | bool | str | map | any
    help: str
    unit: str = ""
    default: Any = None            # None: optional, the daemon decides (``default_text`` says how)
    default_text: str = ""
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    choices: tuple[str, ...] = ()
    cli: str | None = None         # POS, "--flag" or None
    metavar: str = ""

    @property
    def required(self) -> bool:
        return self.default is REQUIRED

    def range_text(self) -> str:
        lo, hi = self.lo, self.hi
        if hi is None:
            return "" if lo is None else f"{'>' if self.lo_open else '≥'} {_num(lo)}"
        if lo is None:
            return f"≤ {_num(hi)}"
        return f"{'(' if self.lo_open else '['}{_num(lo)}, {_num(hi)}]"

    def check(self, value: float) -> str | None:
        """Why ``value`` is out of range, or None."""
        too_low = self.lo is not None and (value <= self.lo if self.lo_open else value < self.lo)
        if too_low or (self.hi is not None and value > self.hi):
            word = "outside" if self.lo is not None and self.hi is not None else "not"
            return f"{_num(value)} is {word} {self.range_text()}{' ' + self.unit if self.unit else ''}"
        return None

    def kind_text(self) -> str:
        return self.type + (f" ({self.unit})" if self.unit else "")

    def checked(self, value: Any, noun: str = "argument") -> Any:
        """``value`` checked (type, finiteness, range, choices; ints become floats for float args):
        the one check of the command table and of the procedures' parameters (``Param``);
        :class:`BadValue` says why."""
        name = f"{noun} {self.name!r}"
        if not _is_of_type(value, self.type):
            raise BadValue(f"{name} must be {self.kind_text()}: {_TYPE_WORDS[self.type]}, got {value!r:.80}")
        if self.type == "float":
            # msgpack ints beyond 2**63 still fit a float; a JSON int may not
            value = float(value) if not isinstance(value, int) or abs(value) < 1e308 else math.inf
            if not math.isfinite(value):
                raise BadValue(f"{name} must be finite, got {value!r}")
        if self.type in ("float", "int") and (why := self.check(value)):
            raise BadValue(f"{name}: {why}")
        if self.choices and value not in self.choices:
            raise BadValue(f"{name}: {value!r:.80} is not one of {', '.join(self.choices)}")
        return value


class BadValue(ValueError):
    """Why a value does not fit its :class:`Arg`; the caller adds the command or procedure."""


_PY_TYPES: dict[str, tuple[type, ...]] = {"float": (float, int), "int": (int,), "bool": (bool,),
                                          "str": (str,), "map": (dict,), "any": (object,)}


def _is_of_type(value: Any, type_name: str) -> bool:
    """``value`` is of the argument type ``type_name`` (a bool is no number)."""
    if isinstance(value, bool) and type_name not in ("bool", "any"):
        return False
    return isinstance(value, _PY_TYPES[type_name])


_TYPE_WORDS = {"float": "a number", "int": "an integer", "bool": "true or false", "str": "a string",
               "map": "a JSON object", "any": "anything"}
