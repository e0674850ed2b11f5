"""numba kernels of Newton-Euler kinematics for the compiled general loop: NumPy's operations of
:func:`lcp.model.kinematics.advance_positions` and of the activation's sizes, repeated exactly.

Holds :func:`advance` (the position update of a step: the compensated sum of h T w, the exponential
map of each unit quaternion, the normalisation; T w and the quaternions' blocks B come from the
compiled increment of :func:`lcp.timestepping.codegen.kinematics_library`), :func:`exp_block`,
:func:`kinematic_sizes` (the activation's np.abs(H_N).sum(axis=1) * max|q|), :func:`pairwise_sum`
(NumPy's pairwise summation, which that sum uses) and :func:`amax_abs`. The products are those NumPy
computes (BLAS's gemm, gemv and dot, which numba calls too), so the compiled loop reproduces the
Python loop's bits. Imports NumPy and numba (:mod:`lcp.numerics.jit`) only; never the loops or
anything above :mod:`lcp.timestepping`.
"""
from __future__ import annotations

import math

import numpy as np

from lcp.numerics.jit import njit

__all__ = ["advance", "amax_abs", "exp_block", "kinematic_sizes", "pairwise_block", "pairwise_sum"]

_EPS = 2.220446049250313e-16


@njit(cache=True)
def pairwise_block(a, lo, n):
    """NumPy's pairwise sum of a[lo:lo + n] for n <= 128: in order below 8 terms, else eight
    accumulators, from the identity 0."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[lo + i]
        return res
    acc = np.empty(8)
    for j in range(8):
        acc[j] = a[lo + j]
    i = 8
    while i < n - (n % 8):
        for j in range(8):
            acc[j] += a[lo + i + j]
        i += 8
    res = ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@njit(cache=True)
def pairwise_sum(a, lo, n):
    """NumPy's pairwise sum of a[lo:lo + n] (its reductions along a contiguous axis): blocks of at
    most 128 (:func:`pairwise_block`), halves (a multiple of 8 first) above. The halving runs on
    an explicit stack: numba's cache does not survive a recursive function."""
    if n <= 128:
        return pairwise_block(a, lo, n)
    slo = np.empty(64, dtype=np.int64)
    sn = np.empty(64, dtype=np.int64)
    state = np.zeros(64, dtype=np.int64)
    left = np.empty(64)
    top = 0
    slo[0] = lo
    sn[0] = n
    ret = 0.0
    while top >= 0:
        L = slo[top]
        N = sn[top]
        if N <= 128:
            ret = pairwise_block(a, L, N)
            top -= 1
            continue
        n2 = N // 2
        n2 -= n2 % 8
        if state[top] == 0:
            state[top] = 1
            top += 1
            slo[top], sn[top], state[top] = L, n2, 0
        elif state[top] == 1:
            left[top] = ret
            state[top] = 2
            top += 1
            slo[top], sn[top], state[top] = L + n2, N - n2, 0
        else:
            ret = left[top] + ret
            top -= 1
    return ret


@njit(cache=True)
def amax_abs(x):
    """np.max(np.abs(x)) (NaN where any entry is NaN)."""
    out = -np.inf
    for a in range(x.size):
        y = abs(x[a])
        if y != y:
            return np.nan
        out = max(out, y)
    return out


@njit(cache=True)
def kinematic_sizes(o_H, r, n, m, q, out):
    """The activation's rounding sizes with Newton-Euler kinematics (n_q != n_v):
    np.abs(H[:m]).sum(axis=1) * max|q|, NumPy's pairwise sums (Activation.__call__)."""
    qmax = amax_abs(q)
    row = np.empty(n)
    for j in range(m):
        for c in range(n):
            row[c] = abs(o_H[j + c * r])
        out[j] = pairwise_sum(row, 0, n) * qmax


@njit(cache=True)
def exp_block(B, p, h, out):
    """lcp.model.kinematics._exp_block: expm(h B) p into ``out`` for a skew B with B^2 = -beta^2 I
    (NumPy's products: BLAS's gemm and gemv, as numba calls them); False where B is not such."""
    scale = amax_abs(B.ravel())
    if scale == 0.0:
        for a in range(4):
            out[a] = p[a]
        return True
    B2 = np.dot(B, B)
    tr = 0.0
    for a in range(4):
        tr += B2[a, a]
    beta2 = -tr / 4.0
    tol = 64 * _EPS * scale
    skew = np.empty(16)
    sq = np.empty(16)
    for a in range(4):
        for c in range(4):
            skew[4 * a + c] = B[a, c] + B[c, a]
            sq[4 * a + c] = B2[a, c] + (beta2 if a == c else 0.0)
    if amax_abs(skew) > tol or amax_abs(sq) > tol * scale:
        return False
    beta = math.sqrt(max(beta2, 0.0))
    x = h * beta
    s = h * (math.sin(x) / x if x > 1e-8 else 1.0 - x * x / 6.0)
    Bp = np.dot(B, p)
    c = math.cos(x)
    for a in range(4):
        out[a] = c * p[a] + s * Bp[a]
    return True


@njit(cache=True)
def advance(kfunc, kargp, kresp, kiw, kw, k_t, k_q, k_w, k_rate, k_B, quats, tk, q, wv, h, cq, qn, cqn):
    """lcp.model.kinematics.advance_positions with a compensation: q + h T(t, q) w by the Kahan sum
    (T w and the blocks B from the compiled increment), each unit quaternion by the exponential map
    where its rows are B p (else the sum), normalised, its compensation reset. False where the C
    function fails."""
    nq = q.size
    k_t[0] = tk
    for a in range(nq):
        k_q[a] = q[a]
    for a in range(wv.size):
        k_w[a] = wv[a]
    if kfunc(kargp.ctypes.data, kresp.ctypes.data, kiw.ctypes.data, kw.ctypes.data, 0) != 0:
        return False
    for a in range(nq):
        x = h * k_rate[a]
        y = x - cq[a]
        s = q[a] + y
        cqn[a] = (s - q[a]) - y
        qn[a] = s
    B = np.empty((4, 4))
    p = np.empty(4)
    rate = np.empty(4)
    pn = np.empty(4)
    for jq in range(quats.size):
        i = quats[jq]
        for a in range(4):
            for c in range(4):
                B[a, c] = k_B[a + 4 * (4 * jq + c)]
            p[a] = q[i + a]
            x = h * k_rate[i + a]
            rate[a] = x / h if h else x
        Bp = np.dot(B, p)
        for a in range(4):
            Bp[a] = Bp[a] - rate[a]
        linear = amax_abs(Bp) <= 64 * _EPS * (amax_abs(B.ravel()) * 2 + amax_abs(rate))
        if not (linear and exp_block(B, p, h, pn)):
            for a in range(4):
                pn[a] = qn[i + a]
        nrm = math.sqrt(np.dot(pn, pn))
        for a in range(4):
            qn[i + a] = pn[a] / nrm
            cqn[i + a] = 0.0
    return True
