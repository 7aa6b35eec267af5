"""How many cases a fuzz test draws.

``make test`` runs a seeded sample that keeps the suite within its time budget; the
counts quoted in docs/benchmarks.md come from the full run,
``RITA_FUZZ=full make test`` (or ``RITA_FUZZ=full .venv/bin/python -m pytest tests/daemon tests/drivers -k fuzz``).
Both are deterministic (seeded generators, derandomized hypothesis); the sample is just smaller.
"""
from __future__ import annotations

import os

FULL = os.environ.get("RITA_FUZZ", "").lower() == "full"


def cases(full: int, sample: int) -> int:
    """``full`` under RITA_FUZZ=full, else ``sample`` (never more than ``full``)."""
    return full if FULL else min(sample, full)


def scaled(threshold: float, full: int, sample: int) -> float:
    """A count the full run must reach, scaled to the sample (same rate per case)."""
    return threshold if FULL else threshold * cases(full, sample) / full
