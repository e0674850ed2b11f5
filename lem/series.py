"""The paper's printed formulas for the Jean-Pratt smooth-sliding branch, and the true series beside them.

Everything whose name ends in ``_printed`` reproduces a formula *as printed* in the seed paper
(section 2 and 4), including its mistakes; the docs' errata page lists them. The functions
without that suffix give what is actually true, so that the two can be set side by side.

Notation (paper): ``t = tan(alpha)``, ``A = m + M t**2``, friction coefficient ``R``,
``kappa = R M t / A`` (the shock number).

Examples
--------
>>> import math
>>> from lem import series
>>> p = dict(m=1.0, M=1.0, alpha=math.pi / 4, R=0.5, g=9.81)
>>> round(series.N0_printed(v0_sign=+1, **p), 4)
26.16
>>> round(series.B_printed(v0_sign=+1, **p), 4)
6.54
>>> series.condition_2_2_printed(**{k: p[k] for k in ("m", "M", "alpha", "R")})
True
"""
from __future__ import annotations

from fractions import Fraction
import math

import numpy as np

from . import jean_pratt

__all__ = [
    "N0_printed",
    "B_printed",
    "tau0_printed",
    "tau0",
    "condition_2_2_printed",
    "series_3_20_printed_coefficients",
    "series_3_20_printed",
    "series_4_1_printed",
    "series_4_2_printed",
    "q_at_tau0_claim_printed",
    "tanh_ode_true_coefficients",
    "tanh_ode_true_series",
    "coulomb_slide",
]


def N0_printed(m: float, M: float, alpha: float, R: float, g: float = 9.81, v0_sign: int = +1) -> float:
    """Sliding normal force N0 = g (m+M) A / (A -+ R M tan(alpha)), paper (2.7) and section 4.

    The sign ``-`` is for v0 > 0 and ``+`` for v0 < 0, as printed (this formula is correct).
    For v0 > 0 and kappa >= 1 it is negative or infinite: no sliding motion exists.
    """
    jean_pratt.check_parameters(m, M, alpha, R, g)
    if v0_sign not in (-1, 1):
        raise ValueError(f"v0_sign must be +1 or -1, got {v0_sign!r}")
    t = jean_pratt.tan_alpha(alpha)
    A = m + M * t * t
    den = A - v0_sign * R * M * t
    if den == 0.0:
        return math.inf
    return g * (m + M) * A / den


def B_printed(m: float, M: float, alpha: float, R: float, g: float = 9.81, v0_sign: int = +1) -> float:
    """Deceleration B = R N0 / A, paper (2.8) and (4.1) (correct as printed)."""
    t = jean_pratt.tan_alpha(alpha)
    return R * N0_printed(m, M, alpha, R, g, v0_sign) / (m + M * t * t)


def tau0_printed(v0: float, B: float) -> float:
    """Stop time tau0 = v0 / B exactly as printed in section 4 (negative for v0 < 0: erratum)."""
    return v0 / B


def tau0(v0: float, B: float) -> float:
    """The true stop time |v0| / B of Coulomb sliding with deceleration B."""
    return abs(v0) / B


def condition_2_2_printed(m: float, M: float, alpha: float, R: float) -> bool:
    """Condition (2.2) for the Jean-Pratt scene as printed: R M tan(alpha) / A < 1, i.e. kappa < 1.

    The paper states it backwards: it is the condition for a sliding
    solution with v0 > 0; for v0 < 0 (and tan(alpha) > 0) one always exists.
    """
    return jean_pratt.kappa(m, M, alpha, R) < 1.0


def series_3_20_printed_coefficients(z0: float, terms: int = 5) -> np.ndarray:
    """Coefficients c_1..c_5 of the printed series (3.20), y = sum c_k x^k.

    y = z0 x - x^2/2 + 4/(5 z0) x^3 - 3/(5 z0^2) x^4 + 32/(75 z0^3) x^5. Printed only to x^5; the
    series does *not* solve (3.9) (its y''(0) = -1 while tanh(0) = 0).
    """
    if not 1 <= terms <= 5:
        raise ValueError(f"terms must be between 1 and 5 (the paper prints five), got {terms!r}")
    if z0 == 0 or not np.isfinite(z0):
        raise ValueError(f"z0 must be finite and non-zero (the printed series divides by it), got {z0!r}")
    c = np.array([z0, -0.5, 4.0 / (5.0 * z0), -3.0 / (5.0 * z0**2), 32.0 / (75.0 * z0**3)])
    return c[:terms]


def series_3_20_printed(x, z0: float, terms: int = 5) -> np.ndarray:
    """The printed series (3.20) evaluated at x (as printed; see :func:`tanh_ode_true_series`)."""
    c = series_3_20_printed_coefficients(z0, terms)
    x = np.asarray(x, dtype=float)
    return sum(ck * x ** (k + 1) for k, ck in enumerate(c))


def _series_4(t, v0: float, B: float, sign: int, terms: int) -> np.ndarray:
    if not 1 <= terms <= 5:
        raise ValueError(f"terms must be between 1 and 5, got {terms!r}")
    if v0 == 0 or not np.isfinite(v0):
        raise ValueError(f"v0 must be finite and non-zero (the printed series divides by it), got {v0!r}")
    if not (np.isfinite(B) and B > 0):
        raise ValueError(f"B must be finite and > 0, got {B!r}")
    t = np.asarray(t, dtype=float)
    c = [v0, sign * B / 2, 0.8 * B**2 / v0, -0.6 * B**3 / v0**2, 32.0 / 75.0 * B**4 / v0**3]
    return sum(ck * t ** (k + 1) for k, ck in enumerate(c[:terms]))


def series_4_1_printed(t, v0: float, B: float, terms: int = 5) -> np.ndarray:
    """Series (4.1) as printed, for v0 > 0: q = v0 t - B/2 t^2 + 4/5 B^2/v0 t^3 - 3/5 B^3/v0^2 t^4
    + 32/75 B^4/v0^3 t^5.

    Only the first two terms are right (they are the exact Coulomb slide, :func:`coulomb_slide`).
    """
    return _series_4(t, v0, B, -1, terms)


def series_4_2_printed(t, v0: float, B: float, terms: int = 5) -> np.ndarray:
    """Series (4.2) as printed, for v0 < 0: q = v0 t + B/2 t^2 + 4/5 B^2/v0 t^3 - ... (as printed)."""
    return _series_4(t, v0, B, +1, terms)


def q_at_tau0_claim_printed(v0: float, B: float) -> float:
    """The paper's claim "q = 0.42 v0^2 / B at t = tau0" (not reproduced by anything; the exact
    Coulomb value is 0.5 v0^2/B)."""
    return 0.42 * v0**2 / B


def tanh_ode_true_coefficients(z0, order: int = 7) -> list:
    """Exact Taylor coefficients of the solution of (3.9) y'' = tanh y, y(0) = 0, y'(0) = z0.

    Computed by exact power-series arithmetic (rational if ``z0`` is an int or Fraction), so it
    serves as an independent reference for the LEM engine. Returns [c_0, ..., c_order].
    Physics.md section 5: y = z0 x + z0 x^3/6 - z0(2 z0^2 - 1) x^5/120
    + z0(16 z0^4 - 22 z0^2 + 1) x^7/5040 + O(x^9).
    """
    if order < 1:
        raise ValueError(f"order must be >= 1, got {order!r}")
    exact = isinstance(z0, (int, Fraction))
    one = Fraction(1) if exact else 1.0
    z0 = Fraction(z0) if exact else float(z0)
    # tanh y = sum_k d_k y^(2k+1); d_k from the Bernoulli expansion, generated via tanh' = 1 - tanh^2.
    nt = order + 2
    th = [0 * one] * nt  # series of tanh(u) in u
    th[1] = one
    for k in range(2, nt):
        # (k) th_k = [1 - th^2]_{k-1}
        sq = sum(th[i] * th[k - 1 - i] for i in range(k))
        th[k] = ((one if k - 1 == 0 else 0 * one) - sq) / k
    y = [0 * one] * (order + 1)
    y[1] = z0
    # Picard-style: y_{n+2} (n+2)(n+1) = [tanh(y)]_n, filled order by order.
    for n in range(0, order - 1):
        # powers of y (series) truncated at degree n
        ypow = [one] + [0 * one] * n  # y^0
        tn = 0 * one
        cur = ypow
        for k in range(1, n + 1):
            cur = [sum(cur[i] * y[j - i] for i in range(j + 1)) for j in range(n + 1)]  # y^k
            if th[k] != 0:
                tn += th[k] * cur[n]
        y[n + 2] = tn / ((n + 2) * (n + 1))
    return y


def tanh_ode_true_series(x, z0: float, order: int = 7) -> np.ndarray:
    """The true Taylor polynomial of (3.9) up to x^order (see :func:`tanh_ode_true_coefficients`)."""
    c = [float(ck) for ck in tanh_ode_true_coefficients(float(z0), order)]
    x = np.asarray(x, dtype=float)
    return sum(ck * x**k for k, ck in enumerate(c))


def coulomb_slide(t, v0: float, B: float) -> np.ndarray:
    """Exact Coulomb motion with constant deceleration B from q = 0: slide, then stick at v0|v0|/(2B)."""
    t = np.asarray(t, dtype=float)
    ts = abs(v0) / B
    tc = np.minimum(t, ts)
    return v0 * tc - np.sign(v0) * B * tc**2 / 2


_MOVED = ("tan_alpha", "check_parameters", "kappa")


def __getattr__(name):
    # the scene's parameters moved to lem.jean_pratt; the old names keep working for a while
    if name in _MOVED:
        import warnings
        warnings.warn(f"lem.series.{name} moved to lem.jean_pratt.{name}", DeprecationWarning, stacklevel=2)
        return getattr(jean_pratt, name)
    raise AttributeError(f"module 'lem.series' has no attribute {name!r}")
