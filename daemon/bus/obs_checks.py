"""Observation checks the schemas cannot express: the lengths inside a stop's recorded stream.

Returned as (JSON path parts, message) so :mod:`daemon.bus.datasets` wraps them as its problems.
"""
from __future__ import annotations

from typing import Any, Iterator


def _stops(obs: dict[str, Any]) -> Iterator[tuple[tuple[Any, ...], Any]]:
    stops = obs.get("stops")
    for i, stop in enumerate(stops if isinstance(stops, list) else []):
        yield ("obs", "stops", i), stop
    if "stop" in obs:
        yield ("obs", "stop"), obs["stop"]


def stream_problems(obs: dict[str, Any]) -> list[tuple[tuple[Any, ...], str]]:
    """``stream.n`` and the per-point arrays (``tilt_deg``, ``host_time_ns``,
    ``t_sigma_ns``) against ``abs_xyz``'s rows."""
    out = []
    for parts, stop in _stops(obs):
        stream = stop.get("stream") if isinstance(stop, dict) else None
        if not isinstance(stream, dict) or not isinstance(pts := stream.get("abs_xyz"), list):
            continue
        n = stream.get("n")
        if isinstance(n, int) and not isinstance(n, bool) and n != len(pts):
            out.append(((*parts, "stream", "n"), f"{n} but abs_xyz has {len(pts)} rows"))
        for key in ("tilt_deg", "host_time_ns", "t_sigma_ns"):
            rows = stream.get(key)
            if isinstance(rows, list) and len(rows) != len(pts):
                out.append(((*parts, "stream", key), f"{len(rows)} rows but abs_xyz has {len(pts)}: one per "
                                                     f"stream point"))
    return out
