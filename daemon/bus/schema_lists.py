"""The dataset schemas' procedure lists, generated from the declarations (daemon/bus/procedures.py).

The schemas stay static files: readers we did not write use them as they are (jsonschema,
``ritactl validate`` on a laptop without this package's code, a customer's own tools), so the
lists stay written out in them. This module writes those lists: each is one line (or, for a
schema's ``allOf``, the lines of its per-procedure dispatch) rewritten in place, so the
hand-written rest of a file and its layout are untouched. What a procedure's obs or result holds
is hand-written under ``$defs`` as ``obs_<name>`` and ``result_<name>`` (``-`` as ``_``); the
dispatch points each procedure there. After adding a procedure, ``python -m
daemon.bus.schema_lists --write``; a test fails while a file differs from what this writes.
Stdlib only, like the declarations.
"""
from __future__ import annotations

import json
import re
import sys
from pathlib import Path

from daemon.bus.names import JobState
from daemon.bus.procedures import PROCEDURES
from daemon.bus.storage import atomic_write_text

SCHEMAS = Path(__file__).resolve().parent / "schemas"
#: state.json's statuses: the states a worker writes (queued and waiting only ritad knows)
STATUSES = tuple(s.value for s in JobState if s not in (JobState.QUEUED, JobState.WAITING))
#: a schema's top-level ``allOf``: the per-procedure dispatch, nothing else
_ALL_OF = re.compile(r'^  "allOf": \[\n(.*?)\n  \],$', re.M | re.S)


def ident(name: str) -> str:
    """A procedure's name as a ``$defs`` key suffix."""
    return name.replace("-", "_")


def _line(key: str) -> re.Pattern[str]:
    """A top-level property's one-line enum."""
    return re.compile(rf'^    "{key}": {{"enum": (\[[^\]\n]*\])}},$', re.M)


def _dispatch(then: str) -> str:
    """One ``if procedure is X then …`` line per procedure; ``then`` takes its ``$defs`` suffix."""
    return ",\n".join(f'    {{"if": {{"properties": {{"procedure": {{"const": {json.dumps(n)}}}}}, '
                      f'"required": ["procedure"]}}, "then": {then.format(ident(n))}}}' for n in PROCEDURES)


def rules() -> dict[str, list[tuple[re.Pattern[str], str]]]:
    """Per schema file: (the pattern of a generated fragment, its group 1 the text; that text)."""
    names = json.dumps(list(PROCEDURES))
    obs = '{{"properties": {{"obs": {{"$ref": "#/$defs/obs_{}"}}}}}}'  # state.json: the obs of each procedure
    kind = re.compile(r'"pattern": "\^\(captures\|procedure:\(([^)"]*)\)\)\$"')
    return {
        "state.schema.json": [(_line("procedure"), names),
                              (_line("status"), json.dumps(list(STATUSES))),
                              (_ALL_OF, _dispatch(obs))],
        "result.schema.json": [(_line("procedure"), names),
                               (_ALL_OF, _dispatch('{{"$ref": "#/$defs/result_{}"}}'))],
        "dataset.schema.json": [(kind, "|".join(PROCEDURES))],
    }


def _each(file: str, text: str, fill: bool) -> str:
    for pattern, value in rules()[file]:
        m = pattern.search(text)
        if m is None:
            raise ValueError(f"{file}: no {pattern.pattern!r} to write the procedure list into")
        text = text[:m.start(1)] + (value if fill else "") + text[m.end(1):]
    return text


def generated(file: str, text: str) -> str:
    """``text`` of schema ``file`` with its procedure lists as the declarations give them."""
    return _each(file, text, True)


def blanked(file: str, text: str) -> str:
    """``text`` without the generated lists: what is written by hand (a test: no procedure name in it)."""
    return _each(file, text, False) if file in rules() else text


def main(argv: list[str]) -> int:
    if argv not in (["--write"], ["--check"]):
        print("usage: python -m daemon.bus.schema_lists --write | --check", file=sys.stderr)
        return 2
    stale = []
    for file in rules():
        path = SCHEMAS / file
        text = path.read_text(encoding="utf-8")
        if generated(file, text) != text:
            stale.append(file)
            if argv == ["--write"]:
                atomic_write_text(path, generated(file, text))
    print(("written: " if argv == ["--write"] else "stale: ") + (", ".join(stale) or "none"))
    return 1 if stale and argv == ["--check"] else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
