"""The operators of independent bodies, compiled: S H', W = H S H' and S x for a block-diagonal S.

For bodies coupled by nothing but their contacts, the iteration matrix's inverse S is block diagonal
(:mod:`lcp.numerics.block_diagonal`), and the step's constant operators are two sparse products. SciPy
computes them well, but a fresh system of a few hundred contacts then pays more for SciPy's
constructors and checks (a dozen matrices, tens of microseconds each) than for the arithmetic. With
numba the products run here on the compressed arrays in one call, and the SciPy matrices are built
only if Python code asks for them (:class:`lcp.timestepping.assembly.StepAssembly`).

The sums are SciPy's, term for term and in the same order (Gustavson's row-by-row product, each
entry accumulated over the inner index in increasing order, exact zeros not stored), so the
operators are the same to the last bit whichever way they are built; the tests compare them.
"""
from __future__ import annotations

import numpy as np

from lcp.numerics.jit import njit

__all__ = ["block_products", "csr_matvec"]


@njit(cache=True)
def _transpose(n_rows, n_cols, ptr, idx, val):
    """The compressed arrays of the transpose (CSR <-> CSC): indices sorted within each row of the
    result when the input's are visited in increasing row order (a counting sort, stable)."""
    count = np.zeros(n_cols + 1, dtype=np.int64)
    for a in range(ptr[n_rows]):
        count[idx[a] + 1] += 1
    for c in range(n_cols):
        count[c + 1] += count[c]
    out_ptr = count.copy()
    out_idx = np.empty(ptr[n_rows], dtype=np.int64)
    out_val = np.empty(ptr[n_rows])
    fill = count[:n_cols].copy()
    for r in range(n_rows):
        for a in range(ptr[r], ptr[r + 1]):
            c = idx[a]
            out_idx[fill[c]] = r
            out_val[fill[c]] = val[a]
            fill[c] += 1
    return out_ptr, out_idx, out_val


@njit(cache=True)
def _product(n_rows, n_cols, Ap, Ai, Ax, Bp, Bi, Bx):
    """C = A B in CSR (A, B in CSR), as SciPy's csr_matmat: row by row, each entry summed over the
    inner index in A's stored order, exact zeros dropped; indices sorted within rows."""
    nnz = 0
    mark = np.full(n_cols, -1, dtype=np.int64)
    for r in range(n_rows):  # the pattern's size (an upper bound on the stored entries)
        for a in range(Ap[r], Ap[r + 1]):
            k = Ai[a]
            for b in range(Bp[k], Bp[k + 1]):
                c = Bi[b]
                if mark[c] != r:
                    mark[c] = r
                    nnz += 1
    Cp = np.zeros(n_rows + 1, dtype=np.int64)
    Ci = np.empty(nnz, dtype=np.int64)
    Cx = np.empty(nnz)
    acc = np.zeros(n_cols)
    mark[:] = -1
    cols = np.empty(n_cols, dtype=np.int64)
    at = 0
    for r in range(n_rows):
        found = 0
        for a in range(Ap[r], Ap[r + 1]):
            k = Ai[a]
            v = Ax[a]
            for b in range(Bp[k], Bp[k + 1]):
                c = Bi[b]
                if mark[c] != r:
                    mark[c] = r
                    acc[c] = v * Bx[b]  # SciPy: sums[c] += v * x from zero; 0 + y == y
                    cols[found] = c
                    found += 1
                else:
                    acc[c] += v * Bx[b]
        # insertion sort of the row's columns (rows hold a few entries)
        for s in range(1, found):
            c = cols[s]
            t = s - 1
            while t >= 0 and cols[t] > c:
                cols[t + 1] = cols[t]
                t -= 1
            cols[t + 1] = c
        for s in range(found):
            c = cols[s]
            if acc[c] != 0.0:
                Ci[at] = c
                Cx[at] = acc[c]
                at += 1
        Cp[r + 1] = at
    return Cp, Ci[:at].copy(), Cx[:at].copy()


@njit(cache=True)
def block_products(n, n_rows, Sp, Si, Sx, Hcp, Hri, Hx):
    """(H, S H' and W = H S H' in CSR; S H' in CSC) from S (n x n, CSR) and the contact Jacobian H
    (n_rows x n, CSC: CasADi's compressed column storage). Exact zeros of H are dropped first,
    as the SciPy route does (``eliminate_zeros``)."""
    keep = 0
    Kp = np.zeros(n + 1, dtype=np.int64)
    Ki = np.empty(Hcp[n], dtype=np.int64)
    Kx = np.empty(Hcp[n])
    for c in range(n):
        for a in range(Hcp[c], Hcp[c + 1]):
            if Hx[a] != 0.0:
                Ki[keep] = Hri[a]
                Kx[keep] = Hx[a]
                keep += 1
        Kp[c + 1] = keep
    Ki, Kx = Ki[:keep], Kx[:keep]
    # H' in CSR is H in CSC: S H' = S (H's columns as rows)
    Tp, Ti, Tx = _product(n, n_rows, Sp, Si, Sx, Kp, Ki, Kx)
    Hp, Hi, Hv = _transpose(n, n_rows, Kp, Ki, Kx)  # H in CSR
    Wp, Wi, Wx = _product(n_rows, n_rows, Hp, Hi, Hv, Tp, Ti, Tx)
    Cp, Ci, Cx = _transpose(n, n_rows, Tp, Ti, Tx)  # S H' in CSC
    return (Hp, Hi, Hv), (Tp, Ti, Tx), (Wp, Wi, Wx), (Cp, Ci, Cx)


@njit(cache=True)
def csr_matvec(p, i, x, v):
    """A v for A in CSR, summed as SciPy's csr_matvec (in stored order, from zero)."""
    out = np.empty(p.size - 1)
    for r in range(p.size - 1):
        s = 0.0
        for a in range(p[r], p[r + 1]):
            s += x[a] * v[i[a]]
        out[r] = s
    return out
