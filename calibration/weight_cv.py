"""The chord or heading_fit's weight: chosen by what predicts a direction the fit did not see.

Within one experiment the weight w and the robot-frame bias b are fitted together
(calibration/heading_weight.py); in-sample, the richer model always fits at least as well, and
b can trade against w (a bend leaning one way moves every mark as a bias does). So the choice is
made by cross-validation, leaving one direction out at a time (its stops share the floor and the
path there, so a stop's neighbours in its own direction are no unseen data):

* **chord**: M and b fitted to the other directions' chord marks (w = 0);
* **weight**: w learned on the other directions as the experiment learns it (its gate at √2σ
  and slope limit), M and b fitted jointly with it;

each predicts the held-out stops' marks, ``P_k + w·Δ_k`` against ``M + R(ψ_k)·b`` (Δ_k = 0 where the
stop keeps the chord). The held-out RMS (2D, mm) of each is the figure (Stone 1974, "Cross-validatory
choice and assessment of statistical predictions").

Between the two bend models a smaller held-out RMS alone is not a choice: with eight folds it is
itself noisy, and a model that flips from one experiment to the next makes the weight's re-check warn
on an unchanged robot. So the cubic replaces the lowest model only when it predicts *significantly*
better (:func:`better`): the held-out mean squared errors are paired by direction (both models
predict the same held-out stops), and the one-sided sign-flip randomisation test over the
directions' differences (Fisher 1935, *The Design of Experiments* §21; exact, all 2^G sign
patterns, no distribution assumed) must give p < :data:`ALPHA_CHOICE`. Between the chord and the
weight the smaller held-out RMS decides, and the record carries the same test's p: requiring the
weight to be significant too kept the chord on 7 of 40 arcs of the default world and missed the
accuracy goals (docs/accuracy.md, "After stop 38").
"""
from __future__ import annotations

import math
from typing import Any, Callable

import numpy as np

from calibration.metrics import bias_design

#: the fewest directions for a leave-one-direction-out comparison (each fold keeps ≥ 4 to fix M, b and w)
MIN_FOLDS = 5
#: the richer model is kept when the paired test's one-sided p is below this (else the simpler one)
ALPHA_CHOICE = 0.05


def design(headings_deg: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Rows x, y per stop; columns M_x, M_y, b_x, b_y (rotated by ψ_k: calibration/metrics.py), −Δ (the
    weight's)."""
    return np.column_stack([bias_design(headings_deg), -delta.reshape(-1)])


def with_weight(A: np.ndarray, y: np.ndarray, w: float) -> np.ndarray | None:
    """(M_x, M_y, b_x, b_y, w): M + R(ψ)·b fitted with the weight fixed at ``w`` (None: headings too few)."""
    B = A[:, :4]
    if np.linalg.cond(B) > 1e6:
        return None
    return np.append(np.linalg.lstsq(B, y - w * A[:, 4], rcond=None)[0], w)


def _held_out(P: np.ndarray, F: np.ndarray, psi: np.ndarray, fitted: np.ndarray, slopes: np.ndarray,
              train: np.ndarray, w: float, limit: float) -> np.ndarray | None:
    """The held-out stops' residuals (N_test, 2) with the weight ``w`` and slope ``limit`` learned on
    ``train``, M and b fitted on ``train`` with it (None: the training headings cannot fix M and b)."""
    use = fitted & (np.abs(np.nan_to_num(slopes)) <= limit)  # as a later job: beyond the limit, the chord
    delta = np.where(use[:, None], F - P, 0.0)
    A, y = design(psi, delta), P.reshape(-1)
    rows = np.repeat(train, 2)
    theta = with_weight(A[rows], y[rows], w)
    if theta is None:
        return None
    return (y - A @ theta)[~rows].reshape(-1, 2)


def cross_validate(P: np.ndarray, F: np.ndarray, psi: np.ndarray, slopes: np.ndarray, groups: np.ndarray,
                   learn: Callable[[np.ndarray], Any]) -> dict[str, Any] | None:
    """{folds, chord_rms_mm, weight_rms_mm, weight_folds (the weight each fold learned), chord_fold_ms_mm2,
    weight_fold_ms_mm2 (each fold's held-out mean squared 2D error, in the directions' order)} over the
    directions ``groups``; ``learn(train_mask)`` gives the weight record learned on those stops (its
    ``weight``, ``slope_limit_rad``); None with fewer than :data:`MIN_FOLDS` directions or a fold M, b cannot
    be fitted in."""
    names = list(dict.fromkeys(groups.tolist()))
    if len(names) < MIN_FOLDS:
        return None
    fitted = np.all(np.isfinite(F), axis=1) & np.isfinite(slopes)
    chord, weight, ws = [], [], []
    for g in names:
        train = groups != g
        learned = learn(train)
        r_chord = _held_out(P, F, psi, fitted, slopes, train, 0.0, math.inf)
        r_weight = _held_out(P, F, psi, fitted, slopes, train, learned.weight, learned.slope_limit_rad)
        if r_chord is None or r_weight is None:
            return None
        chord.append(r_chord)
        weight.append(r_weight)
        ws.append(float(learned.weight))

    def rms(r: list[np.ndarray]) -> float:  # 2D, as fit_bias's
        return float(np.sqrt(np.mean(np.sum(np.concatenate(r) ** 2, axis=1))))

    def per_fold(r: list[np.ndarray]) -> list[float]:
        return [float(np.mean(np.sum(x ** 2, axis=1))) for x in r]

    return {"folds": len(names), "chord_rms_mm": rms(chord), "weight_rms_mm": rms(weight), "weight_folds": ws,
            "chord_fold_ms_mm2": per_fold(chord), "weight_fold_ms_mm2": per_fold(weight)}


def sign_flip_p(d: Any) -> float:
    """One-sided p of the paired differences ``d`` having a mean > 0: the share of the 2^G sign patterns
    whose mean is at least the observed one (the observed pattern counts: p ≥ 2^−G)."""
    x = np.asarray(d, dtype=float).reshape(-1)
    signs = 1.0 - 2.0 * ((np.arange(2 ** len(x))[:, None] >> np.arange(len(x))) & 1)
    return float(np.mean(signs @ x >= x.sum() - 1e-15 * np.abs(x).sum()))


def better(simpler_ms: Any, richer_ms: Any) -> tuple[bool, float]:
    """(the richer model predicts significantly better, the test's p) from the two models' per-fold held-out
    mean squared errors, paired by direction (:func:`sign_flip_p` of simpler − richer at ALPHA_CHOICE)."""
    a, b = np.asarray(simpler_ms, dtype=float), np.asarray(richer_ms, dtype=float)
    if a.shape != b.shape or a.size < MIN_FOLDS:
        return False, 1.0
    p = sign_flip_p(a - b)
    return p < ALPHA_CHOICE, p
