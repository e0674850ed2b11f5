"""The products of the compiled general loop, rounded as the Python loop's NumPy products round.

Holds :func:`matvec` (A @ x of a C-ordered A: BLAS's dot or gemv, as NumPy calls them),
:func:`seqmv` (A @ x of the F-ordered column slices X[:, idx] of up to three columns: each row
summed in order), :func:`rows` and :func:`cols` (the C-ordered rows X[idx] and columns X[:, idx]
of a column-major buffer of CasADi's C function), :func:`cols_f` (the columns as NumPy lays
X[:, idx] out: F-ordered, for ``np.dot``, which then calls BLAS's gemv as NumPy does). Shared by
the kernels of :mod:`lcp.timestepping.general_kernels` and
:mod:`lcp.timestepping.planar_multi_kernels`, so that their sums are the Python loop's sums.
Imports NumPy and numba (:mod:`lcp.numerics.jit`) only; never anything else of :mod:`lcp`.
"""
from __future__ import annotations

import numpy as np

from lcp.numerics.jit import njit

__all__ = ["cols", "cols_f", "matvec", "rows", "seqmv"]


@njit(cache=True)
def matvec(A, x):
    """A @ x as NumPy computes it for a C-ordered A: BLAS's dot of the row for one row, BLAS's
    gemv otherwise (numba calls the same BLAS kernels, so the sums round the same way and the
    compiled loop reproduces the Python loop's bits)."""
    if A.shape[0] == 1:
        out = np.empty(1)
        if A.shape[1] <= 16:  # BLAS's dot of a short row sums in order (measured): no call
            s = 0.0
            for c in range(A.shape[1]):
                s += A[0, c] * x[c]
            out[0] = s
        else:
            out[0] = np.dot(A[0], x)
        return out
    return np.dot(A, x)


@njit(cache=True)
def rows(o_X, n_rows, n_cols, idx):
    """The rows ``idx`` of the (n_rows x n_cols) column-major buffer o_X, C-ordered (X[idx] in NumPy)."""
    out = np.empty((idx.size, n_cols))
    for a in range(idx.size):
        for c in range(n_cols):
            out[a, c] = o_X[idx[a] + c * n_rows]
    return out


@njit(cache=True)
def seqmv(A, x):
    """A @ x for the F-ordered column slices X[:, idx] of the Python loop (S H' of the active set):
    NumPy's product of such an array sums each row in order, as this loop does."""
    out = np.zeros(A.shape[0])
    for a in range(A.shape[0]):
        s = 0.0
        for c in range(A.shape[1]):
            s += A[a, c] * x[c]
        out[a] = s
    return out


@njit(cache=True)
def cols(o_X, n_rows, idx):
    """The columns ``idx`` of the (n_rows x any) column-major buffer o_X, C-ordered (X[:, idx])."""
    out = np.empty((n_rows, idx.size))
    for b in range(idx.size):
        for a in range(n_rows):
            out[a, b] = o_X[a + idx[b] * n_rows]
    return out


@njit(cache=True)
def cols_f(o_X, n_rows, idx):
    """The columns ``idx`` of the (n_rows x any) column-major buffer o_X as an F-ordered array,
    the layout of NumPy's X[:, idx] of a C-ordered X: ``np.dot`` of it with a vector calls BLAS's
    gemv as NumPy does (for four columns and more its sums are not in order, so :func:`seqmv`
    would differ in the last bit)."""
    out = np.empty((idx.size, n_rows)).T
    for b in range(idx.size):
        for a in range(n_rows):
            out[a, b] = o_X[a + idx[b] * n_rows]
    return out
