"""Does heading_fit's stored weight still hold? Its learning conditions and the experiment's own weight.

A weight (calibration/heading_weight.py) is the share of the fitted bend that helped on the
paths of the experiment that learned it. If the robot changed since (another approach speed or
distance, another stream rate, the tilt compensation switched, paths that bend elsewhere in the
move), the share that helps changes and nothing in a single stop shows it. So the weight carries
what it was learned under (:func:`learning_conditions`), and every experiment with heading_fit
learns its own weight from its own stops and compares (:func:`recheck`):

* the two weights, z = (w_own − w_applied) / √(σ_own² + σ_applied²), a disagreement beyond
  :data:`RECHECK_Z` (each σ covers the spread between experiments, calibration/heading_weight.py);
* the applied weight on this experiment's stops, which it never saw (:func:`chord_predicts_better`): with M
  and b refitted the marks' squared scatter is a parabola in the applied weight v with its minimum at this
  experiment's own w (same bend model), so the chord (v = 0) makes these stops agree better exactly when
  w_own < v/2. As in the learning's own choice (calibration/weight_cv.py) the smaller held-out scatter
  decides, no significance test: on an unchanged robot (w_own ~ N(w*, σ_own²), v ~ N(w*, σ_applied²))
  it fires with probability Φ(−(w*/2) / √(σ_own² + σ_applied²/4)), Φ(−z/√5) for equal σs with z = w*/σ:
  26 % at z = √2, 9 % at 3, 1.3 % at 5, 0.1 % at 7. A weight shown only weakly is one the chord nearly
  matches, so which of the two these stops favour is then close to chance, and the warning says which;
* the conditions: each a tolerance of its own (:data:`TOLERANCE`); the slopes' rms by a z of its
  log ratio (the rms of n slopes has a relative standard error ≈ 1/√(2n)); the bend model the stops'
  bends are best read by (``shape_model``: chosen with each model's weight ungated,
  calibration/heading_weight.py ``bend_model``, so that it describes the paths, not which weight passed
  the gate) when the one now is the richer (a simpler one now only means the richer was not shown
  significantly here, calibration/weight_cv.py). A weight stored before ``shape_model`` was recorded has
  this condition not compared (its ``model`` followed the gate); nothing warns for the field's absence.

Any of them makes the experiment's verdict ``warn``, naming both weights and what differs. When this
experiment's own weight has no σ (its bend was fitted at too few stops, or its headings do not
separate the weight from M and b), z cannot be made: the conditions are still compared, a differing
one still warns (the weight was learned on another robot state, and nothing here shows it holds),
and the warning says that the weight itself could not be re-checked, and why; with the same
conditions the verdict stays ``ok`` (nothing contradicts the weight).
"""
from __future__ import annotations

import math
from typing import Any

from calibration.heading_weight import MODELS

#: two weights disagree beyond this many standard errors of their difference
RECHECK_Z = 3.0
#: relative change of a scalar condition beyond which the weight was learned under other conditions: a stream
#: rate or approach speed within 25 % samples the same path alike, a distance within 10 % bends alike
TOLERANCE = {"stream_rate_hz": 0.25, "speed_mm_s": 0.25, "distance_mm": 0.10}
#: the slopes' rms differs beyond this many standard errors of its log ratio
SLOPE_Z = 3.0


def _median(values: list[float]) -> float | None:
    v = sorted(x for x in values if math.isfinite(x))
    return None if not v else (v[len(v) // 2] if len(v) % 2 else 0.5 * (v[len(v) // 2 - 1] + v[len(v) // 2]))


def learning_conditions(rates_hz: list[float], speeds_mm_s: list[float], distances_mm: list[float],
                        tilt: bool, weight: Any, shape_model: str | None = None) -> dict[str, Any]:
    """What a weight was learned under: the stops' median stream rate, approach speed and distance (None where
    no stop gives it), whether the tilt was compensated, the bend model of the weight (``model``) and the one
    the stops' bends are best read by (``shape_model``: heading_weight ``bend_model``, None when not made),
    and the fitted slopes' rms, robust scale and count (``weight``: the :class:`HeadingWeight`)."""
    limit = weight.slope_limit_rad
    return {"stream_rate_hz": _median(rates_hz), "speed_mm_s": _median(speeds_mm_s),
            "distance_mm": _median(distances_mm), "tilt": bool(tilt), "model": weight.model,
            "shape_model": shape_model,
            "slope_rms_rad": weight.slope_rms_rad, "n_stops": weight.n_stops,
            "slope_scale_rad": None if not math.isfinite(limit) else limit / 4.0}


def _scalar_differs(name: str, a: Any, b: Any) -> str | None:
    if a is None or b is None:
        return None if a is None and b is None else f"{name} {a} learned, {b} now"
    if abs(b - a) > TOLERANCE[name] * abs(a):
        return f"{name} {a:.4g} learned, {b:.4g} now (beyond {100 * TOLERANCE[name]:.0f} %)"
    return None


def _slopes_differ(a: dict[str, Any], b: dict[str, Any]) -> str | None:
    sa, sb = a.get("slope_rms_rad"), b.get("slope_rms_rad")
    na, nb = a.get("n_stops") or 0, b.get("n_stops") or 0
    if not sa or not sb or na < 2 or nb < 2:
        return None
    z = abs(math.log(sb / sa)) / math.sqrt(1.0 / (2 * na) + 1.0 / (2 * nb))
    if z <= SLOPE_Z:
        return None
    return (f"the fitted end slopes' rms {sa * 1e6:.0f} µrad learned, {sb * 1e6:.0f} µrad now "
            f"(z {z:.1f} > {SLOPE_Z:g}: the paths bend differently)")


def _model_differs(learned: Any, now: Any) -> str | None:
    """The paths' bend model now against the learned one (``shape_model``), as evidence of a changed path only
    when the one now is the richer: an experiment reads the bends by a richer model only when its held-out
    directions show it significantly (calibration/weight_cv.py), so a simpler one now means "not shown
    here", which says nothing against the richer model learned. Not compared when either is not recorded
    (a weight stored before the field, or a model not determined now)."""
    order = list(MODELS)
    if learned not in order or now not in order or order.index(now) <= order.index(learned):
        return None
    return (f"bend model {learned!r} learned, {now!r} now (the model the stops' bends are best read by, "
            f"each model's weight ungated)")


def conditions_differ(learned: dict[str, Any] | None, now: dict[str, Any]) -> list[str]:
    """Each condition of ``now`` that differs from those the weight was ``learned`` under, named."""
    if learned is None:
        return ["the stored weight records no learning conditions (stored before they were recorded)"]
    out = [_scalar_differs(k, learned.get(k), now.get(k)) for k in TOLERANCE]
    if learned.get("tilt") != now.get("tilt"):
        out.append(f"tilt compensation {'on' if learned.get('tilt') else 'off'} learned, "
                   f"{'on' if now.get('tilt') else 'off'} now")
    out.append(_model_differs(learned.get("shape_model"), now.get("shape_model")))
    out.append(_slopes_differ(learned, now))
    return [d for d in out if d]


def not_rechecked(same: Any) -> str:
    """Why the experiment's own weight has no σ to compare with (its record's reason, else the stop count)."""
    return same.reason or f"its σ is not estimated from the {same.n_stops} stops whose bend was fitted"


def chord_predicts_better(applied: Any, same: Any) -> str | None:
    """The reason when the chord makes this experiment's stops agree better than the applied weight v (M and
    b refitted): w_own < v/2, see the module's docstring; None when it does not, when no weight is applied,
    or when this experiment's own weight is not estimated (no σ: its w_fit is no estimate)."""
    v, w = applied.weight, same.weight_fit
    if not (applied.applied and v > 0 and math.isfinite(same.sigma)) or w >= v / 2:
        return None
    return (f"the chord predicts this experiment's stops better than the applied weight: their own weight "
            f"{w:.2f} is below half the applied {v:.2f} (the marks' scatter, a parabola in the applied "
            f"weight with its minimum at the own, is lower at 0)")


def recheck(applied: Any, own: Any, same: Any = None) -> dict[str, Any]:
    """The stored weight ``applied`` against the experiment's own ``own`` (both
    :class:`calibration.heading_weight.HeadingWeight`; ``own.conditions`` set): {applied_weight,
    applied_sigma, own_weight_fit, own_sigma, own_model, shape_model, z (null when a σ is not estimated),
    chord_better (:func:`chord_predicts_better`), differs, ok, message}. ``same``: the experiment's weight
    re-learned with the applied one's bend model (None: ``own``), whose weight and slopes are compared
    (another model's slopes are other numbers); the paths' bend model (``own.conditions['shape_model']``)
    is a condition of its own."""
    same = own if same is None else same
    s = math.hypot(applied.sigma, same.sigma)
    z = (same.weight_fit - applied.weight_fit) / s if math.isfinite(s) and s > 0 else None
    now = {**(own.conditions or {}), "slope_rms_rad": same.slope_rms_rad, "n_stops": same.n_stops}
    differs = conditions_differ(applied.conditions, now)
    disagree = z is not None and abs(z) > RECHECK_Z
    chord = chord_predicts_better(applied, same)
    ok = not disagree and not differs and chord is None
    both = (f"applied weight {applied.weight:.2f} (fit {applied.weight_fit:.2f} ± {applied.sigma:.2f}, "
            f"{applied.model}), this experiment's own {same.weight_fit:.2f} ± {same.sigma:.2f}")
    why = ([f"they differ by {z:.1f}σ (> {RECHECK_Z:g}σ)"] if disagree else []) + ([chord] if chord else []) \
        + differs
    if z is None:  # no σ here: only the conditions are compared, and the warning says so
        why.append(f"the weight itself could not be re-checked here ({not_rechecked(same)})")
    message = None if ok else (f"heading_fit's stored weight may not hold for this robot any more: {both}; "
                               f"{'; '.join(why)}; the chord's figures are in the result (chord)")
    return {"applied_weight": applied.weight, "applied_weight_fit": applied.weight_fit,
            "applied_sigma": applied.sigma if math.isfinite(applied.sigma) else None,
            "own_weight_fit": same.weight_fit, "own_sigma": same.sigma if math.isfinite(same.sigma) else None,
            "own_model": own.model, "shape_model": (own.conditions or {}).get("shape_model"), "z": z,
            "chord_better": chord is not None, "differs": differs, "ok": ok, "message": message}
