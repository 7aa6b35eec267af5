"""Checked hints: mypy finds nothing in daemon/, drivers/ and calibration/ (issue #23).

The configuration and its strictness are pyproject.toml's ``[tool.mypy]``; docs/architecture.md,
"Checked hints", says what they check and why. The run is cold every time: no cache is read or
written (``--cache-dir`` is the null device), so no earlier run, other checkout or other mypy
version can change the answer, and nothing is left in the tree. It takes ~10 s on two cores.
"""
from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
CHECKED = ["daemon", "drivers", "calibration"]


def test_mypy_checks_the_product_packages():
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["mypy"]
    assert config["files"] == CHECKED
    # an untyped third-party package is named in an override; ignoring every missing import would
    # also hide a misspelt module of ours
    assert "ignore_missing_imports" not in config


def test_mypy_finds_no_errors():
    if importlib.util.find_spec("mypy") is None:
        pytest.skip("mypy is not installed (it is in the test extra: pip install -e '.[robot,test]')")
    env = {k: v for k, v in os.environ.items() if k not in ("MYPYPATH", "MYPY_CACHE_DIR", "MYPY_FORCE_COLOR")}
    out = subprocess.run([sys.executable, "-m", "mypy", "--config-file", "pyproject.toml",
                          "--cache-dir", os.devnull, "--no-color-output"],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=240)
    report = (out.stdout + out.stderr).strip()
    assert out.returncode == 0, f"mypy (pyproject.toml [tool.mypy]) found errors:\n{report}"
    assert out.stdout.startswith("Success: no issues found"), report
