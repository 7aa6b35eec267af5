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
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from calibration.compensation import Compensation, compensate
from calibration.measure import DEFAULT_SIGMA_T_MM, mark_to_abs, robot_pose_at
from calibration.scs import Scs
from daemon.bus.procedures import EXPERIMENT
from daemon.compute.procedures import recorded
from daemon.compute.inputs import (calibration_inputs, heading_weight, imu_yaw, reflector_mount, stop_of,
                                   tracker_position)

#: how closely the marks recomputed here must reproduce the stored ones (mm)
SAME_MM = 1e-6

Shifts = list[dict[str, list[float]]]


def _mark_xy(calib: dict[str, Any], scs: Scs, stop: dict[str, Any], uv: Any, comp: Compensation,
             anchor_mm: float) -> tuple[np.ndarray, list[str]]:
    """The mark's ACS xy from ``uv`` with ``comp`` at ``stop`` (the inputs as daemon/compute/procedures.py
    ``_mark_in_acs`` passes them), and the compensations that applied."""
    offset, bias = calibration_inputs(calib)
    mount, _ = reflector_mount(calib)
    weight, _ = heading_weight(calib)
    a = compensate(comp, stop_of(stop), np.array(calib["rob_H_scn"], dtype=float), imu_offset=offset,
                   bias_b_mm=bias, anchor_sigma_mm=anchor_mm, imu_yaw_deg=imu_yaw(calib), mount=mount,
                   abs_t_trk=tracker_position(stop["P_at"]), heading_weight=weight)
    abs_H_rob = robot_pose_at(a.abs_P_prev, a.abs_P_at, None, a.roll_deg, a.pitch_deg)
    return mark_to_abs(uv, scs, a.rob_H_scn, abs_H_rob)[0][:2], list(a.applied)


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


def compensation_shifts(result: dict[str, Any], dataset: Path | str) -> tuple[Shifts, str]:
    """Per stop ``{name: [dx, dy]}`` (mm) for each compensation it applied, and ``""``; or ``[]`` and why
    the shifts cannot be given."""
    got = _inputs(result, Path(dataset))
    if isinstance(got, str):
        return [], got
    obs, comp, anchor = got
    marks, stops = result.get("marks") or [], obs.get("stops") or []
    if len(marks) != len(stops):
        return [], f"the dataset holds {len(stops)} stops, the result {len(marks)} marks"
    try:
        calib = obs["calibration"]
        scs = Scs.from_dict(calib["scs"], source="state.json: obs.calibration.scs")
        out: Shifts = []
        for i, (stop, mark) in enumerate(zip(stops, marks)):
            full, applied = _mark_xy(calib, scs, stop, mark["uv"], comp, anchor)
            off = float(np.hypot(*(full - np.asarray(mark["abs_xyz"][:2], float))))
            if not off <= SAME_MM:
                return [], (f"stop {i}: the stored mark is not what the dataset gives ({off * 1000:.3f} µm "
                            "apart)")
            out.append({n: (full - _mark_xy(calib, scs, stop, mark["uv"], replace(comp, **{n: False}),
                                            anchor)[0]).tolist() for n in applied})
    except (ValueError, KeyError, TypeError, IndexError) as exc:
        return [], f"the dataset's stops cannot be measured again ({type(exc).__name__}: {exc})"
    return out, ""


__all__ = ["SAME_MM", "Shifts", "compensation_shifts"]
