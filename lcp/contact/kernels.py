"""Per-contact compiled kernels shared by the planar and spatial Gauss-Seidel sweeps and the compiled loop.

- :func:`local_planar`: the exact solution of one planar contact's Coulomb problem;
- :func:`row_dot`, :func:`row_absdot`: a CSR row times a vector (and its absolute value);
- :func:`contact_residual`: one contact's natural-map residual;
- :func:`contact_scale`: one contact's impulse scale (the contact-by-contact tolerances).

They are inlined into their callers at numba's level (``inline="always"``): a call per contact
would cost more than the work. Imports :mod:`lcp.numerics.jit` only.
"""
from __future__ import annotations


import numpy as np

from lcp.contact.law import COUPLING_FLOOR
from lcp.numerics.jit import njit

__all__ = ["OPEN", "STICK", "SLIDE_POS", "SLIDE_NEG", "contact_residual", "contact_scale", "local_planar",
           "row_absdot", "row_dot"]

#: local outcome codes (as lcp.contact.problem's modes; -1: no closed-form case admissible)
OPEN, STICK, SLIDE_POS, SLIDE_NEG = 0, 1, 2, 3


@njit(cache=True, inline="always")
def local_planar(W00, W01, W10, W11, qN, qT, mu):
    """Exact solution (pN, pT, mode) of one planar contact u = W r + q (mode -1: none admissible)."""
    scale = max(abs(qN) / W00, abs(qT) / W11 if W11 > 0 else 0.0, 1e-300)
    tol = 1e-13 * scale
    if qN / W00 >= -tol:
        return 0.0, 0.0, OPEN
    det = W00 * W11 - W01 * W10
    if det > 0:
        pN = (-qN * W11 + qT * W01) / det
        pT = (-qT * W00 + qN * W10) / det
        if pN >= -tol and abs(pT) <= mu * pN + tol:
            return pN, pT, STICK
    a = W00 - mu * W01
    if a > 0:
        pN = -qN / a
        uT = (W10 - mu * W11) * pN + qT
        if pN >= -tol and uT >= -tol * W11:
            return pN, -mu * pN, SLIDE_POS
    a = W00 + mu * W01
    if a > 0:
        pN = -qN / a
        uT = (W10 + mu * W11) * pN + qT
        if pN >= -tol and uT <= tol * W11:
            return pN, mu * pN, SLIDE_NEG
    return np.nan, np.nan, -1


@njit(cache=True, inline="always")
def row_dot(indptr, indices, data, x, i):
    s = 0.0
    for p in range(indptr[i], indptr[i + 1]):
        s += data[p] * x[indices[p]]
    return s


@njit(cache=True, inline="always")
def contact_residual(pN, pT, uN, uT, mu, rhoN, rhoT):
    """The natural map of one planar contact, max(|min(p_N, rho_N u_N)|, |p_T - proj(p_T - rho_T u_T)|)."""
    s = mu * max(pN, 0.0)
    z = min(max(pT - rhoT * uT, -s), s)
    return max(abs(min(pN, rhoN * uN)), abs(pT - z))


@njit(cache=True, inline="always")
def contact_scale(pN, pT, qN, qT, rhoN, rhoT, aN, aT, floor):
    """Impulse scale of one contact: its impulses, or those that would cancel its free velocity,
    at least COUPLING_FLOOR of rho times the terms of its velocity (aN, aT: the rows of |W| |p|)
    and ``floor`` (SCALE_FLOOR times the problem's scale).

    Acceptance and mode thresholds are taken relative to each contact's own scale as well as to
    the problem's: with bodies of very different masses (1e8 apart, say) a tolerance on the heavy
    contacts' scale alone accepts light contacts' impulses with no correct digit."""
    return max(abs(qN) * rhoN, abs(qT) * rhoT, abs(pN), abs(pT),
               COUPLING_FLOOR * rhoN * aN, COUPLING_FLOOR * rhoT * aT, floor, 1e-300)


@njit(cache=True, inline="always")
def row_absdot(indptr, indices, data, x, i):
    s = 0.0
    for p in range(indptr[i], indptr[i + 1]):
        s += abs(data[p] * x[indices[p]])
    return s
