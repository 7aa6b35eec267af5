"""What the size of the product's code must not hide: long functions, long lines, copies.

Checked over calibration/, daemon/, drivers/ and fakes/, each check shown to catch a synthetic
offender:

* no function over ``MAX_FUNCTION`` lines: a function is read whole;
* no line over ``MAX_LINE`` characters in a file that has none today; the files that still have
  some are listed in ``LONG_LINES`` with their count, which may only go down (a file cleaned
  leaves the list), so a new long line fails wherever it is written;
* no module over ``MAX_MODULE`` lines: a file is split where its concepts part, not to a count
  (below the limit nothing is asked of a module's length);
* no block of six or more near-identical lines standing twice: the same code with at most other
  string or number literals (comments, blank lines and docstrings left out).

Layers and import cycles are tests/system/test_layers.py's.
"""
from __future__ import annotations

import ast
import io
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PRODUCT = ("calibration", "daemon", "drivers", "fakes")
MAX_MODULE, MAX_FUNCTION, MAX_LINE, MIN_BLOCK = 500, 60, 110, 6

#: files with lines over MAX_LINE characters (2026-11-28) and how many: the count may only go down,
#: and a file without any leaves the list (the test says which number to lower or which entry to drop)
LONG_LINES: dict[str, int] = {
}


def product_files() -> dict[str, str]:
    return {str(p.relative_to(ROOT)): p.read_text(encoding="utf-8")
            for pkg in PRODUCT for p in sorted((ROOT / pkg).rglob("*.py"))}


def oversized(files: dict[str, str]) -> list[str]:
    out = []
    for name, src in files.items():
        if (n := len(src.splitlines())) > MAX_MODULE:
            out.append(f"{name}: {n} lines > {MAX_MODULE}")
        for node in ast.walk(ast.parse(src)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                if (n := node.end_lineno - node.lineno + 1) > MAX_FUNCTION:
                    out.append(f"{name}:{node.lineno} {node.name}: {n} lines > {MAX_FUNCTION}")
    return out


def long_lines(files: dict[str, str], known: dict[str, int]) -> list[str]:
    """Files with more lines over MAX_LINE characters than ``known`` allows, or fewer than it records."""
    out = []
    for name, src in files.items():
        lines = src.splitlines()
        n = sum(len(line) > MAX_LINE for line in lines)
        allowed = known.get(name, 0)
        if n > allowed:
            first = next(i for i, line in enumerate(lines, 1) if len(line) > MAX_LINE)
            out.append(f"{name}: {n} lines over {MAX_LINE} characters "
                       f"(allowed {allowed}; the first at line {first})")
        elif n < allowed:
            fix = f"lower LONG_LINES[{name!r}] to {n}" if n else f"drop {name!r} from LONG_LINES"
            out.append(f"{name}: {n} lines over {MAX_LINE} characters, {allowed} recorded: {fix}")
    out += [f"{name}: in LONG_LINES but gone: drop it" for name in sorted(known.keys() - files.keys())]
    return out


def code_lines(src: str) -> list[tuple[int, str]]:
    """(line number, normalised text) of each line with code: literals become placeholders;
    comments, imports and lines that hold only a string (docstrings) are dropped."""
    lines: dict[int, list[str]] = {}
    fstring = 0  # Python >= 3.12 splits f-strings into parts: the whole f-string is one literal
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):
        kind = tokenize.tok_name[tok.type]
        if kind in ("COMMENT", "NL", "NEWLINE", "INDENT", "DEDENT", "ENDMARKER"):
            continue
        if kind in ("FSTRING_START", "FSTRING_END"):
            fstring += 1 if kind == "FSTRING_START" else -1
            text = "'S'" if kind == "FSTRING_START" else ""
        elif fstring:
            continue
        else:
            text = {"STRING": "'S'", "NUMBER": "0"}.get(kind, tok.string)
        if text:
            lines.setdefault(tok.start[0], []).append(text)
    return [(n, " ".join(t)) for n, t in sorted(lines.items())
            if t != ["'S'"] and t[0] not in ("import", "from")]


def repeated_blocks(files: dict[str, str]) -> list[str]:
    """Pairs of places sharing MIN_BLOCK consecutive normalised code lines."""
    first: dict[tuple[str, ...], tuple[str, int]] = {}
    found: dict[tuple[str, str], str] = {}
    for name, src in files.items():
        lines = code_lines(src)
        for i in range(len(lines) - MIN_BLOCK + 1):
            window = tuple(text for _, text in lines[i:i + MIN_BLOCK])
            if sum(len(t) > 12 for t in window) < MIN_BLOCK // 2:
                continue  # closing brackets, `else:`, `return x`: too thin to be a copy
            start = lines[i][0]
            if window not in first:
                first[window] = (name, start)
                continue
            other, other_start = first[window]
            if other == name and start - other_start < MIN_BLOCK * 2:
                continue  # overlapping runs of one repetitive block (a table)
            found.setdefault((other, name), f"{name}:{start} repeats {other}:{other_start}")
    return sorted(found.values())


def test_no_module_or_function_over_the_limit():
    assert oversized(product_files()) == []


def test_no_new_long_line():
    assert long_lines(product_files(), LONG_LINES) == []


def test_no_block_repeated():
    assert repeated_blocks(product_files()) == []


def test_the_checks_catch_offenders():
    body = "\n".join(f"    x{i} = compute(a, b, {i}, 'label {i}')" for i in range(61))
    long_fn = f"def f(a, b):\n{body}\n    return x0\n"
    assert oversized({"fakes/long.py": long_fn}) == ["fakes/long.py:1 f: 63 lines > 60"]
    assert oversized({"fakes/big.py": "x = 1\n" * 501}) == ["fakes/big.py: 501 lines > 500"]
    assert oversized({"fakes/fine.py": "x = 1\n" * 500}) == []
    block = "\n".join(f"    value_{i} = transform(source['key {i}'], factor={i})" for i in range(6))
    copy = block.replace("'key", "'other key").replace("factor=", "factor=1")  # other literals only
    files = {"fakes/a.py": f"def f(source):\n{block}\n",
             "fakes/b.py": f"def g(source):\n    '''doc'''\n{copy}\n"}
    assert repeated_blocks(files) == ["fakes/b.py:3 repeats fakes/a.py:2"]
    renamed = copy.replace("value_", "result_")  # other names: not a copy by this rule
    files = {"fakes/a.py": files["fakes/a.py"], "fakes/c.py": f"def g(source):\n{renamed}\n"}
    assert repeated_blocks(files) == []


def test_the_long_line_ratchet_catches_offenders():
    fine = "x = 1\n"
    long = "y = '" + "é" * (MAX_LINE - 5) + "'\n"  # MAX_LINE + 1 characters, more bytes: characters count
    at_limit = "y = '" + "é" * (MAX_LINE - 6) + "'\n"
    assert len(long) == MAX_LINE + 2 and long_lines({"fakes/ok.py": fine + at_limit}, {}) == []
    assert long_lines({"fakes/new.py": fine + long}, {}) == [
        f"fakes/new.py: 1 lines over {MAX_LINE} characters (allowed 0; the first at line 2)"]
    assert long_lines({"fakes/old.py": long * 2}, {"fakes/old.py": 2}) == []
    assert long_lines({"fakes/old.py": long * 3}, {"fakes/old.py": 2})[0].startswith("fakes/old.py: 3 lines")
    assert long_lines({"fakes/old.py": long}, {"fakes/old.py": 2}) == [
        f"fakes/old.py: 1 lines over {MAX_LINE} characters, 2 recorded: "
        "lower LONG_LINES['fakes/old.py'] to 1"]
    cleaned = long_lines({"fakes/old.py": fine}, {"fakes/old.py": 2})
    assert cleaned[0].endswith("drop 'fakes/old.py' from LONG_LINES")
    assert long_lines({}, {"fakes/gone.py": 1}) == ["fakes/gone.py: in LONG_LINES but gone: drop it"]


def test_the_longest_first_files_exist():
    from tests.conftest import LONGEST_FIRST

    missing = [p for p in LONGEST_FIRST if not (ROOT / p).is_file()]
    assert not missing, f"tests/conftest.py LONGEST_FIRST names files that are gone: {missing}"
