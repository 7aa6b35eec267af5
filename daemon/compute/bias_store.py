"""The calibration an experiment's ``store_bias`` writes: the same function for the live worker
(daemon/worker/compensations.py ``store_bias``) and ``ritactl recompute --store-bias``, so that offline
and live store alike (docs/datasets.md, "Compensations").
"""
from __future__ import annotations

import time
from typing import Any

import numpy as np

from calibration.compensation import apply_bias


def biased_calibration(active: dict[str, Any], result: dict[str, Any],
                       stored: str | None = None) -> dict[str, Any]:
    """``active`` with the experiment ``result``'s fitted bias b added to what it already held, the
    heading_fit weight it learned (calibration/heading_weight.py) and its σ check (calibration/coverage.py:
    later marks scale their σ by it); ``stored``: the time stamp (UTC) the record gets (None: now).

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
    weight = result.get("heading_weight")
    # with heading_fit the b that goes with the learned weight is the one fitted jointly with it (a bend that
    # leans one way would otherwise be in b and in the weight twice); without it, the chord's marks' b and no
    # weight (the held one was learned with another b)
    fit_b = fit["b"] if not weight or weight.get("b_mm") is None else weight["b_mm"]
    # its covariance goes with it: every later mark it corrects carries it (calibration/bias_check.py); the
    # held bias is a number added, not a second estimate
    cov = ((result.get("checks") or {}).get("bias") or {}).get("cov_mm2") if not weight or \
        weight.get("b_mm") is None else weight.get("b_cov_mm2")
    b = np.asarray(fit_b, float) + (np.asarray(held, float) if applied else 0.0)
    apply_bias(np.eye(4), b)  # refuses a b no calibration can have, before anything is written
    new = {k: v for k, v in active.items() if k not in ("heading_weight", "sigma_check")}
    if weight:
        new["heading_weight"] = {**weight, "job": result.get("job")}
    sigma = (result.get("checks") or {}).get("sigma")
    if sigma:  # the σ this experiment validated goes with its b: a later mark states it (no check: none)
        new["sigma_check"] = {**sigma, "job": result.get("job")}
    used = [n for n in summary.get("requested", []) if summary["applied"].get(n)]
    return {**new, "robot_bias_mm": b.tolist(),
            "robot_bias": {"job": result.get("job"), "fit_b_mm": list(fit_b), "fit_rms_mm": fit.get("rms_mm"),
                           "added_to_mm": held if applied else None, "compensation": used,
                           "cov_mm2": cov,
                           "stored": stored or time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())}}
