"""Does the stated σ hold? An experiment's own scatter against it: the Birge ratio.

Every stop of an 8-direction experiment sees the same mark M. After the model the product
assumes, ``P_i = M + R(ψ_i)·b + e_i`` (calibration/metrics.py ``fit_bias``: the mark and the
robot-frame bias), what is left of each stop's mark is its own error e_i. A mark's stated
``std_mm`` is √trace of its xy covariance, so σ_i/√2 per coordinate; if it holds,

    χ² = Σ_i |r_i|² / (σ_i²/2)   follows χ² with ν = 2N − 4 degrees of freedom (M and b: 4),

and the Birge ratio R_B = √(χ²/ν) is 1 (R. T. Birge, Phys. Rev. 40, 207 (1932)). The parts of
σ that are the same at every stop (the calibration's frozen error: a robot-frame bias, the
reflector mount's: an ACS offset; the stored bias's own error: R(ψ)·δb) are absorbed by b and M and left
out of σ_i here.

A variance is not a coverage. A mark's σ is read as an isotropic 2-D Gaussian's: |e| ≤ 1.73 σ
at 95 % (:data:`P95_RADIUS`). An error along one line (a heading error moves the mark
perpendicular to the camera's lever arm only) or with heavy tails (a kink at a random point of the
move) can have R_B ≈ 1 and still leave far more than 5 % of the stops outside 1.73 σ. So the
coverage is tested as well: each stop's residual over its σ, corrected for what the fit took
(√(ν/2N), the mean leverage), is beyond 1.73 with probability 5 % when the σ holds; k of N stops
beyond it is a binomial count, called inconsistent when P(X ≥ k) < :data:`ALPHA`.

The σ is called inconsistent when either test fails (each at α: together at most 2α). The factor
every stated σ is multiplied by is the larger of R_B and the coverage factor k₉₅ = q₉₅/1.73 (q₉₅:
the 95th percentile of the normalised residuals; the factor that makes the experiment's own
residuals covered at 95 %, the coverage factor of JCGM 100:2008 (GUM) §6.2–6.3 taken from the
data's own distribution as JCGM 101:2008 §7.7 does), and it is applied whenever it exceeds 1, as
the Particle Data Group applies its S = √(χ²/(N − 1)) whenever S > 1, significant or not (Review of
Particle Physics, Introduction, "Unconstrained averaging"); the verdict warns only when a test
fails. A factor < 1 never shrinks a σ: the data can show that a σ is too small, not that a
systematic part is absent.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Any, Sequence

import numpy as np

from calibration.metrics import bias_design

#: the test's significance level: a σ that holds is called inconsistent in 1 % of experiments
ALPHA = 0.01
#: the standard normal's (1 − ALPHA) quantile, for the χ² quantile (:func:`chi2_quantile`)
Z_ALPHA = 2.3263
#: σ parts common to every stop of one experiment (absorbed by M and b; calibration/measure.py BLOCKS; the
#: stored bias's, calibration/bias_check.py, is R(ψ)·δb: taken up by b)
COMMON_PARTS = ("calibration", "mount", "bias")
#: |e|/σ's 95 % point for an isotropic 2-D Gaussian of radial σ: √(χ²₂(0.95)/2) = √(5.991/2)
P95_RADIUS = 1.7308
#: the share of stops beyond :data:`P95_RADIUS` when the σ holds
P_BEYOND = 0.05


def chi2_quantile(dof: int, z: float = Z_ALPHA) -> float:
    """The χ² distribution's quantile at the normal quantile ``z`` (Wilson & Hilferty 1931: (χ²/ν)^⅓ is
    nearly normal with mean 1 − 2/(9ν) and variance 2/(9ν); within 1 % of the exact value for
    ν ≥ 3)."""
    v = 2.0 / (9.0 * dof)
    return dof * (1.0 - v + z * math.sqrt(v)) ** 3


@dataclass(frozen=True)
class SigmaCheck:
    """The experiment's scatter against its stated σ; ``scale`` multiplies every stated σ (1: it holds)."""

    chi2: float
    dof: int
    birge_ratio: float  # √(χ²/ν)
    limit_ratio: float  # √(χ²_{ν,1−α}/ν): the ratio beyond which the σ is inconsistent
    alpha: float
    ok: bool
    scale: float  # max(1, birge_ratio, coverage_factor)
    n_stops: int
    message: str | None
    n_beyond: int = 0  # stops whose normalised residual is beyond P95_RADIUS
    p_beyond: float = 1.0  # P(X ≥ n_beyond) for X ~ Binomial(n_stops, P_BEYOND)
    coverage_factor: float = 0.0  # q95 of the normalised residuals / P95_RADIUS

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def binomial_tail(k: int, n: int, p: float) -> float:
    """P(X ≥ k) for X ~ Binomial(n, p), summed exactly."""
    return float(sum(math.comb(n, i) * p ** i * (1.0 - p) ** (n - i) for i in range(max(k, 0), n + 1)))


def scatter_sigma(std_mm: float, parts_mm: dict[str, float]) -> float:
    """A mark's σ without the parts common to every stop (:data:`COMMON_PARTS`; they add in quadrature)."""
    common = sum(float(parts_mm.get(p, 0.0)) ** 2 for p in COMMON_PARTS)
    return math.sqrt(max(std_mm ** 2 - common, 0.0))


def _coverage(r: np.ndarray, s: np.ndarray, dof: int) -> tuple[int, float, float]:
    """(stops beyond P95_RADIUS, the binomial P of that many or more, the coverage factor q95/P95_RADIUS)
    of the residuals ``r`` (N, 2) over their radial σ ``s``, each σ shrunk by the fit's mean leverage."""
    z = np.linalg.norm(r, axis=1) / (s * math.sqrt(dof / (2.0 * len(s))))
    k = int(np.count_nonzero(z > P95_RADIUS))
    return k, binomial_tail(k, len(s), P_BEYOND), float(np.percentile(z, 95)) / P95_RADIUS


def _message(what: str, c: SigmaCheck) -> str | None:
    """The warning naming the figure that failed, and the factor every σ got."""
    why = []
    if c.birge_ratio > c.limit_ratio:
        why.append(f"Birge ratio {c.birge_ratio:.2f} (χ² {c.chi2:.1f} over {c.dof} degrees of freedom; "
                   f"consistent up to {c.limit_ratio:.2f} at {100 * c.alpha:g} %)")
    if c.p_beyond < c.alpha:
        why.append(f"{c.n_beyond} of {c.n_stops} stops beyond {P95_RADIUS:.2f} σ where "
                   f"{P_BEYOND * c.n_stops:.0f} are expected (P {c.p_beyond:.1e} < {c.alpha:g}; coverage "
                   f"factor {c.coverage_factor:.2f})")
    if why:
        return (f"{what} does not cover the experiment's own scatter: {'; '.join(why)}: every σ stated here "
                f"is scaled by {c.scale:.2f}")
    return None if c.scale <= 1.0 else (
        f"{what} is scaled by {c.scale:.2f} to cover the experiment's own scatter (Birge ratio "
        f"{c.birge_ratio:.2f}, coverage factor {c.coverage_factor:.2f}: both within the checks at "
        f"{100 * c.alpha:g} %)")


def check_sigma(xy: Any, headings_deg: Any, sigma_mm: Sequence[float], what: str = "the marks' stated σ"
                ) -> SigmaCheck | None:
    """The Birge ratio and the 95 % coverage of the marks ``xy`` (N, 2) about M + R(ψ)·b fitted by weighted
    least squares with their σ ``sigma_mm`` (radial, N); None when it cannot be made (fewer than 3 stops
    beyond the 4 unknowns, headings that do not separate M from b, a σ that is not positive)."""
    P = np.asarray(xy, dtype=float).reshape(-1, 2)
    psi = np.asarray(headings_deg, dtype=float).reshape(-1)
    s = np.asarray(sigma_mm, dtype=float).reshape(-1)
    dof = 2 * len(P) - 4
    if len(P) != len(psi) or len(P) != len(s) or dof < 3 or not np.all(s > 0) or not np.all(np.isfinite(P)):
        return None
    A = bias_design(psi)
    w = np.repeat(np.sqrt(2.0) / s, 2)  # 1 / (σ_i/√2) per coordinate
    if np.linalg.cond(A * w[:, None]) > 1e6:
        return None
    theta, *_ = np.linalg.lstsq(A * w[:, None], P.reshape(-1) * w, rcond=None)
    r = P.reshape(-1) - A @ theta
    chi2 = float(np.sum((r * w) ** 2))
    ratio, limit = math.sqrt(chi2 / dof), math.sqrt(chi2_quantile(dof) / dof)
    k, p, factor = _coverage(r.reshape(-1, 2), s, dof)
    ok = ratio <= limit and p >= ALPHA
    c = SigmaCheck(chi2, dof, ratio, limit, ALPHA, ok, max(1.0, ratio, factor), len(P), None, k, p, factor)
    return replace(c, message=_message(what, c))


def stored_scale(record: Any) -> tuple[float, str]:
    """(scale, why not read: "" when read) from a calibration's ``sigma_check`` record (1 without one)."""
    if not record:
        return 1.0, ""
    try:
        scale = float(record["scale"])
    except (KeyError, TypeError, ValueError) as exc:
        return 1.0, f"calibration: sigma_check is not a σ check record ({exc!r}): σ not scaled"
    if not (math.isfinite(scale) and scale >= 1.0):
        return 1.0, f"calibration: sigma_check scale={scale} must be >= 1: σ not scaled"
    return scale, ""
