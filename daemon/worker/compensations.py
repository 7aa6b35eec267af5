"""The compensations' inputs the worker records on the robot, and the bias it stores.

The math is :mod:`calibration.compensation`; reading stored records is
:mod:`daemon.compute.inputs`. Here:

* :func:`read_tilt` — the inclinometer averaged at a standstill (``imu_readings``);
* :func:`store_bias` — an experiment's fitted robot-frame bias into the active calibration (what is stored:
  :func:`daemon.compute.bias_store.biased_calibration`, which ``ritactl recompute --store-bias`` shares).

docs/datasets.md ("Compensations") documents every field written here.
"""
from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from daemon.bus.storage import atomic_write_json, calibration_dir
from daemon.compute.bias_store import biased_calibration


def read_tilt(call: Callable[..., Any], n: int, interval_s: float = 0.0) -> dict[str, Any] | None:
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
        return (f"robot-frame bias NOT stored: the experiment used calibration "
                f"{result.get('calibration_job')!r} but {active.get('job')!r} is active now")
    try:
        new = biased_calibration(active, result, time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))
    except ValueError as exc:
        return f"robot-frame bias NOT stored: {exc}"
    # the copy goes beside the history, not into it: it is no new referencing result
    atomic_write_json(cdir / "history" / "bias" / f"{active.get('job')}.bias-{result.get('job')}.json", new)
    atomic_write_json(path, new)
    b, w = new["robot_bias_mm"], result.get("heading_weight")
    weight = "" if not w else (f" and heading_fit's weight {w['weight']:.2f}" if w["applied"] else
                               " and heading_fit's weight 0 (later jobs keep the chord)")
    made_of = _made_of(new["robot_bias"], result)
    return (f"robot-frame bias b = ({b[0]:+.4f}, {b[1]:+.4f}) mm{made_of}{weight} "
            f"stored in the active calibration {path} (later jobs apply it with compensation 'bias')")


def _made_of(record: dict[str, Any], result: dict[str, Any]) -> str:
    """Where the stored b comes from when it is not the table's fitted b, so that no reader takes one for the
    other: the fit plus the bias the stops applied, or the b fitted jointly with heading_fit's weight."""
    fit_b, held = record["fit_b_mm"], record.get("added_to_mm")
    table_b = ((result.get("metrics") or {}).get("fit") or {}).get("b")
    parts = []
    if table_b is not None and any(abs(x - y) > 5e-5 for x, y in zip(fit_b, table_b)):
        parts.append(f"fitted jointly with heading_fit's weight ({fit_b[0]:+.4f}, {fit_b[1]:+.4f}); "
                     f"the table's b, fitted without it, is ({table_b[0]:+.4f}, {table_b[1]:+.4f})")
    if held is not None:
        parts.append(f"{'' if parts else 'the fitted '}({fit_b[0]:+.4f}, {fit_b[1]:+.4f}) plus the "
                     f"({held[0]:+.4f}, {held[1]:+.4f}) the stops already applied")
    return f" ({'; '.join(parts)})" if parts else ""
