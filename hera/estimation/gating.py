"""Innovation gating: chi-square quantiles without scipy.

A block of dimension m with innovation y and innovation covariance S is consistent with the
model when its normalised innovation squared NIS = y^T S^-1 y is below the chi-square
quantile with m degrees of freedom at probability ``gate`` (seed 000, "innovation gating";
e.g. gate = 0.999). The quantile is computed here: regularised incomplete gamma function
(series / continued fraction), a Wilson-Hilferty first guess, and safeguarded Newton steps.
"""

from __future__ import annotations

import math
from functools import lru_cache

__all__ = ["chi2_cdf", "chi2_ppf", "chi2_sf", "gate_threshold"]

_EPS = 1e-16
_TINY = 1e-300


def _gamma_series(a: float, x: float) -> float:
    """Regularised lower incomplete gamma P(a, x) by its power series (x < a + 1)."""
    term = 1.0 / a
    total = term
    ap = a
    for _ in range(10_000):
        ap += 1.0
        term *= x / ap
        total += term
        if abs(term) < abs(total) * _EPS:
            break
    return total * math.exp(-x + a * math.log(x) - math.lgamma(a))


def _gamma_cont_frac(a: float, x: float) -> float:
    """Regularised upper incomplete gamma Q(a, x) by its continued fraction (x >= a + 1),
    evaluated with the modified Lentz method."""
    b = x + 1.0 - a
    c = 1.0 / _TINY
    d = 1.0 / b
    h = d
    for i in range(1, 10_000):
        an = -i * (i - a)
        b += 2.0
        d = an * d + b
        if abs(d) < _TINY:
            d = _TINY
        c = b + an / c
        if abs(c) < _TINY:
            c = _TINY
        d = 1.0 / d
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < _EPS:
            break
    return h * math.exp(-x + a * math.log(x) - math.lgamma(a))


def _gamma_pq(a: float, x: float) -> tuple[float, float]:
    """(P(a, x), Q(a, x)) with the smaller of the two computed directly (no cancellation)."""
    if x <= 0.0:
        return 0.0, 1.0
    if x < a + 1.0:
        p = _gamma_series(a, x)
        return p, 1.0 - p
    q = _gamma_cont_frac(a, x)
    return 1.0 - q, q


def chi2_cdf(x: float, dof: int) -> float:
    """P(X <= x) for X ~ chi-square with ``dof`` degrees of freedom."""
    return _gamma_pq(0.5 * dof, 0.5 * x)[0]


def chi2_sf(x: float, dof: int) -> float:
    """P(X > x) for X ~ chi-square with ``dof`` degrees of freedom (accurate in the tail)."""
    return _gamma_pq(0.5 * dof, 0.5 * x)[1]


def _chi2_logpdf(x: float, dof: int) -> float:
    k2 = 0.5 * dof
    return (k2 - 1.0) * math.log(x) - 0.5 * x - k2 * math.log(2.0) - math.lgamma(k2)


def _normal_quantile_guess(p: float) -> float:
    """Standard normal quantile, Abramowitz & Stegun 26.2.23 (|error| < 4.5e-4): a first
    guess only."""
    q = p if p < 0.5 else 1.0 - p
    t = math.sqrt(-2.0 * math.log(q))
    z = t - (2.515517 + 0.802853 * t + 0.010328 * t * t) / (
        1.0 + 1.432788 * t + 0.189269 * t * t + 0.001308 * t**3
    )
    return -z if p < 0.5 else z


def chi2_ppf(p: float, dof: int) -> float:
    """Quantile x with P(X <= x) = p for X ~ chi-square(dof); 0 < p < 1, dof >= 1.

    Wilson-Hilferty approximation as the first guess, then Newton steps on the regularised
    gamma function (on the upper tail when p > 0.5), kept inside a shrinking bracket.
    Relative accuracy about 1e-12.
    """
    if not 0.0 < p < 1.0:
        raise ValueError(f"probability must be in (0, 1), got {p!r}")
    if dof < 1:
        raise ValueError(f"degrees of freedom must be >= 1, got {dof!r}")
    if dof == 2:
        return -2.0 * math.log1p(-p)
    upper = p > 0.5
    target = 1.0 - p if upper else p
    k = float(dof)
    z = _normal_quantile_guess(p)
    c = 2.0 / (9.0 * k)
    x = k * max(1.0 - c + z * math.sqrt(c), 0.05) ** 3
    lo, hi = 0.0, math.inf
    for _ in range(200):
        pp, qq = _gamma_pq(0.5 * k, 0.5 * x)
        # g(x) increasing in x; g = 0 at the quantile.
        g = (target - qq) if upper else (pp - target)
        if g > 0.0:
            hi = min(hi, x)
        else:
            lo = max(lo, x)
        dens = math.exp(_chi2_logpdf(x, dof))
        x_new = x - g / dens if dens > 0.0 else math.nan
        if not (lo < x_new < hi) or not math.isfinite(x_new):
            x_new = 0.5 * (lo + hi) if math.isfinite(hi) else 2.0 * x + 1.0
        if abs(x_new - x) <= 1e-14 * max(x, 1e-300):
            return x_new
        x = x_new
    return x


@lru_cache(maxsize=256)
def gate_threshold(gate: float, dof: int) -> float:
    """Cached chi-square quantile used as the NIS gate for a block of dimension ``dof``."""
    return chi2_ppf(gate, dof)
