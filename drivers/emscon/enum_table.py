"""docs/emscon.md's enum table, generated from :mod:`drivers.emscon.enums` (values, names, docstrings).

``python -m drivers.emscon.enum_table --markdown`` prints it; a test compares it with the doc.
A module of its own so that ``-m`` does not run the enums a second time as ``__main__``.
"""
from __future__ import annotations

import sys
from enum import IntEnum

from drivers.emscon import enums

#: every enum of the protocol, in definition order (the table's rows)
ENUMS: tuple[type[IntEnum], ...] = tuple(
    v for v in vars(enums).values()
    if isinstance(v, type) and issubclass(v, IntEnum) and v.__module__ == enums.__name__)


def markdown_table() -> str:
    """One row per enum: its name, what it is for (its docstring) and every value with its name."""
    rows = ["| enum | what it is | values |", "|---|---|---|"]
    for cls in ENUMS:
        if not cls.__doc__:
            raise ValueError(f"{cls.__name__} has no docstring: say what it is for, it is the table's cell")
        values = ", ".join(f"{int(m)} `{m.name}`" for m in cls)
        what = " ".join(cls.__doc__.split())  # a docstring wrapped over lines is one table cell
        rows.append(f"| `{cls.__name__}` | {what} | {values} |")
    return "\n".join(rows) + "\n"


if __name__ == "__main__":
    if sys.argv[1:] != ["--markdown"]:
        sys.exit("usage: python -m drivers.emscon.enum_table --markdown")
    sys.stdout.write(markdown_table())
