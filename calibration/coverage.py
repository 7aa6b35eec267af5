"""Does the stated σ hold? An experiment's own scatter against it: the Birge ratio.

Every stop of an 8-direction experiment sees the same mark M. After the model the product
assumes, ``P_i = M + R(ψ_i)·b + e_i`` (calibration/metrics.py ``fit_bias``: the mark and the
robot-frame bias), what is left of each stop's mark is its own error e_i. A mark's stated
``std_mm`` is √trace of its xy covariance, so σ_i/√2 per coordinate; if it holds,

    χ² = Σ_i |r_i|² / (σ_i²/2)   follows χ² with ν = 2N − 4 degrees of freedom (M and b: 4),

and the Birge ratio R_B = √(χ²/ν) is 1 (R. T. Birge, Phys. Rev. 40, 207 (1932)). The parts of
σ that are the same at every stop (the calibration's frozen error: a robot-frame bias, the
reflector mount's: an ACS offset) are absorbed by b and M and left out of σ_i here.

The σ is called inconsistent when χ² exceeds its (1 − :data:`ALPHA`) quantile. Then, as the
Particle Data Group scales the error of an average whose inputs disagree (Review of Particle
Physics, Introduction, "Unconstrained averaging": S = √(χ²/(N − 1)), applied when S > 1), every
stated σ is multiplied by R_B. R_B < 1 never shrinks a σ: the data can show that a σ is too
small, not that a systematic part is absent.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Sequence

import numpy as np

from calibration.metrics import bias_design

#: the test's significance level: a σ that holds is called inconsistent in 1 % of experiments
ALPHA = 0.01
#: the standard normal's (1 − ALPHA) quantile, for the χ² quantile (:func:`chi2_quantile`)
Z_ALPHA = 2.3263
#: σ parts common to every stop of one experiment (absorbed by M and b; calibration/measure.py BLOCKS names)
COMMON_PARTS = ("calibration", "mount")


def chi2_quantile(dof: int, z: float = Z_ALPHA) -> float:
    """The χ² distribution's quantile at the normal quantile ``z`` (Wilson & Hilferty 1931: (χ²/ν)^⅓ is
    nearly normal with mean 1 − 2/(9ν) and variance 2/(9ν); within 1 % of the exact value for ν ≥ 3)."""
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
    scale: float  # birge_ratio when inconsistent, else 1
    n_stops: int
    message: str | None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def scatter_sigma(std_mm: float, parts_mm: dict[str, float]) -> float:
    """A mark's σ without the parts common to every stop (:data:`COMMON_PARTS`; they add in quadrature)."""
    common = sum(float(parts_mm.get(p, 0.0)) ** 2 for p in COMMON_PARTS)
    return math.sqrt(max(std_mm ** 2 - common, 0.0))


def check_sigma(xy: Any, headings_deg: Any, sigma_mm: Sequence[float], what: str = "the marks' stated σ"
                ) -> SigmaCheck | None:
    """The Birge ratio of the marks ``xy`` (N, 2) about M + R(ψ)·b fitted by weighted least squares with
    their σ ``sigma_mm`` (radial, N); None when it cannot be made (fewer than 3 stops beyond the 4 unknowns,
    headings that do not separate M from b, a σ that is not positive)."""
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
    chi2 = float(np.sum(((P.reshape(-1) - A @ theta) * w) ** 2))
    ratio, limit = math.sqrt(chi2 / dof), math.sqrt(chi2_quantile(dof) / dof)
    ok = ratio <= limit
    message = None if ok else (
        f"{what} does not cover the experiment's own scatter: Birge ratio {ratio:.2f} (χ² {chi2:.1f} over "
        f"{dof} degrees of freedom; consistent up to {limit:.2f} at {100 * ALPHA:g} %): every σ stated "
        f"here is scaled by {ratio:.2f}")
    return SigmaCheck(chi2, dof, ratio, limit, ALPHA, ok, 1.0 if ok else ratio, len(P), message)


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


__all__ = ["ALPHA", "COMMON_PARTS", "SigmaCheck", "check_sigma", "chi2_quantile", "scatter_sigma",
           "stored_scale"]
