"""What each compensation did at each stop of an experiment: the mark's move when that one is left out.

The report's per-stop file shows, beside a mark's σ and its parts, how far each applied
compensation moved the mark (ACS x, y, mm): the mark with every compensation the stop applied,
minus the mark with all of them but that one. The image is not read again: the stored pixel
position ``uv`` goes through the same pose math (calibration/measure.py ``mark_to_abs``) with the
poses :func:`calibration.compensation.compensate` gives, from the dataset's ``state.json``.

The shifts are only given when they describe the stored marks: the marks recomputed here with
every compensation must equal ``result.json``'s to 1 nm, else none is given and the report says
why (a recompute with another calibration, a dataset changed since). Shifts do not add up exactly
when compensations interact (heading_fit reads the tilt).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from calibration.compensation import Compensation, compensate
from calibration.measure import DEFAULT_SIGMA_T_MM, mark_to_abs, robot_pose_at
from calibration.metrics import experiment_metrics
from calibration.scs import Scs
from daemon.bus.procedures import EXPERIMENT
from daemon.compute.procedures import recorded
from daemon.compute.inputs import (calibration_inputs, heading_weight, imu_yaw, reflector_mount, stop_of,
                                   tracker_position)

#: how closely the marks recomputed here must reproduce the stored ones (mm)
SAME_MM = 1e-6

Shifts = list[dict[str, list[float]]]


@dataclass(frozen=True)
class Effects:
    """What the compensations did: per stop each applied one's move of the mark, and the marks without any
    (ACS xy, mm, and headings, deg: what ``ritactl recompute --compensation none`` measures); or why not."""

    shifts: Shifts
    plain_xy: np.ndarray | None = None
    plain_headings: np.ndarray | None = None
    why: str = ""


def _mark_xy(calib: dict[str, Any], scs: Scs, stop: dict[str, Any], uv: Any, comp: Compensation,
             anchor_mm: float) -> tuple[np.ndarray, list[str], float]:
    """The mark's ACS xy from ``uv`` with ``comp`` at ``stop`` (the inputs as daemon/compute/procedures.py
    ``_mark_in_acs`` passes them), the compensations that applied, and the heading (deg)."""
    offset, bias = calibration_inputs(calib)
    mount, _ = reflector_mount(calib)
    weight, _ = heading_weight(calib)
    a = compensate(comp, stop_of(stop), np.array(calib["rob_H_scn"], dtype=float), imu_offset=offset,
                   bias_b_mm=bias, anchor_sigma_mm=anchor_mm, imu_yaw_deg=imu_yaw(calib), mount=mount,
                   abs_t_trk=tracker_position(stop["P_at"]), heading_weight=weight, calibration=calib)
    abs_H_rob = robot_pose_at(a.abs_P_prev, a.abs_P_at, None, a.roll_deg, a.pitch_deg)
    heading = math.degrees(math.atan2(abs_H_rob[1, 0], abs_H_rob[0, 0]))  # as _mark_in_acs states it
    return mark_to_abs(uv, scs, a.rob_H_scn, abs_H_rob)[0][:2], list(a.applied), heading


def _inputs(result: dict[str, Any], dataset: Path) -> tuple[dict[str, Any], Compensation, float] | str:
    """(the dataset's obs, the compensation the result used, heading_fit's anchor σ), or why not."""
    if "calibration" in (result.get("recomputed_with") or []):
        return "recomputed with another calibration than the dataset's"
    try:
        obs = json.loads((dataset / "state.json").read_text(encoding="utf-8"))["obs"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return f"the dataset's state.json cannot be read ({type(exc).__name__}: {exc})"
    requested = (result.get("compensation") or {}).get("requested")
    if requested is None:
        return "the result records no compensation"
    sigma_t = recorded(EXPERIMENT, obs).sigma_t_mm
    anchor = DEFAULT_SIGMA_T_MM if sigma_t is None else float(sigma_t)  # as _mark_in_acs anchors heading_fit
    return obs, Compensation.parse(",".join(requested) or "none"), anchor


def _without(comp: Compensation, name: str) -> Compensation:
    """``comp`` with the compensation ``name`` left out (built in or registered)."""
    return Compensation.parse([n for n in comp.names() if n != name])


def compensation_effects(result: dict[str, Any], dataset: Path | str) -> Effects:
    """:class:`Effects` of an experiment result whose dataset folder is ``dataset``."""
    got = _inputs(result, Path(dataset))
    if isinstance(got, str):
        return Effects([], why=got)
    obs, comp, anchor = got
    marks, stops = result.get("marks") or [], obs.get("stops") or []
    if len(marks) != len(stops):
        return Effects([], why=f"the dataset holds {len(stops)} stops, the result {len(marks)} marks")
    shifts: Shifts = []
    plain = []
    try:
        calib = obs["calibration"]
        scs = Scs.from_dict(calib["scs"], source="state.json: obs.calibration.scs")
        for i, (stop, mark) in enumerate(zip(stops, marks)):
            full, applied, _ = _mark_xy(calib, scs, stop, mark["uv"], comp, anchor)
            off = float(np.hypot(*(full - np.asarray(mark["abs_xyz"][:2], float))))
            if not off <= SAME_MM:
                return Effects([], why=f"stop {i}: the stored mark is not what the dataset gives "
                                       f"({off * 1000:.3f} µm apart)")
            shifts.append({n: (full - _mark_xy(calib, scs, stop, mark["uv"], _without(comp, n),
                                               anchor)[0]).tolist() for n in applied})
            xy, _, heading = _mark_xy(calib, scs, stop, mark["uv"], Compensation(), anchor)
            plain.append([*xy, heading])
    except (ValueError, KeyError, TypeError, IndexError) as exc:
        return Effects([], why=f"the dataset's stops cannot be measured again ({type(exc).__name__}: {exc})")
    p = np.array(plain, dtype=float).reshape(-1, 3)
    return Effects(shifts, p[:, :2], p[:, 2])


def plain_metrics(result: dict[str, Any], effects: Effects) -> dict[str, Any] | None:
    """The experiment's metrics without any compensation (calibration/metrics.py on the plain marks, grouped
    as the result's), or None when the effects could not be computed or nothing was applied."""
    applied = (result.get("compensation") or {}).get("applied") or {}
    if effects.plain_xy is None or effects.plain_headings is None or not any(applied.values()):
        return None
    groups = [m.get("k", 0) for m in result.get("marks") or []]
    return experiment_metrics(effects.plain_xy, effects.plain_headings, groups).to_dict()


def left_out_metrics(result: dict[str, Any], effects: Effects) -> dict[str, dict[str, Any]]:
    """Per compensation some stop applied: the experiment's metrics with that one left out alone (each stop's
    mark minus its shift), to name the compensation that made a figure worse."""
    marks = result.get("marks") or []
    if not effects.shifts or len(effects.shifts) != len(marks):
        return {}
    full = np.array([m["abs_xyz"][:2] for m in marks], dtype=float)
    headings = np.array([m["heading_deg"] for m in marks], dtype=float)
    groups = [m.get("k", 0) for m in marks]
    out = {}
    for name in dict.fromkeys(n for s in effects.shifts for n in s):
        xy = full - np.array([s.get(name, (0.0, 0.0)) for s in effects.shifts], dtype=float)
        out[name] = experiment_metrics(xy, headings, groups).to_dict()
    return out
