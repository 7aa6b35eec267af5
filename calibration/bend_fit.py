"""The heading at the end of a bent straight move, from the tracker's stream, only when the bend is shown.

The stream gives the reflector's path between the two standstill points ``P_prev`` and
``P_at`` (the anchors). Its lateral offset from the chord, ``e(s)`` with ``x = s/L``, is
fitted with the lowest-degree polynomial (2: one arc; 3: an S-curve or an arc over part of the
move; up to ``MAX_DEGREE``) whose residuals match the stream's own noise. The end slope
``e'(L)`` turns the chord.

Both inputs are noisy. Anchoring the shape exactly at the standstill points turns their
error into an end slope of ~2.5 σ_a / L (10 µm over 200 mm: 125 µrad, more than the chord's
own 70 µrad), so the anchors are weighted observations here, as the stream points are (see
:func:`bend_fit`). The fitted end slope is used only when it cannot be worse than the chord
or when the bend it shows is significant; otherwise the chord stays and
:attr:`BendFit.why` says so. A path whose shape the fit does not model falls back to the
chord too.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from calibration.registration import as_points

#: the fewest stream points and the shortest span a heading fit accepts
MIN_FIT_POINTS, MIN_FIT_SPAN_MM = 5, 20.0
#: an end slope is applied only beyond this many standard errors (a straight drive passes 3σ 0.3 % of the
#: time)
SIGNIFICANCE = 3.0
#: the highest polynomial degree of the path's lateral offset; beyond it the chord is kept
MAX_DEGREE = 5
#: a degree fits when its residual variance is within this many standard errors of the stream's noise
LACK_OF_FIT_Z = 3.5
#: z of the test that a richer model gives the same end slope
HAUSMAN_Z = 2.5
#: names of the shapes by degree (2: one arc, 3: an S-curve or a partial arc)
SHAPES = {2: "arc", 3: "s-curve", 4: "higher-order", 5: "higher-order"}
#: the share of the move at its end whose residuals show what the fitted path misses there (a kink)
END_FRACTION = 0.2
#: the least lateral noise a stream point is credited with (an interferometer's resolution, not a real
#: tracker's noise): it keeps noise-free synthetic paths from calling rounding a shape
STREAM_SIGMA_FLOOR_MM = 0.0005


@dataclass(frozen=True)
class BendFit:
    """The end tangent of a move: the fitted one when the bend is significant, else the chord's."""

    direction: np.ndarray  # unit (3,), z = 0, the travel direction at the end
    slope_rad: float  # fitted end slope against the chord
    sigma_rad: float  # its standard error (stream and anchor noise)
    shape: str  # "arc", "s-curve", "higher-order", or "other" (not modelled: the chord is kept)
    stream_sigma_mm: float  # the stream's lateral noise, from second differences of neighbouring points
    significant: bool
    why: str  # why the chord was kept ("" when the fit is used)
    #: the end slope the fitted path misses near the stop (rad): the fitted end slope against a line through
    #: the stream's last :data:`END_FRACTION` of the move, beyond that line's noise (a kink there); 0 when
    #: none is seen
    end_lack_of_fit_rad: float = 0.0


def _frame(points: object, abs_P_prev: object, abs_P_at: object) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                          np.ndarray, float]:
    """(x = s/L, e, u, n, L) of the stream points strictly between the anchors."""
    P = as_points(points, "points")[:, :2]
    a = as_points(abs_P_prev, "abs_P_prev", 1)[0][:2]
    b = as_points(abs_P_at, "abs_P_at", 1)[0][:2]
    L = float(np.linalg.norm(b - a))
    if len(P) < MIN_FIT_POINTS or L < MIN_FIT_SPAN_MM:
        raise ValueError(f"fit_heading: {len(P)} stream points over a {L:.1f} mm move "
                         f"(need >= {MIN_FIT_POINTS} points over >= {MIN_FIT_SPAN_MM:.0f} mm)")
    u = (b - a) / L
    n = np.array([-u[1], u[0]])
    x, e = (P - a) @ u / L, (P - a) @ n
    inside = (x > 0.02) & (x < 0.98)  # the ends carry no bend information
    if np.count_nonzero(inside) < MIN_FIT_POINTS + 1:
        raise ValueError(f"fit_heading: only {np.count_nonzero(inside)} stream points lie between the two "
                         f"stops")
    return x[inside], e[inside], u, n, L


def _rss(A: np.ndarray, e: np.ndarray) -> float:
    r = e - A @ np.linalg.lstsq(A, e, rcond=None)[0]
    return float(r @ r)


def _shape(x: np.ndarray, e: np.ndarray, min_degree: int = 2) -> tuple[int, float]:
    """(polynomial degree, stream noise σ_s): the lowest degree the stream's residuals cannot tell from noise.

    The noise comes from second differences of neighbouring points (a smooth path's curvature
    adds nothing at mm spacing), so it does not depend on the model; a degree whose residual
    variance exceeds it by more than chance allows is rejected. Degree 0 means none up to
    ``MAX_DEGREE`` fits: a shape the fit does not model.
    """
    order = np.argsort(x)
    d2 = np.diff(e[order], 2)
    var_s = max(float(d2 @ d2) / (6.0 * max(len(d2), 1)), STREAM_SIGMA_FLOOR_MM ** 2)
    for deg in range(min_degree, MAX_DEGREE + 1):
        dof = len(x) - deg - 1
        if dof < 3:
            break
        ratio = _rss(np.vander(x, deg + 1, increasing=True), e) / dof / var_s
        if ratio < 1.0 + LACK_OF_FIT_Z * np.sqrt(2.0 / dof):
            return deg, float(np.sqrt(var_s))
    return 0, float(np.sqrt(var_s))


def _end_slope(x: np.ndarray, e: np.ndarray, deg: int, sig_s: float, anchor_sigma_mm: float,
               L: float) -> tuple[float, float]:
    """(end slope, its variance) of the degree-``deg`` path fitted to the stream and the two anchors."""
    A = np.vstack([np.vander(x, deg + 1, increasing=True),
                   np.vander(np.array([0.0, 1.0]), deg + 1, increasing=True)])  # e(0), e(1): 0 ± σ_a
    w = np.concatenate([np.full(len(x), 1.0 / sig_s ** 2), np.full(2, 1.0 / anchor_sigma_mm ** 2)])
    cov = np.linalg.inv(A.T @ (A * w[:, None]))
    theta = cov @ (A.T @ (w * np.concatenate([e, [0.0, 0.0]])))
    d = np.arange(deg + 1, dtype=float) / L  # d/ds of x^k at s = L
    return float(d @ theta), float(d @ cov @ d)


def _end_lack_of_fit(x: np.ndarray, e: np.ndarray, slope: float, var: float, sig_s: float, L: float) -> float:
    """How far the fitted end ``slope`` (variance ``var``) is from what the stream's last :data:`END_FRACTION`
    of the move shows by itself (a line through those points: a kink or a late bend leaves the end straight,
    where a polynomial over the whole move over- or undershoots). Only a difference beyond
    :data:`SIGNIFICANCE` of its noise counts (the line's slope sits mid-window, which on a smooth bend differs
    a little from the end's); then √(d² − var_d), an unbiased estimate of the squared slope missed (rad), else
    0."""
    end = x >= 1.0 - END_FRACTION
    if np.count_nonzero(end) < MIN_FIT_POINTS:
        return 0.0
    s = x[end] * L - float(np.mean(x[end] * L))  # mm along the move, centred
    line = float(s @ (e[end] - np.mean(e[end]))) / float(s @ s)  # the end's own slope
    d2, var_d = (slope - line) ** 2, sig_s ** 2 / float(s @ s) + var
    return float(np.sqrt(d2 - var_d)) if d2 > SIGNIFICANCE ** 2 * var_d else 0.0


def bend_fit(points: object, abs_P_prev: object, abs_P_at: object, anchor_sigma_mm: float = 0.010,
             significance: float = SIGNIFICANCE, min_degree: int = 2) -> BendFit:
    """The end tangent from the stream and the anchors, weighted by their noise; see the module's docstring.

    The lateral path ``e(x) = θ·basis(x)`` in the measured chord's frame is fitted by weighted
    least squares to the stream (σ_s from its own residuals) and to the two anchors, where the
    true path passes ``0 ± σ_a`` from the chord. The end slope ``e'(L)`` is then the heading's
    correction and ``dᵀ(AᵀWA)⁻¹d`` its whole error variance. It is used when it is at least as
    precise as the chord's own ``2σ_a²/L²`` (then it cannot lose even on a straight drive), or when
    the bend it shows exceeds ``significance`` standard errors; else the chord stays.
    ``min_degree`` 3 fits at least a cubic, which an S-curve's end slope needs even where the stream's noise
    hides its asymmetry (unbiased for an arc too, but noisier).
    """
    x, e, u, n, L = _frame(points, abs_P_prev, abs_P_at)
    deg, sig_s = _shape(x, e, min_degree)
    shape = SHAPES.get(deg, "other")
    if deg == 0:  # the richest model's slope still says how far the chord may be off (the stop's own scale)
        top = min(MAX_DEGREE, len(x) - 2)
        slope, var = _end_slope(x, e, top, sig_s, anchor_sigma_mm, L) if top >= 2 else (0.0, np.inf)
        return BendFit(np.array([u[0], u[1], 0.0]), slope, float(np.sqrt(var)), shape, sig_s, False,
                       f"the path along the move has a shape the fit does not model (no polynomial up to "
                       f"degree {MAX_DEGREE} leaves only the stream's noise of {sig_s * 1000:.1f} µm): the "
                       f"chord is used")
    slope, var = _end_slope(x, e, deg, sig_s, anchor_sigma_mm, L)
    for more in (1, 2):  # the slope must not hinge on the model: richer models must agree (a Hausman test)
        slope2, var2 = _end_slope(x, e, deg + more, sig_s, anchor_sigma_mm, L)
        if abs(slope2 - slope) > HAUSMAN_Z * np.sqrt(max(var2 - var, 1e-18)):
            # its σ holds the models' disagreement: how far the chord may be off is not better known
            return BendFit(np.array([u[0], u[1], 0.0]), slope, float(np.sqrt(var + (slope2 - slope) ** 2)),
                           "other", sig_s, False,
                           f"the end slope depends on the path's model ({slope * 1e6:.0f} µrad as {shape}, "
                           f"{slope2 * 1e6:.0f} µrad with {more} degree(s) more): a shape the fit does not "
                           f"model; the chord is used")
    sigma = float(np.sqrt(var))
    chord_sigma = np.sqrt(2.0) * anchor_sigma_mm / L
    significant = sigma <= chord_sigma or abs(slope) > significance * sigma
    why = "" if significant else (
        f"no significant bend: the end slope {slope * 1e6:.0f} µrad is within {significance:g}σ "
        f"({significance * sigma * 1e6:.0f} µrad; stream noise {sig_s * 1000:.1f} µm, anchors "
        f"{anchor_sigma_mm * 1000:.1f} µm): the chord is used")
    t = u + slope * n if significant else u
    t = t / np.linalg.norm(t)
    return BendFit(np.array([t[0], t[1], 0.0]), slope, sigma, shape, sig_s, significant, why,
                   _end_lack_of_fit(x, e, slope, var, sig_s, L))


def fit_heading(points: Any, abs_P_prev: Any, abs_P_at: Any, anchor_sigma_mm: float = 0.010) -> np.ndarray:
    """Unit ACS direction (z = 0) of a bent move's tangent at its end; ValueError when no bend is shown.

    See :func:`bend_fit` (calibration/bend_fit.py): the chord turned by the fitted end slope,
    only when the bend is significant against the anchors' and the stream's noise.
    """
    fit = bend_fit(points, abs_P_prev, abs_P_at, anchor_sigma_mm)
    if not fit.significant:
        raise ValueError(fit.why)
    return fit.direction


def fit_heading_sigma(fit_sigma_rad: float, anchor_sigma_mm: float, length_mm: float) -> float:
    """The heading fit's σ less the chord's tracker part 2σ_a²/L², which measure_mark's Jacobian already
    carries through the two tracker points (the fit's σ counts its anchors' noise too)."""
    chord_var = 2.0 * (anchor_sigma_mm / length_mm) ** 2
    return float(np.sqrt(max(fit_sigma_rad ** 2 - chord_var, 0.0)))


def chord_sigma(fit: BendFit, anchor_sigma_mm: float, length_mm: float) -> float:
    """The chord's heading σ at a stop that keeps it, from the stop's own fit (0 when the fit states none).

    The chord is off the end tangent by the true end slope, known as the fitted one ± its σ, and by what the
    fit misses at the end: the expected squared error is slope² + σ² + missed² (less the anchors' part, which
    measure_mark carries through the two tracker points). A caller keeps the a-priori σ where this is smaller:
    a turn near the stop whose trace across the stream is below its noise (250 µrad over the last 20 mm: 5 µm)
    is invisible to the fit but not to the chord.
    """
    own = float(np.sqrt(fit.slope_rad ** 2 + fit.sigma_rad ** 2 + fit.end_lack_of_fit_rad ** 2))
    return fit_heading_sigma(own, anchor_sigma_mm, length_mm) if np.isfinite(own) else 0.0
