"""The paper's equations as LEM fields, with the corrected (3.13) and (3.16)."""
from __future__ import annotations

import math
from fractions import Fraction

import numpy as np

from .fields import AnalyticField, PolynomialField
from .validation import check_float, check_int

__all__ = [
    "bernoulli_numbers",
    "moment_rhs_3_16",
    "smooth_friction_field",
    "tanh_ode_field",
    "tanh_taylor_coefficients",
]


def bernoulli_numbers(m: int) -> list:
    """Bernoulli numbers B_0..B_m (B_1 = -1/2) as Fractions."""
    check_int("m", m, 0)
    B = [Fraction(0)] * (m + 1)
    B[0] = Fraction(1)
    for k in range(1, m + 1):
        B[k] = -sum(math.comb(k + 1, j) * B[j] for j in range(k)) / Fraction(k + 1)
    return B


def tanh_taylor_coefficients(degree: int, exact: bool = True) -> list:
    """Coefficients of tanh y = sum_k c_k y**k, k = 0..degree, by the corrected (3.13).

    c_(2k-1) = 2**(2k) (2**(2k) - 1) B_(2k) / (2k)!  (1, -1/3, 2/15, -17/315, ...); the paper
    prints D_sigma**k where the power must be 2k - 1.
    """
    check_int("degree", degree, 0)
    B = bernoulli_numbers(degree + 1)
    c = [Fraction(0)] * (degree + 1)
    for k in range(1, (degree + 1) // 2 + 1):
        if 2 * k - 1 <= degree:
            c[2 * k - 1] = Fraction(2 ** (2 * k) * (2 ** (2 * k) - 1)) * B[2 * k] / math.factorial(2 * k)
    return c if exact else [float(v) for v in c]


def tanh_ode_field(degree: int, exact: bool = True) -> PolynomialField:
    """The paper's (3.10) y' = z, z' = tanh y, with tanh replaced by its degree-``degree`` Taylor
    polynomial (corrected (3.13)); its moment system is the corrected (3.16)."""
    c = tanh_taylor_coefficients(degree, exact)
    return PolynomialField([{(0, 1): 1}, {(k, 0): ck for k, ck in enumerate(c) if ck != 0}])


def moment_rhs_3_16(j: int, k: int, degree: int) -> dict:
    """Right side of the corrected (3.16) for v_jk = y**j z**k, truncated at total degree ``degree``.

    v_jk' = j v_(j-1,k+1) + k sum_m c_(2m-1) v_(j+2m-1,k-1), written out independently of the
    engine so that tests can compare the two. Returns {(j', k'): coefficient (Fraction)}.
    """
    c = tanh_taylor_coefficients(degree + 1)
    out: dict = {}
    if j >= 1 and j + k <= degree:
        out[(j - 1, k + 1)] = out.get((j - 1, k + 1), 0) + Fraction(j)
    if k >= 1:
        for m in range(1, degree + 2):
            p = 2 * m - 1
            if j + p + k - 1 > degree:
                break
            out[(j + p, k - 1)] = out.get((j + p, k - 1), 0) + k * c[p]
    return out


def smooth_friction_field(B: float, eps: float) -> AnalyticField:
    """qdd = -B tanh(qd / eps) as (q, v)' = (v, -B tanh(v / eps)): a smooth Coulomb slide.

    As eps -> 0 it tends to the exact slide qdd = -B sign(qd) (the paper's (2.8) uses tanh(B q),
    of position, with the wrong sign).
    """
    check_float("B", B)
    check_float("eps", eps, 0.0, strict=True)
    B, eps = float(B), float(eps)
    return AnalyticField(lambda t, y: [y[1], -B * np.tanh(y[1] / eps)], 2)
