"""How much longer than on a quiet machine a wait may take before it counts as a hang (issue 34).

Tests assert order and causality, never a wall-clock latency (those are benchmarks: bench/, with
docs/benchmarks.md). Their waits only catch hangs: a wait's bound is what the step takes on a quiet
2-core machine with room to spare, times ``LOAD_FACTOR`` for a machine that others are using.

``RITA_LOAD_FACTOR`` (default 3: the suite beside 2 × cores busy processes, ``make test-under-load``)
sets it; raise it on a machine busier still, never lower it below 1.
"""
from __future__ import annotations

import os

LOAD_FACTOR = max(1.0, float(os.environ.get("RITA_LOAD_FACTOR", "3")))


def hang_s(quiet_s: float) -> float:
    """The bound of a wait whose step takes well under ``quiet_s`` on a quiet machine."""
    return quiet_s * LOAD_FACTOR
