"""Output of closed-form phases: compiled with numba when installed, the same operations in NumPy otherwise.

A sweep of single-contact scenes spends more time writing 1000 output rows of quadratic pieces with
NumPy's small-array operations than computing the pieces themselves. :func:`piece_output` writes
them in one compiled call, straight into the result's layout: per output time t in piece k, the
values c0 + c1 dt + c2 (dt/2) dt with dt = t - t0_k, in exactly the floating-point operations of
:func:`piece_output_numpy` (no fused multiply-add: numba does not contract without ``fastmath``),
so that the two give the same bits.

The pieces come as two arrays: ``P`` (k, 5), rows (t0, t1, N, f, mode) (the start and end of the
piece, its constant contact forces and its mode), and ``C`` (3, k, 2n + 2), the coefficients c0,
c1, c2 of (q, v, cumulative normal and tangential impulses).
"""
from __future__ import annotations

import numpy as np

from lcp.numerics.jit import HAVE_NUMBA, njit

__all__ = ["HAVE_NUMBA", "piece_output", "piece_output_numpy", "warm"]


def _bounds(t_out, P):
    """Rows [lo_k, hi_k) of the output times in piece k; the last piece keeps its end time."""
    k = P.shape[0]
    lo = np.searchsorted(t_out, P[:, 0])
    hi = np.searchsorted(t_out, P[:, 1])
    if hi[k - 1] < t_out.size and t_out[hi[k - 1]] == P[k - 1, 1]:
        hi[k - 1] += 1
    return lo, hi


def piece_output_numpy(t_out, P, C, n):
    """(q, v, p_N, p_T, force_N, force_T, modes) at the output times, by NumPy row operations.

    ``q``, ``v``: (N, n); ``p_N``, ``p_T``: (N - 1, 1) impulses over each output interval;
    ``force_N``, ``force_T``: (N, 1); ``modes``: (N, 1) int8 (the caller drops the last row).
    """
    N_out = t_out.size
    lo, hi = _bounds(t_out, P)
    Y = np.empty((2 * n + 2, N_out))
    FN = np.empty((N_out, 1))
    FT = np.empty((N_out, 1))
    MD = np.empty((N_out, 1), dtype=np.int8)
    for k in range(P.shape[0]):
        a, b = int(lo[k]), int(hi[k])
        if b <= a:
            continue
        dt = t_out[a:b] - P[k, 0]
        h = 0.5 * dt
        h *= dt
        Y[:, a:b] = (C[0, k][:, None] + C[1, k][:, None] * dt) + C[2, k][:, None] * h
        FN[a:b], FT[a:b], MD[a:b] = P[k, 2], P[k, 3], int(P[k, 4])
    PC = Y[2 * n:]
    dP = (PC[:, 1:] - PC[:, :-1]).T
    return (np.ascontiguousarray(Y[:n].T), np.ascontiguousarray(Y[n:2 * n].T), dP[:, :1].copy(),
            dP[:, 1:].copy(), FN, FT, MD)


@njit(cache=True)
def _piece_output_compiled(t_out, P, C, n):
    N_out = t_out.size
    k_all = P.shape[0]
    lo = np.searchsorted(t_out, P[:, 0])
    hi = np.searchsorted(t_out, P[:, 1])
    if hi[k_all - 1] < N_out and t_out[hi[k_all - 1]] == P[k_all - 1, 1]:
        hi[k_all - 1] += 1
    Q = np.empty((N_out, n))
    V = np.empty((N_out, n))
    PC = np.empty((N_out, 2))
    FN = np.empty((N_out, 1))
    FT = np.empty((N_out, 1))
    MD = np.empty((N_out, 1), dtype=np.int8)
    for k in range(k_all):
        t0, fN, fT, md = P[k, 0], P[k, 2], P[k, 3], np.int8(P[k, 4])
        for j in range(lo[k], hi[k]):
            dt = t_out[j] - t0
            h = 0.5 * dt
            h = h * dt
            for r in range(n):
                Q[j, r] = (C[0, k, r] + C[1, k, r] * dt) + C[2, k, r] * h
                V[j, r] = (C[0, k, n + r] + C[1, k, n + r] * dt) + C[2, k, n + r] * h
            for r in range(2):
                PC[j, r] = (C[0, k, 2 * n + r] + C[1, k, 2 * n + r] * dt) + C[2, k, 2 * n + r] * h
            FN[j, 0] = fN
            FT[j, 0] = fT
            MD[j, 0] = md
    dPN = np.empty((N_out - 1, 1))
    dPT = np.empty((N_out - 1, 1))
    for j in range(N_out - 1):
        dPN[j, 0] = PC[j + 1, 0] - PC[j, 0]
        dPT[j, 0] = PC[j + 1, 1] - PC[j, 1]
    return Q, V, dPN, dPT, FN, FT, MD


def piece_output(t_out, P, C, n):
    """:func:`piece_output_numpy`'s output, compiled when numba is installed (the same bits)."""
    if HAVE_NUMBA:
        return _piece_output_compiled(t_out, P, C, n)
    return piece_output_numpy(t_out, P, C, n)


def warm() -> None:
    """Compile (or load from numba's cache) once, on a tiny input."""
    if HAVE_NUMBA:
        _piece_output_compiled(np.array([0.0, 1.0]), np.array([[0.0, 1.0, 0.0, 0.0, 0.0]]), np.zeros((3, 1, 4)), 1)
