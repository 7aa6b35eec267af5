"""What moves between a dataset's stop records and the compensation math (calibration/compensation.py).

* :func:`parse_compensation` — a job's ``compensation`` parameter (resolved: daemon/bus/procedures.py);
* :func:`stop_of` — a dataset stop record → :class:`calibration.compensation.Stop`;
* :func:`plate_imu_offset` — the inclinometer's offset and yaw from the on-plate runs (referencing);
* :func:`compensation_summary` — which compensations were requested, applied, skipped;
* :func:`tracker_distance_mm` — how far the tracker stood from a stop's points (its σ grows with it);
* :func:`tracker_position` — the tracker's ACS position a point was measured from (the mount's line of sight);
* :func:`reflector_mount` — the reflector mount offset a calibration holds;
* :func:`heading_weight` — the share of heading_fit's fitted bend a calibration holds.

docs/datasets.md ("Compensations") documents every field read here.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from calibration.bias_check import read_cov
from calibration.compensation import Compensation, Stop, names_known, tilt_of_pose
from calibration.heading_weight import NOT_LEARNED, HeadingWeight
from calibration.imu_mount import imu_mount
from calibration.mount import MountOffset


def parse_compensation(value: str) -> Compensation:
    """``Compensation.parse`` of a job's resolved ``compensation`` with the error naming the parameter (a
    ValueError: ritactl recompute exits 5)."""
    try:
        return Compensation.parse(value)
    except (ValueError, TypeError, AttributeError) as exc:
        raise ValueError(f"compensation={value!r}: {exc}") from None


def _reading(rec: dict[str, Any]) -> tuple[float, float]:
    """(roll, pitch) in degrees of an inclinometer record."""
    return float(rec["roll_deg"]), float(rec["pitch_deg"])


def _tilt(rec: dict[str, Any] | None) -> tuple[float, float] | None:
    return None if not rec else _reading(rec)


def stop_of(stop: dict[str, Any]) -> Stop:
    """The compensation inputs of one stored stop record (its approach points, tilt, stream)."""
    stream = stop.get("stream") or {}
    pts = stream.get("abs_xyz")
    tilt = stream.get("tilt_deg")
    return Stop(np.asarray(stop["P_prev"]["abs_xyz"], float), np.asarray(stop["P_at"]["abs_xyz"], float),
                _tilt(stop.get("imu_prev")), _tilt(stop.get("imu_at")),
                None if not pts else np.asarray(pts, float),
                None if not tilt or not pts or len(tilt) != len(pts) else np.asarray(tilt, float),
                reverse=float(stop.get("move_mm", 1.0)) < 0)


def plate_imu_offset(runs_obs: list[dict[str, Any]], abs_H_robs: list[np.ndarray],
                     height_mm: float) -> dict[str, Any] | None:
    """The inclinometer's mounting from the on-plate runs that read it (None: none did).

    calibration/imu_mount.py: the offset, and with two runs the yaw and the check that the
    runs agree; its messages and verdict join the referencing result's.
    """
    pairs = [(tilt_of_pose(H), _reading(r["imu0"]), _reading_sigma(r["imu0"]))
             for r, H in zip(runs_obs, abs_H_robs) if r.get("imu0")]
    if not pairs:
        return None
    return imu_mount([p[0] for p in pairs], [p[1] for p in pairs], [p[2] for p in pairs], height_mm).to_dict()


def _reading_sigma(rec: dict[str, Any]) -> float:
    """1σ of an averaged standstill reading (deg) from its spread and count."""
    n = max(int(rec.get("n") or 1), 1)
    return float(np.hypot(rec.get("roll_std_deg") or 0.0, rec.get("pitch_std_deg") or 0.0)) / np.sqrt(2.0 * n)


def calibration_inputs(calib: dict[str, Any]) -> tuple[tuple[float, float] | None, list[float] | None]:
    """(imu_offset_deg, robot_bias_mm) a calibration holds, each None when absent."""
    off = calib.get("imu_offset_deg")
    b = calib.get("robot_bias_mm")
    offset = None if off is None else (float(off[0]), float(off[1]))
    return offset, (None if b is None else [float(v) for v in b])


def bias_cov(calib: dict[str, Any]) -> tuple[np.ndarray | None, str]:
    """(the stored robot-frame bias's covariance, mm² RCS (calibration/bias_check.py), why it is not read: ""
    when read or absent). None: no bias, a bias stored before the field, or a record that is not one."""
    if calib.get("robot_bias_mm") is None:
        return None, ""
    value = (calib.get("robot_bias") or {}).get("cov_mm2")
    if value is None:
        return None, ""
    try:
        return read_cov(value, "calibration: robot_bias.cov_mm2"), ""
    except ValueError as exc:
        return None, f"{exc}: the bias's own uncertainty is not stated, nor the bias re-checked"


def imu_yaw(calib: dict[str, Any]) -> float:
    """The inclinometer's yaw in the body a calibration holds (0 when it was not resolved)."""
    return float(calib.get("imu_yaw_deg") or 0.0)


def tracker_distance_mm(stop: dict[str, Any]) -> float | None:
    """The larger distance from the tracker to P_prev and P_at (mm): the norm of their tracker-frame x y z
    (docs/datasets.md, "Tracker points"); None when a point does not carry them."""
    pts = [stop.get(k) or {} for k in ("P_prev", "P_at")]
    if not all(all(c in p for c in ("x", "y", "z")) for p in pts):
        return None
    return max(float(np.linalg.norm([float(p["x"]), float(p["y"]), float(p["z"])])) for p in pts)


def tracker_position(point: dict[str, Any]) -> np.ndarray | None:
    """The tracker's ACS position (``abs_H_trk``'s translation) a stored point carries, else None."""
    H = point.get("abs_H_trk")
    return None if H is None else np.asarray(H, dtype=float)[:3, 3]


def reflector_mount(calib: dict[str, Any]) -> tuple[MountOffset | None, str]:
    """The reflector mount offset of a calibration (a referencing with reversal), None when it holds none,
    and why a record it holds cannot be read ("" when it can): a bad record skips the compensation only."""
    rec = calib.get("reflector_mount")
    try:
        return (None if not rec else MountOffset.from_dict(rec, "calibration: reflector_mount")), ""
    except ValueError as exc:
        return None, str(exc)


def heading_weight(calib: dict[str, Any]) -> tuple[HeadingWeight, str]:
    """heading_fit's learned weight a calibration holds (an experiment stored it; none: the chord,
    :data:`NOT_LEARNED`), and why a record it holds cannot be read ("" when it can; then the chord too)."""
    rec = calib.get("heading_weight")
    try:
        return (NOT_LEARNED if not rec else HeadingWeight.from_dict(rec, "calibration: heading_weight")), ""
    except ValueError as exc:
        return NOT_LEARNED, str(exc)


def _weight_value(calib: dict[str, Any]) -> float | None:
    """The weight later jobs apply (0 when the record says the chord), None without a readable record."""
    w, bad = heading_weight(calib)
    return None if bad or w is NOT_LEARNED else w.weight


def stop_record(comp: Compensation, applied: Any) -> dict[str, Any]:
    """The per-stop compensation record of a mark."""
    return {"requested": comp.names(), "applied": list(applied.applied), "skipped": dict(applied.skipped)}


def compensation_summary(comp: Compensation, records: list[dict[str, Any]],
                         calib: dict[str, Any]) -> dict[str, Any]:
    """Over all stops: per compensation how many stops applied it and why the others skipped it."""
    offset, bias = calibration_inputs(calib)
    out: dict[str, Any] = {"requested": comp.names(), "stops": len(records), "applied": {}, "skipped": {},
                           "skipped_stops": {},
                           "imu_offset_deg": None if offset is None else list(offset), "robot_bias_mm": bias,
                           "reflector_mount_los_mm": (calib.get("reflector_mount") or {}).get("los_mm"),
                           "heading_weight": _weight_value(calib)}
    for name in names_known():
        if name not in out["requested"]:
            continue
        out["applied"][name] = sum(name in r["applied"] for r in records)
        reasons = [r["skipped"][name] for r in records if name in r["skipped"]]
        if reasons:
            out["skipped"][name] = sorted(set(reasons))
            # how many stops gave each reason: a reader sees "reason ×7", not seven copies or one
            out["skipped_stops"][name] = {r: reasons.count(r) for r in dict.fromkeys(reasons)}
    return out
