"""Per-contact compiled kernels of the Gauss-Seidel sweeps (planar and spatial) and the compiled loop.

Where a kernel differs by law its twin stands beside it:

- :func:`local_planar` / :func:`local_disk3`: the exact solution of one contact's Coulomb problem,
  planar (2 x 2) or disk (3 x 3: open, stick, slide with its direction by Newton in the angle and,
  failing that, all roots of a quartic in exp(i t));
- :func:`contact_residual` / :func:`disk_residual`: one contact's natural-map residual;
- :func:`row_dot`, :func:`row_absdot`: a CSR row times a vector (and its absolute value);
- :func:`contact_scale`: one contact's impulse scale (the contact-by-contact tolerances).

They are inlined into their callers at numba's level (``inline="always"``): a call per contact
would cost more than the work (the disk kernels are plain compiled calls). Imports
:mod:`lcp.contact.law` (its floors) and :mod:`lcp.numerics.jit` only: it must not import any
problem or solver.
"""
from __future__ import annotations


import math

import numpy as np

from lcp.contact.law import COUPLING_FLOOR
from lcp.numerics.jit import njit

__all__ = ["OPEN", "SLIDE", "SLIDE_NEG", "SLIDE_POS", "STICK", "contact_residual", "contact_scale", "disk_residual",
           "local_disk3", "local_planar", "row_absdot", "row_dot", "solve3"]

#: local outcome codes (as lcp.contact.modes; -1: no closed-form case admissible)
OPEN, STICK, SLIDE_POS, SLIDE_NEG, SLIDE = 0, 1, 2, 3, 4


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


# ----------------------------------------------------------------- the disk law's twins
@njit(cache=True)
def disk_residual(pN, pT0, pT1, uN, uT0, uT1, mu, rhoN, rhoT):
    """Natural map of one disk contact: max(|min(p_N, rho_N u_N)|, |p_T - proj_D(p_T - rho_T u_T)|),
    D the disk of radius mu max(p_N, 0)."""
    s = mu * max(pN, 0.0)
    z0 = pT0 - rhoT * uT0
    z1 = pT1 - rhoT * uT1
    nz = math.hypot(z0, z1)
    if nz > s:
        f = s / nz
        z0 *= f
        z1 *= f
    return max(abs(min(pN, rhoN * uN)), math.hypot(pT0 - z0, pT1 - z1))


@njit(cache=True)
def _solve3(W, b0, b1, b2):
    """x with W x = b (3 x 3, Gaussian elimination with partial pivoting); ok False if singular.

    Scalars only (no heap allocation: this runs once per contact and sweep)."""
    a00, a01, a02 = W[0, 0], W[0, 1], W[0, 2]
    a10, a11, a12 = W[1, 0], W[1, 1], W[1, 2]
    a20, a21, a22 = W[2, 0], W[2, 1], W[2, 2]
    big = max(abs(a00), abs(a01), abs(a02), abs(a10), abs(a11), abs(a12), abs(a20), abs(a21), abs(a22))
    if big == 0.0:
        return 0.0, 0.0, 0.0, False
    small = 1e-14 * big
    # column 0: pivot row first
    if abs(a10) > abs(a00) and abs(a10) >= abs(a20):
        a00, a01, a02, b0, a10, a11, a12, b1 = a10, a11, a12, b1, a00, a01, a02, b0
    elif abs(a20) > abs(a00) and abs(a20) > abs(a10):
        a00, a01, a02, b0, a20, a21, a22, b2 = a20, a21, a22, b2, a00, a01, a02, b0
    if abs(a00) <= small:
        return 0.0, 0.0, 0.0, False
    f = a10 / a00
    a11 -= f * a01
    a12 -= f * a02
    b1 -= f * b0
    f = a20 / a00
    a21 -= f * a01
    a22 -= f * a02
    b2 -= f * b0
    # column 1
    if abs(a21) > abs(a11):
        a11, a12, b1, a21, a22, b2 = a21, a22, b2, a11, a12, b1
    if abs(a11) <= small:
        return 0.0, 0.0, 0.0, False
    f = a21 / a11
    a22 -= f * a12
    b2 -= f * b1
    if abs(a22) <= small:
        return 0.0, 0.0, 0.0, False
    x2 = b2 / a22
    x1 = (b1 - a12 * x2) / a11
    x0 = (b0 - a01 * x1 - a02 * x2) / a00
    return x0, x1, x2, True


#: the 3 x 3 solve of the local problem's stick case, for the compiled loops' branch refinement
solve3 = _solve3


@njit(cache=True)
def _par(c, s, v0x, v0y, V00, V01, V10, V11):
    """h = d x v and dh/dt for d = (c, s) = (cos t, sin t), v = v0 + V d."""
    vx = v0x + V00 * c + V01 * s
    vy = v0y + V10 * c + V11 * s
    h = c * vy - s * vx
    dh = -s * vy - c * vx + c * (-V10 * s + V11 * c) - s * (-V00 * s + V01 * c)
    return h, dh


@njit(cache=True)
def _polish(c, s, v0x, v0y, V00, V01, V10, V11):
    """Newton on h(t) = 0 from the unit vector (c, s), rotating it; steps limited to 0.5 (a
    double root converges linearly). A direction where h is exactly zero is returned unchanged;
    the iteration stops once a tiny step no longer shrinks (the rounding floor of h)."""
    nrm = math.hypot(c, s)
    c /= nrm
    s /= nrm
    prev = np.inf
    for _ in range(60):
        h, dh = _par(c, s, v0x, v0y, V00, V01, V10, V11)
        if h == 0.0 or dh == 0.0:
            break
        step = -h / dh
        if step > 0.5:
            step = 0.5
        elif step < -0.5:
            step = -0.5
        if abs(step) < 1e-12 and abs(step) >= prev:
            break  # no longer shrinking: h is at its rounding floor (further steps only dither)
        prev = abs(step)
        # rotate by atan(step) (= step + O(step^3): still Newton's quadratic convergence) with one
        # square root instead of a cosine and a sine
        w = 1.0 / math.sqrt(1.0 + step * step)
        c, s = (c - s * step) * w, (s + c * step) * w
        if abs(step) <= 1e-16:
            break
    return c, s


@njit(cache=True)
def _slide_at(c, s, W, qN, qT0, qT1, mu, rhoN, rhoT):
    """Impulse and local residual of the sliding candidate with direction d = (c, s) (residual inf
    when a(d) <= 0 or the tangential velocity points the wrong way)."""
    a = W[0, 0] - mu * (W[0, 1] * c + W[0, 2] * s)
    if not a > 0.0:
        return 0.0, 0.0, 0.0, np.inf
    pN = -qN / a
    pT0 = -mu * pN * c
    pT1 = -mu * pN * s
    uN = W[0, 0] * pN + W[0, 1] * pT0 + W[0, 2] * pT1 + qN
    uT0 = W[1, 0] * pN + W[1, 1] * pT0 + W[1, 2] * pT1 + qT0
    uT1 = W[2, 0] * pN + W[2, 1] * pT0 + W[2, 2] * pT1 + qT1
    if uT0 * c + uT1 * s < 0.0 and math.hypot(uT0, uT1) * rhoT > 1e-13 * pN:
        return 0.0, 0.0, 0.0, np.inf
    return pN, pT0, pT1, disk_residual(pN, pT0, pT1, uN, uT0, uT1, mu, rhoN, rhoT)


@njit(cache=True)
def local_disk3(W, qN, qT0, qT1, mu, g0, g1):
    """Exact solution of one disk contact u = W r + q (W 3 x 3, order N, T0, T1).

    (g0, g1) is a guess of the sliding direction d (e.g. the last tangential impulse negated;
    (0, 0) for none). Returns (pN, pT0, pT1, mode, residual): mode 0 open, 1 stick, 4 slide,
    -1 when no case is admissible (a Painleve-type block: NaN impulses). ``residual`` is the local
    natural map of the returned impulse.
    """
    WNN = W[0, 0]
    if not WNN > 0.0:
        return np.nan, np.nan, np.nan, -1, np.inf
    wT = max(W[1, 1], W[2, 2])
    rhoN = 1.0 / WNN
    rhoT = 1.0 / wT if wT > 0.0 else 1.0
    scale = max(abs(qN) * rhoN, math.hypot(qT0, qT1) * rhoT, 1e-300)
    tol = 1e-13 * scale
    if qN * rhoN >= -tol:
        return 0.0, 0.0, 0.0, OPEN, 0.0
    if mu == 0.0:
        # no friction: the normal impulse alone; the contact slides unless u_T vanishes
        pN = -qN * rhoN
        uT0 = W[1, 0] * pN + qT0
        uT1 = W[2, 0] * pN + qT1
        md = STICK if math.hypot(uT0, uT1) * rhoT <= tol else SLIDE
        return pN, 0.0, 0.0, md, abs(W[0, 0] * pN + qN) * rhoN
    x0, x1, x2, ok = _solve3(W, -qN, -qT0, -qT1)
    if ok and x0 >= -tol and math.hypot(x1, x2) <= mu * x0 + tol:
        return x0, x1, x2, STICK, 0.0
    # sliding: a(t) u_T = v0 + V d
    v0x = -qN * W[1, 0] + WNN * qT0
    v0y = -qN * W[2, 0] + WNN * qT1
    V00 = mu * (qN * W[1, 1] - qT0 * W[0, 1])
    V01 = mu * (qN * W[1, 2] - qT0 * W[0, 2])
    V10 = mu * (qN * W[2, 1] - qT1 * W[0, 1])
    V11 = mu * (qN * W[2, 2] - qT1 * W[0, 2])
    accept = 1e-12 * scale
    if ok and math.hypot(x1, x2) > 0.0:
        c0, s0 = -x1, -x2
    elif g0 != 0.0 or g1 != 0.0:
        c0, s0 = g0, g1
    elif v0x != 0.0 or v0y != 0.0:
        c0, s0 = v0x, v0y
    else:
        c0, s0 = 1.0, 0.0
    c, s = _polish(c0, s0, v0x, v0y, V00, V01, V10, V11)
    pN, pT0, pT1, res = _slide_at(c, s, W, qN, qT0, qT1, mu, rhoN, rhoT)
    if res <= accept:
        return pN, pT0, pT1, SLIDE, res
    # every root of h: z^2 h(t) with z = exp(i t) is a quartic in z
    a0 = 0.5 * (V10 - V01)
    a1 = v0y
    b1 = -v0x
    a2 = 0.5 * (V10 + V01)
    b2 = 0.5 * (V11 - V00)
    coef = np.empty(5, dtype=np.complex128)  # highest degree first
    coef[0] = 0.5 * complex(a2, -b2)
    coef[1] = 0.5 * complex(a1, -b1)
    coef[2] = complex(a0, 0.0)
    coef[3] = 0.5 * complex(a1, b1)
    coef[4] = 0.5 * complex(a2, b2)
    cmax = 0.0
    for i in range(5):
        cmax = max(cmax, abs(coef[i]))
    best = (np.nan, np.nan, np.nan, np.inf)
    if cmax > 0.0:
        lo = 0
        while lo < 4 and abs(coef[lo]) <= 1e-15 * cmax:
            lo += 1
        hi = 4
        while hi > lo and abs(coef[hi]) <= 1e-15 * cmax:
            hi -= 1  # a zero constant term is a root z = 0, off the unit circle
        deg = hi - lo
        if deg >= 1:
            C = np.zeros((deg, deg), dtype=np.complex128)
            for j in range(deg):
                C[0, j] = -coef[lo + 1 + j] / coef[lo]
            for i in range(1, deg):
                C[i, i - 1] = 1.0
            roots = np.linalg.eigvals(C)
            for i in range(deg):
                z = roots[i]
                if not (abs(z) > 0.0 and np.isfinite(z.real) and np.isfinite(z.imag)):
                    continue
                c, s = _polish(z.real, z.imag, v0x, v0y, V00, V01, V10, V11)
                cand = _slide_at(c, s, W, qN, qT0, qT1, mu, rhoN, rhoT)
                if cand[3] < best[3]:
                    best = cand
    if best[3] <= accept:
        return best[0], best[1], best[2], SLIDE, best[3]
    # no admissible sliding direction: maybe a stick at the cone's edge missed by the tolerance
    if ok and x0 >= -tol:
        sN = max(x0, 0.0)
        uN = W[0, 0] * x0 + W[0, 1] * x1 + W[0, 2] * x2 + qN
        uT0 = W[1, 0] * x0 + W[1, 1] * x1 + W[1, 2] * x2 + qT0
        uT1 = W[2, 0] * x0 + W[2, 1] * x1 + W[2, 2] * x2 + qT1
        r = disk_residual(sN, x1, x2, uN, uT0, uT1, mu, rhoN, rhoT)
        if r <= accept:
            return x0, x1, x2, STICK, r
    return np.nan, np.nan, np.nan, -1, np.inf
