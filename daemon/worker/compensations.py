"""The issue #15 compensations on the product path: what the worker records and how compute uses it.

The math is :mod:`calibration.compensation` (one source of truth); this module only
moves data between the bus, the dataset's stop records and that math:

* :func:`read_tilt` — the inclinometer averaged at a standstill (``imu_readings``);
* :func:`stop_of` — a dataset stop record → :class:`calibration.compensation.Stop`;
* :func:`plate_imu_offset` — the inclinometer's offset and yaw from the on-plate runs (referencing);
* :func:`compensation_summary` — which compensations were requested, applied, skipped;
* :func:`store_bias` — an experiment's fitted robot-frame bias into the active calibration.

docs/datasets.md ("Compensations") documents every field written here.
"""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from calibration.compensation import NAMES, Compensation, Stop, apply_bias, tilt_of_pose
from calibration.imu_mount import imu_mount
from daemon.bus.procedure_params import DEFAULTS as PARAM_DEFAULTS
from daemon.bus.storage import atomic_write_json, calibration_dir

#: inclinometer readings averaged at a standstill (1 s at the base's 10 Hz)
DEFAULT_IMU_READINGS: int = PARAM_DEFAULTS["imu_readings"]  # the procedures' parameter table
#: the compensations a job applies when its parameters do not say
DEFAULT_COMPENSATION: str = PARAM_DEFAULTS["compensation"]


def parse_compensation(value: Any) -> Compensation:
    """``Compensation.parse`` with the error naming the parameter (a ValueError: ritactl recompute exits 5)."""
    try:
        return Compensation.parse(DEFAULT_COMPENSATION if value is None else value)
    except (ValueError, TypeError, AttributeError) as exc:
        raise ValueError(f"compensation={value!r}: {exc}") from None


def read_tilt(call: Any, n: int, interval_s: float = 0.0) -> dict[str, Any] | None:
    """Mean roll/pitch of ``n`` robot.status readings at a standstill, or None when the base reports no tilt.

    ``call`` is ``ctx.call``. The readings are ``interval_s`` apart (the inclinometer's
    output period: closer readings repeat one sample and average nothing). Never fails
    for a base without an inclinometer: the first reading without roll/pitch ends it.
    """
    readings = []
    for i in range(max(1, int(n))):
        if i:
            time.sleep(max(0.0, float(interval_s)))
        st = call("robot.status")
        if st.get("roll_deg") is None or st.get("pitch_deg") is None:
            return None
        readings.append((float(st["roll_deg"]), float(st["pitch_deg"])))
    r = np.array(readings)
    return {"roll_deg": float(r[:, 0].mean()), "pitch_deg": float(r[:, 1].mean()), "n": len(r),
            "roll_std_deg": float(r[:, 0].std()), "pitch_std_deg": float(r[:, 1].std())}


def _tilt(rec: dict[str, Any] | None) -> tuple[float, float] | None:
    return None if not rec else (float(rec["roll_deg"]), float(rec["pitch_deg"]))


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
    pairs = [(tilt_of_pose(H), _tilt(r["imu0"]), _reading_sigma(r["imu0"]))
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
    return (None if off is None else (float(off[0]), float(off[1]))), (None if b is None else [float(v) for v in b])


def imu_yaw(calib: dict[str, Any]) -> float:
    """The inclinometer's yaw in the body a calibration holds (0 when it was not resolved)."""
    return float(calib.get("imu_yaw_deg") or 0.0)


def stop_record(comp: Compensation, applied: Any) -> dict[str, Any]:
    """The per-stop compensation record of a mark."""
    return {"requested": comp.names(), "applied": list(applied.applied), "skipped": dict(applied.skipped)}


def compensation_summary(comp: Compensation, records: list[dict[str, Any]], calib: dict[str, Any]) -> dict[str, Any]:
    """Over all stops: per compensation how many stops applied it and why the others skipped it."""
    offset, bias = calibration_inputs(calib)
    out: dict[str, Any] = {"requested": comp.names(), "stops": len(records), "applied": {}, "skipped": {},
                           "imu_offset_deg": None if offset is None else list(offset), "robot_bias_mm": bias}
    for name in NAMES:
        if name not in out["requested"]:
            continue
        out["applied"][name] = sum(name in r["applied"] for r in records)
        reasons = sorted({r["skipped"][name] for r in records if name in r["skipped"]})
        if reasons:
            out["skipped"][name] = reasons
    return out


def biased_calibration(active: dict[str, Any], result: dict[str, Any]) -> dict[str, Any]:
    """``active`` with the experiment ``result``'s fitted bias b added to what it already held.

    An experiment that already applied the calibration's bias fits only what is left,
    so the stored bias is the sum; one that did not fits the whole bias.
    """
    fit = (result.get("metrics") or {}).get("fit")
    if not fit or fit.get("b") is None:
        raise ValueError("the experiment fitted no robot-frame bias (too few directions?): nothing to store")
    check = (result.get("checks") or {}).get("bias_model") or {}
    if check.get("ok") is False:  # the data contradict the bias model: b would not be a robot-frame bias
        raise ValueError(check.get("message") or "the cluster means do not follow M + R(ψ)·b")
    summary = result.get("compensation") or {}
    n_applied, n_stops = summary.get("applied", {}).get("bias", 0), summary.get("stops", 0)
    if 0 < n_applied < n_stops:
        raise ValueError(f"the bias was applied to {n_applied} of {n_stops} stops only: the fit mixes both")
    # what the experiment's own calibration copy applied (not what is active now: another job may have
    # stored a bias since this one started)
    held = summary.get("robot_bias_mm") if n_applied else None
    applied = held is not None
    b = np.asarray(fit["b"], float) + (np.asarray(held, float) if applied else 0.0)
    apply_bias(np.eye(4), b)  # refuses a b no calibration can have, before anything is written
    return {**active, "robot_bias_mm": b.tolist(),
            "robot_bias": {"job": result.get("job"), "fit_b_mm": list(fit["b"]), "fit_rms_mm": fit.get("rms_mm"),
                           "added_to_mm": held if applied else None,
                           "compensation": [n for n in summary.get("requested", []) if summary["applied"].get(n)],
                           "stored": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}}


def store_bias(data_dir: Path, result: dict[str, Any]) -> str:
    """Write the fitted bias into the active calibration (atomic); the one line the result's messages get.

    Only when the experiment used the calibration that is still active: a bias
    belongs to the calibration it was measured with. The previous active calibration
    stays in ``calibration/history`` (it is there already under its job id); the new
    one is also kept as ``calibration/history/bias/<calibration job>.bias-<experiment job>.json``.
    """
    cdir = calibration_dir(data_dir)
    path = cdir / "active.json"
    if not path.exists():
        return "robot-frame bias NOT stored: there is no active calibration"
    active = json.loads(path.read_text())
    if active.get("job") != result.get("calibration_job"):
        return (f"robot-frame bias NOT stored: the experiment used calibration {result.get('calibration_job')!r} "
                f"but {active.get('job')!r} is active now")
    try:
        new = biased_calibration(active, result)
    except ValueError as exc:
        return f"robot-frame bias NOT stored: {exc}"
    # the copy goes beside the history, not into it: it is no new referencing result
    atomic_write_json(cdir / "history" / "bias" / f"{active.get('job')}.bias-{result.get('job')}.json", new)
    atomic_write_json(path, new)
    b = new["robot_bias_mm"]
    return (f"robot-frame bias b = ({b[0]:+.4f}, {b[1]:+.4f}) mm stored in the active calibration {path} "
            f"(later jobs apply it with compensation 'bias')")
