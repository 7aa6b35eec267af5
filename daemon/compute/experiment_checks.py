"""What an 8-direction experiment's own data say about the figures it states (docs/accuracy.md).

* :func:`sigma_check` — the marks' stated σ against their scatter about M + R(ψ)·b (calibration/coverage.py):
  when it does not cover, the verdict is ``warn`` and every mark's ``std_mm`` is scaled by the Birge ratio;
* :func:`bias_check` — the bias this experiment fits, with its covariance (what ``store_bias`` stores),
  and the calibration's stored bias re-checked against what is left of it here (calibration/bias_check.py);
* :func:`weight_checks` — heading_fit's weight learned here, with its learning conditions, re-checked
  against the one the calibration applied (calibration/weight_check.py), and the chord's own figures.

docs/datasets.md (the 8-direction result: ``checks.sigma``, ``checks.bias``, ``checks.heading_weight``,
``chord``)
documents the fields.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from calibration.bias_check import chord_bias, recheck_bias
from calibration.coverage import check_sigma, scatter_sigma
from calibration.heading_weight import NOT_LEARNED, bend_model, learn_from_stops, learn_model
from calibration.metrics import experiment_metrics
from calibration.weight_check import learning_conditions, recheck
from daemon.compute.inputs import bias_cov, heading_weight


def sigma_check(marks: list[dict[str, Any]], xy: np.ndarray, headings: np.ndarray) -> dict[str, Any] | None:
    """The Birge ratio of the marks about the bias model; when the σ does not cover, each mark's ``std_mm``
    becomes the stated one × the ratio (its ``sigma`` keeps ``stated_mm`` and ``scale``). None: not made."""
    sig = [scatter_sigma(m["std_mm"], m["sigma"]["parts_mm"]) for m in marks]
    check = check_sigma(xy, headings, sig)
    if check is None:
        return None
    for m in marks:
        m["sigma"].update(stated_mm=m["std_mm"], scale=check.scale, scale_source="this experiment")
        m["std_mm"] = m["std_mm"] * check.scale
    return check.to_dict()


def bias_check(calib: dict[str, Any], summary: dict[str, Any], xy: np.ndarray, headings: np.ndarray,
               groups: np.ndarray) -> dict[str, Any] | None:
    """The robot-frame bias of the marks ``xy`` over the stops with its covariance (``b_mm``, ``cov_mm2``:
    what is left of the calibration's bias when the stops applied it) and, when every stop applied a stored
    bias that states its covariance, that bias re-checked against it (``ok``, ``message``, ...). None: the
    headings do not separate M from b."""
    fitted = chord_bias(xy, headings, groups)
    if fitted is None:
        return None
    b, C = fitted
    out: dict[str, Any] = {"b_mm": b.tolist(), "cov_mm2": C.tolist(), "ok": True, "message": None}
    n, stops = summary["applied"].get("bias", 0), summary["stops"]
    stored, bad = bias_cov(calib)
    if bad and n:
        return {**out, "ok": False, "message": bad}
    if stored is None or n != stops or summary.get("robot_bias_mm") is None:
        return out  # nothing stated to check against, or a fit that mixes stops with and without it
    job = (calib.get("robot_bias") or {}).get("job")
    return {**out, **recheck_bias(summary["robot_bias_mm"], stored, b, C, job).to_dict()}


def _speed_mm_s(stream: dict[str, Any]) -> float | None:
    """The approach's speed: the median over the middle half of the stream's point-to-point speeds (its ends
    can lie in the standstill before and after the move)."""
    P, t = stream.get("abs_xyz") or [], stream.get("host_time_ns") or []
    if len(P) < 8 or len(t) != len(P):
        return None
    d = np.linalg.norm(np.diff(np.asarray(P, float), axis=0), axis=1)
    dt = np.diff(np.asarray(t, float)) * 1e-9
    n = len(d)
    mid = slice(n // 4, n - n // 4)
    ok = dt[mid] > 0
    return float(np.median(d[mid][ok] / dt[mid][ok])) if np.any(ok) else None


def _conditions(stops: list[dict[str, Any]], marks: list[dict[str, Any]], weight: Any,
                shape_model: str | None) -> dict[str, Any]:
    """The experiment's learning conditions (calibration/weight_check.py) from its stop records."""
    streams = [s.get("stream") or {} for s in stops]
    rates = [float(st["rate_hz"]) for st in streams if st.get("rate_hz") is not None]
    speeds = [v for v in (_speed_mm_s(st) for st in streams) if v is not None]
    dist = [float(np.linalg.norm(np.subtract(s["P_at"]["abs_xyz"], s["P_prev"]["abs_xyz"])[:2]))
            for s in stops]
    tilt = sum("tilt" in m["compensation"]["applied"] for m in marks) * 2 > len(marks)  # the most stops'
    return learning_conditions(rates, speeds, dist, tilt, weight, shape_model)


def weight_checks(obs: dict[str, Any], marks: list[dict[str, Any]], learn: list[Any], headings: np.ndarray,
                  groups: np.ndarray) -> tuple[dict[str, Any], dict[str, Any] | None, dict[str, Any]]:
    """(the weight learned here with its conditions, its re-check against the calibration's applied weight
    (None: the calibration holds none, or no stop's bend was fitted here), the chord's metrics: the marks with
    the chord's heading)."""
    own = learn_from_stops(learn, headings, groups)
    # the paths' bend model, read with each model's weight ungated: a condition that does not follow the gate
    own = replace(own, conditions=_conditions(obs["stops"], marks, own, bend_model(learn, headings, groups)))
    applied, _ = heading_weight(obs["calibration"])
    check = None  # the calibration holds no weight, or no stop here fitted a bend: nothing to compare
    if applied is not NOT_LEARNED and own.n_stops:
        same = own if own.model == applied.model else learn_model(learn, headings, groups, applied.model)
        check = recheck(applied, own, same)
    chord_xy = np.array([c for c, _ in learn], dtype=float).reshape(-1, 2)
    return own.to_dict(), check, experiment_metrics(chord_xy, headings, groups).to_dict()
