"""How much of the stream's fitted bend to apply, learned from an 8-direction experiment's own scatter.

The chord P_prev→P_at is off the final heading by the path's bend; the bend fit
(calibration/bend_fit.py) reads that bend from the tracker's stream, but with an error its
stated σ does not hold in full (the tracker's pattern along the move, the floor's lean left
after the tilt compensation). Which of the two headings is better, and by how much, is what
no single stop can show; an experiment can, because all its stops see the same mark:

    P_k(w) = P_k^chord + w · Δ_k,    Δ_k = P_k^fit − P_k^chord

(the mark as measured with the chord, and what the full fitted slope moves it by). Fitting

    P_k^chord = M + R(ψ_k)·b − w · Δ_k

by least squares over the stops (M the mark, b the robot-frame bias, as
calibration/metrics.py ``fit_bias`` models them) gives the weight w that makes the marks agree
best (per bend model, :data:`MODELS`; the experiment keeps the model whose weight predicts the directions
it did not see better, :func:`learn_from_stops`). It is the classic shrinkage factor
var(bend) / (var(bend) + var(fit error)), estimated with the fit's *actual* error: on straight drives
w ≈ 0 (the fit only adds noise), on bent ones it approaches 1 as the fit's error shrinks. w is applied by
later jobs (as b is) only when applying it is expected to err less than the chord (w above √2 of its
standard errors, :data:`APPLY_Z`) and it predicts the directions left out better (calibration/weight_cv.py);
else they keep the chord and say why.

The heading's σ left after applying w is the shrinkage's own: with S² the stops' mean squared
fitted slope (= var(bend) + var(fit error)), var(bend) = w·S² and what remains is
w·(1 − w)·S² (at least w times the fits' stated σ), plus the weight's own uncertainty σ_w² · S².
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np

from calibration.bias_check import B_COLUMNS, jackknife_cov, larger, read_cov, sandwich_lstsq
from calibration.measure import robot_pose_at
from calibration.weight_cv import better, cross_validate, design, with_weight

#: the weight is applied only beyond this many standard errors above 0: where its expected squared error is
#: below the chord's. Applying v instead of the best w* costs (v − w*)²·S² of squared heading (the loss is a
#: parabola in v); the estimate costs σ², the chord w*², whose unbiased estimate is w_fit² − σ², so the
#: estimate wins when w_fit² − σ² > σ²: z > √2 (Mallows' Cp and Akaike's criterion for one parameter: the
#: prediction error, which the cross-validation then estimates held out; not a significance test)
APPLY_Z = math.sqrt(2.0)
#: a stop's fitted slope beyond this many times the learning experiment's robust slope scale is not applied
#: (a Gaussian's tail beyond 4σ: 6e-5)
SLOPE_LIMIT = 4.0
#: the fewest stops with a fitted bend the weight is learned from
MIN_STOPS = 8
#: the bend fit's models an experiment chooses between, by their least polynomial degree
#: (calibration/bend_fit.py):
#: the lowest degree the stream's noise allows (an arc is a parabola), or at least a cubic (an S-curve's end
#: slope is in its asymmetry, which the stream's noise can hide from the lack-of-fit test)
MODELS = {"lowest": 2, "cubic": 3}
#: a 2 × 2 covariance as a record holds it (b_mm's, mm²)
Cov2 = tuple[tuple[float, float], tuple[float, float]]


@dataclass(frozen=True)
class HeadingWeight:
    """The fraction of the fitted end slope later jobs apply, and the heading σ it leaves."""

    weight: float  # applied fraction of the fitted slope, in [0, 1] (0 when not applied)
    weight_fit: float  # the least-squares estimate before clipping
    sigma: float  # its standard error
    n_stops: int  # stops whose bend was fitted
    slope_rms_rad: float  # S: rms of the fitted end slopes against the chord
    sigma_heading_rad: float  # the heading's 1σ when the weight is applied
    applied: bool
    why: str  # why later jobs keep the chord ("" when applied)
    model: str = "lowest"  # the bend fit's model, a key of MODELS
    rms_mm: float = math.nan  # the marks' residual rms about M + R(ψ)·b with the weight applied
    slope_limit_rad: float = math.inf  # a stop's fitted slope beyond it keeps the chord (learning and use)
    #: the robot-frame bias (RCS x, y, mm) fitted jointly with the weight, the weight as stored (0 when not
    #: applied): the b that goes with it, beyond the bias the experiment's marks already had removed
    b_mm: tuple[float, float] | None = None
    #: what it was learned under (calibration/weight_check.py ``learning_conditions``): None when not recorded
    conditions: dict[str, Any] | None = None
    #: the leave-one-direction-out comparison that chose between the chord and the weight
    #: (calibration/weight_cv.py): None when not made
    cv: dict[str, Any] | None = None
    #: why the chord is kept, without the consequence ``why`` adds to it ("" when applied): what a message
    #: that states its own consequence quotes, so that nothing parses ``why``
    reason: str = ""
    #: b_mm's covariance (mm², RCS; calibration/bias_check.py): the uncertainty every mark it corrects carries
    b_cov_mm2: Cov2 | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-able: a figure that was not estimated (infinite or NaN) is null."""
        d = {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
             for k, v in asdict(self).items()}
        d["b_mm"] = None if self.b_mm is None else list(self.b_mm)
        d["b_cov_mm2"] = None if self.b_cov_mm2 is None else [list(r) for r in self.b_cov_mm2]
        return d

    @classmethod
    def from_dict(cls, d: Any, source: str = "heading_weight") -> "HeadingWeight":
        """From a stored record; ValueError naming ``source`` and the bad field."""
        if not isinstance(d, dict):
            raise ValueError(f"{source}: expected an object, got {type(d).__name__}")
        try:
            b = d.get("b_mm")
            w = cls(float(d["weight"]), float(d["weight_fit"]),
                    math.inf if d["sigma"] is None else float(d["sigma"]),
                    int(d["n_stops"]),
                    float(d["slope_rms_rad"]), float(d["sigma_heading_rad"]), bool(d["applied"]),
                    str(d["why"]),
                    str(d.get("model", "lowest")),
                    math.nan if d.get("rms_mm") is None else float(d["rms_mm"]),
                    math.inf if d.get("slope_limit_rad") is None else float(d["slope_limit_rad"]),
                    None if b is None else (float(b[0]), float(b[1])), _record(d.get("conditions")),
                    _record(d.get("cv")), str(d.get("reason", "")), _cov(d.get("b_cov_mm2"), source))
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{source}: not a heading weight record ({exc!r})") from None
        if w.model not in MODELS:
            raise ValueError(f"{source}: model={w.model!r} is not a bend model ({', '.join(MODELS)})")
        if not (0.0 <= w.weight <= 1.0) or not all(math.isfinite(v) and v >= 0 for v in
                                                   (w.slope_rms_rad, w.sigma_heading_rad)) \
                or not w.sigma >= 0:
            raise ValueError(f"{source}: weight={w.weight} must lie in [0, 1] and sigma={w.sigma}, "
                             f"slope_rms_rad={w.slope_rms_rad}, "
                             f"sigma_heading_rad={w.sigma_heading_rad} be >= 0")
        return w


def _cov(value: Any, source: str) -> Cov2 | None:
    """A stored b_cov_mm2 (None when absent: stored before the field); ValueError naming the field."""
    return None if value is None else _cov2(read_cov(value, f"{source}: b_cov_mm2"))


def _cov2(C: np.ndarray) -> Cov2:
    """A 2 × 2 array as the record's tuples."""
    return (float(C[0, 0]), float(C[0, 1])), (float(C[1, 0]), float(C[1, 1]))


def _record(d: Any) -> dict[str, Any] | None:
    """A stored sub-record (conditions, cv) as a dict, None when absent; a TypeError when it is no object."""
    if d is None or isinstance(d, dict):
        return d
    raise TypeError(f"expected an object or null, got {type(d).__name__}")


#: what a calibration without a learned weight gives: the chord (a single stop cannot show which heading
#: is better)
_NO_WEIGHT = ("the calibration holds no learned weight for the bend fit (an 8-direction experiment with "
              "heading_fit learns it and stores it with the bias)")
NOT_LEARNED = HeadingWeight(0.0, 0.0, math.inf, 0, 0.0, 0.0, False, _NO_WEIGHT + ": the chord is used",
                            reason=_NO_WEIGHT)


def _slope_limit(slopes: np.ndarray, fitted: np.ndarray) -> float:
    """:data:`SLOPE_LIMIT` × a robust scale of the fitted slopes (1.4826 × their median magnitude, a zero-mean
    Gaussian's σ), so that one wild slope cannot raise its own limit (an rms can: max|s|/rms ≤ √n)."""
    if not np.any(fitted):
        return math.inf
    return SLOPE_LIMIT * 1.4826 * float(np.median(np.abs(slopes[fitted])))


def _jackknife_var(A: np.ndarray, y: np.ndarray, groups: np.ndarray | None) -> float:
    """The weight's variance from leaving one direction out at a time (the jackknife over directions,
    calibration/bias_check.py; 0 when it cannot be made): a direction's stops share its floor and path, so
    its errors do not average within it and the sandwich over stops understates the spread between
    experiments."""
    def fold(keep: np.ndarray) -> np.ndarray:
        rows = np.repeat(keep, 2)
        return np.linalg.lstsq(A[rows], y[rows], rcond=None)[0][4:5]

    C = None if groups is None else jackknife_cov(fold, groups)
    return 0.0 if C is None else float(C[0, 0])


def _bias_with(A: np.ndarray, y: np.ndarray, w: float, g: np.ndarray | None,
               joint: np.ndarray | None = None) -> tuple[tuple[float, float] | None, Cov2 | None]:
    """The robot-frame bias b fitted with the weight fixed at ``w``, and its covariance (calibration/
    bias_check.py: the sandwich or, over ``g``'s directions, the jackknife); (None, None): headings too few.
    ``joint``: the covariance of the fit that learned ``w``, whose b carries the weight's error (each fold
    then learns its own weight); None: the chord (w = 0, nothing learned)."""
    theta = with_weight(A, y, w)
    if theta is None:
        return None, None

    def fold(keep: np.ndarray) -> np.ndarray | None:
        rows = np.repeat(keep, 2)
        w_k = w if joint is None else np.linalg.lstsq(A[rows], y[rows], rcond=None)[0][4]
        t = with_weight(A[rows], y[rows], float(np.clip(w_k, 0.0, 1.0)))
        return None if t is None else t[B_COLUMNS]

    own = sandwich_lstsq(A[:, :4], y - w * A[:, 4])[1] if joint is None else joint
    C = larger(own[B_COLUMNS, B_COLUMNS], None if g is None else jackknife_cov(fold, g))
    return (float(theta[2]), float(theta[3])), _cov2(C)


def learn_heading_weight(chord_xy: Any, fit_xy: Any, headings_deg: Any, slopes_rad: Any,
                         fit_sigmas_rad: Any = None, model: str = "lowest",
                         groups: Any = None, gate_z: float = APPLY_Z) -> HeadingWeight:
    """The weight of the fitted slope from an experiment's stops; see the module's docstring.

    ``chord_xy`` (N, 2): each stop's mark with the chord's heading; ``fit_xy`` (N, 2): with the full
    fitted slope, NaN where no bend was fitted (the stop then helps fix M and b only);
    ``headings_deg`` (N,): the stops' headings; ``slopes_rad`` (N,): the fitted end slopes (NaN: none);
    ``fit_sigmas_rad`` (N,): the fits' stated σ, a floor under the heading σ left (w near 1);
    ``groups`` (N,): each stop's direction; with ≥ 5 the weight's σ is at least the jackknife's over them;
    ``gate_z``: the weight is applied above this many σ (0: whenever above 0, as :func:`bend_model` reads the
    paths' shape whatever weight passes the gate).
    """
    P = np.asarray(chord_xy, dtype=float).reshape(-1, 2)
    F = np.asarray(fit_xy, dtype=float).reshape(-1, 2)
    psi = np.asarray(headings_deg, dtype=float).reshape(-1)
    slopes = np.asarray(slopes_rad, dtype=float).reshape(-1)
    if not (len(P) == len(F) == len(psi) == len(slopes)):
        raise ValueError(f"learn_heading_weight: {len(P)} chord marks, {len(F)} fitted, {len(psi)} headings, "
                         f"{len(slopes)} slopes (need one of each per stop)")
    fitted = np.all(np.isfinite(F), axis=1) & np.isfinite(slopes)
    limit = _slope_limit(slopes, fitted)
    fitted &= np.abs(np.nan_to_num(slopes)) <= limit  # as later jobs will: such a slope keeps the chord
    n = int(np.count_nonzero(fitted))
    S = float(np.sqrt(np.mean(slopes[fitted] ** 2))) if n else 0.0
    A, y = design(psi, np.where(fitted[:, None], F - P, 0.0)), P.reshape(-1)
    g = None if groups is None else np.asarray(groups).reshape(-1)

    def chord(w_fit: float, sigma: float, why: str) -> HeadingWeight:
        b, b_cov = _bias_with(A, y, 0.0, g) if len(y) else (None, None)
        return HeadingWeight(0.0, w_fit, sigma, n, S, 0.0, False, why + ": the chord is used", model,
                             math.nan, limit, b, reason=why, b_cov_mm2=b_cov)

    if n < MIN_STOPS:
        return chord(0.0, math.inf, f"the bend was fitted at {n} stops (the weight needs >= {MIN_STOPS})")
    # as fit_bias; then its four columns (with_weight) are at most as ill-conditioned
    if np.linalg.cond(A) > 1e6:
        return chord(0.0, math.inf, "the stops' headings and bends do not separate the weight from the mark "
                                    "and the robot-frame bias")
    theta, cov = sandwich_lstsq(A, y)
    w_fit, sigma = float(theta[4]), float(np.sqrt(max(cov[4, 4], _jackknife_var(A, y, g))))
    if not w_fit > gate_z * sigma:
        z = "√2" if gate_z == APPLY_Z else f"{gate_z:g}"
        return chord(w_fit, sigma, f"the bend fit is not expected to make the marks agree better than the "
                                   f"chord (weight {w_fit:.2f} ± {sigma:.2f}, not above {z}σ: its own error "
                                   f"would exceed what it corrects)")
    w = min(w_fit, 1.0)
    fixed = with_weight(A, y, w)  # not None: cond of four of A's columns <= cond(A) <= 1e6
    assert fixed is not None
    b, b_cov = _bias_with(A, y, w, g, cov)
    rms = float(np.sqrt(np.mean((y - A @ fixed) ** 2) * 2.0))
    stated = np.asarray(fit_sigmas_rad, dtype=float).reshape(-1)[fitted] if fit_sigmas_rad is not None else []
    floor = (w * float(np.median(stated))) ** 2 if len(stated) and np.all(np.isfinite(stated)) else 0.0
    left = max(w * (1.0 - w) * S ** 2, floor) + (sigma * S) ** 2
    return HeadingWeight(w, w_fit, sigma, n, S, float(np.sqrt(left)), True, "", model, rms, limit, b,
                         b_cov_mm2=b_cov)


#: one stop's marks for the weight: with the chord's heading, and per model (xy with the whole fitted slope,
#: the slope, its stated σ) for the models whose bend was fitted
StopMarks = tuple[np.ndarray, dict[str, tuple[np.ndarray, float, float]]]


def stop_marks(applied: Any, rob_P: Any) -> StopMarks:
    """One stop's marks with the chord's heading and with each model's whole fitted slope.

    ``applied``: the stop's :class:`calibration.compensation.Applied` (its ``chord_P_prev`` and
    ``fits``); ``rob_P``: the mark in the robot frame as measured.
    """
    P_at, rob = np.asarray(applied.abs_P_at, float), np.asarray(rob_P, float).reshape(3)
    tilt = (applied.roll_deg, applied.pitch_deg)

    def at(P_prev: Any) -> np.ndarray:
        return np.asarray((robot_pose_at(P_prev, P_at, None, *tilt) @ np.append(rob, 1.0))[:2])

    chord = at(applied.abs_P_prev if applied.chord_P_prev is None else applied.chord_P_prev)
    return chord, {m: (at(P), slope, sigma) for m, (P, slope, sigma) in applied.fits.items()}


def learn_from_stops(stops: list[StopMarks], headings_deg: Any, groups: Any = None) -> HeadingWeight:
    """The weight of the bend model that predicts held-out directions best, or the chord with its own b when
    that predicts them better (calibration/weight_cv.py): among the models whose weight is shown, the one
    with the smaller held-out error, as the chord and the weight are chosen (no significance test: the
    better prediction is what is stored; :func:`bend_model` keeps one). :func:`learn_heading_weight` per
    model from each stop's :func:`stop_marks`; when no model's weight is shown, the lowest's reason.
    ``groups``: each stop's direction (default: its heading to the nearest 45°, the paper's eight)."""
    chord = np.array([c for c, _ in stops], dtype=float).reshape(-1, 2)
    psi = np.asarray(headings_deg, dtype=float).reshape(-1)
    found = [learn_model(stops, psi, groups, model) for model in MODELS]
    shown = [w for w in found if w.applied]  # in MODELS' order: the simplest first
    if not shown:
        return found[0]
    # which model's weight to store is a prediction question, as weight against chord is below: the smaller
    # held-out error decides, significant or not (bend_model keeps the test: a condition must be stable)
    best = min(shown, key=lambda w: (w.cv or {})["weight_rms_mm"])
    cv = best.cv or {}
    p = better(cv["chord_fold_ms_mm2"], cv["weight_fold_ms_mm2"])[1]
    if cv["weight_rms_mm"] < cv["chord_rms_mm"]:
        return replace(best, cv={**cv, "chosen": "weight", "p": p})
    return _chord_instead(best, {**cv, "chosen": "chord", "p": p}, chord, psi, _directions(psi, groups), (
        f"the chord with its own b predicts the directions left out better ({cv['chord_rms_mm']:.4f} mm RMS) "
        f"than weight {best.weight:.2f} with its joint b ({cv['weight_rms_mm']:.4f} mm)"))


def _held_out_choice(fold_ms: list[list[float]]) -> int:
    """The index of the model kept among candidates in MODELS' order (each its per-direction held-out mean
    squared errors): the simplest, replaced by a richer one only when that predicts significantly better
    than the one kept so far (weight_cv.py ``better``)."""
    best = 0
    for i in range(1, len(fold_ms)):
        if better(fold_ms[best], fold_ms[i])[0]:
            best = i
    return best


def _directions(psi: np.ndarray, groups: Any) -> np.ndarray:
    """Each stop's direction: ``groups``, by default the heading to the nearest 45° (the paper's eight)."""
    return np.asarray(groups).reshape(-1) if groups is not None else np.round(psi / 45.0).astype(int) % 8


def _model_inputs(stops: list[StopMarks], headings_deg: Any, groups: Any,
                  model: str) -> tuple[np.ndarray, ...]:
    """(chord marks, marks with the model's whole fitted slope (NaN: none), headings, slopes, their stated σ,
    directions) of the stops for one bend model; directions by default the heading to the nearest 45°."""
    chord = np.array([c for c, _ in stops], dtype=float).reshape(-1, 2)
    psi = np.asarray(headings_deg, dtype=float).reshape(-1)
    g = _directions(psi, groups)
    rec = [fits.get(model, (np.full(2, np.nan), math.nan, math.nan)) for _, fits in stops]
    xy = np.array([r[0] for r in rec], dtype=float).reshape(-1, 2)
    slopes, sig = np.array([r[1] for r in rec], dtype=float), np.array([r[2] for r in rec], dtype=float)
    return chord, xy, psi, slopes, sig, g


def learn_model(stops: list[StopMarks], headings_deg: Any, groups: Any, model: str) -> HeadingWeight:
    """One bend model's weight (:func:`learn_from_stops` without the choice between models), with its
    leave-one-direction-out figures when it is shown in-sample."""
    chord, xy, psi, slopes, sig, g = _model_inputs(stops, headings_deg, groups, model)
    w = learn_heading_weight(chord, xy, psi, slopes, sig, model, g)
    if not w.applied:
        return w
    # shown in-sample: does it also predict the directions it did not see?
    cv = cross_validate(chord, xy, psi, slopes, g, lambda t: learn_heading_weight(
        chord[t], xy[t], psi[t], slopes[t], sig[t], model))
    return replace(w, cv=cv) if cv is not None else _chord_instead(w, None, chord, psi, g, (
        "fewer than 5 directions: the weight cannot be checked on a direction it did not see"))


def _ungated_folds(stops: list[StopMarks], headings_deg: Any, groups: Any, model: str) -> list[float] | None:
    """The model's held-out mean squared errors per direction (weight_cv.py) with its weight not gated, in
    sample and in each fold (applied whenever above 0); None: its bend was fitted at too few stops, or the
    directions are too few."""
    chord, xy, psi, slopes, sig, g = _model_inputs(stops, headings_deg, groups, model)
    if learn_heading_weight(chord, xy, psi, slopes, sig, model, g, gate_z=0.0).n_stops < MIN_STOPS:
        return None
    cv = cross_validate(chord, xy, psi, slopes, g, lambda t: learn_heading_weight(
        chord[t], xy[t], psi[t], slopes[t], sig[t], model, gate_z=0.0))
    return None if cv is None else list(cv["weight_fold_ms_mm2"])


def bend_model(stops: list[StopMarks], headings_deg: Any, groups: Any = None) -> str | None:
    """The bend model the stops' bends are best read by: a description of the paths' shape, not of which
    weight passes the gate. The richer model only when it predicts the directions left out significantly
    better (weight_cv.py ``better``; :func:`learn_from_stops` stores the smaller held-out error, no test),
    with each model's weight not gated, so that it does not change with the gate (calibration/weight_check.py
    compares it). None: the lowest model's figures cannot be made (its bend fitted at too few stops, too few
    directions)."""
    folds = {m: _ungated_folds(stops, headings_deg, groups, m) for m in MODELS}
    if folds[next(iter(MODELS))] is None:
        return None
    made = [(m, f) for m, f in folds.items() if f is not None]  # in MODELS' order, the lowest first
    return made[_held_out_choice([f for _, f in made])][0]


def _chord_instead(w: HeadingWeight, cv: dict[str, Any] | None, chord: np.ndarray, psi: np.ndarray,
                   g: np.ndarray | None, why: str) -> HeadingWeight:
    """``w``'s record turned into the chord's: weight 0, the chord's own b and its covariance, why."""
    b, b_cov = _bias_with(design(psi, np.zeros((len(psi), 2))), chord.reshape(-1), 0.0, g)
    return replace(w, weight=0.0, applied=False, why=why + ": the chord is used", sigma_heading_rad=0.0,
                   rms_mm=math.nan, b_mm=b, b_cov_mm2=b_cov, cv=cv, reason=why)


def weighted_slope(weight: HeadingWeight, slope_rad: float) -> tuple[float, float, str]:
    """(slope to apply, the heading's 1σ, why the chord is kept instead or "") for one stop's fitted end
    slope.

    A slope beyond the learning experiment's limit (:data:`SLOPE_LIMIT` × its slopes' robust scale) is not
    one of the bends the weight was learned on (the fit read something else there: a lean, a jolt); that
    stop keeps the chord.
    """
    if abs(slope_rad) > weight.slope_limit_rad:
        return 0.0, 0.0, (f"the fitted end slope {slope_rad * 1e6:.0f} µrad is beyond the "
                          f"{weight.slope_limit_rad * 1e6:.0f} µrad ({SLOPE_LIMIT:g}× the robust scale) of "
                          f"the slopes the weight was learned on: the chord is used")
    return weight.weight * slope_rad, weight.sigma_heading_rad, ""
