"""The action ``exp(t A) B`` of a sparse matrix exponential, lean enough for many small systems.

The LEM engine propagates thousands of small moment systems (dimension ~ 10**2, a few columns)
per solve. :func:`scipy.sparse.linalg.expm_multiply` spends most of its time there estimating
norms of powers of ``A`` to choose its Taylor degree; its arithmetic is a truncated Taylor series
with scaling (Al-Mohy and Higham, SIAM J. Sci. Comput. 33, 2011). :func:`expmv` runs the same
algorithm with the exact 1-norm of ``A`` (cheap for a CSR matrix) and, compiled, cheap upper
bounds of the norms of its powers (products of a row vector with ``|A|``) in place of the
estimates, and the Taylor loop compiled with numba (a dependency; the NumPy loop stays as the reference),
in NumPy otherwise. There is no shift by trace(A)/n: for moment matrices (diagonal ~ degree x growth rate)
the shift costs digits.

Examples
--------
>>> import numpy as np, scipy.sparse as sp
>>> A = sp.csr_matrix(np.array([[0.0, 1.0], [-1.0, 0.0]]))
>>> V = expmv(A, np.array([[1.0], [0.0]]), np.pi / 2, onenorm(A))
>>> np.allclose(V[:, 0], [0.0, -1.0], atol=1e-15)
True
"""
from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp

# Through lcp's jit module, so that numba's cache folder is set (LCP_CACHE_DIR) before numba is
# first imported: importing numba here directly cached lem's kernels beside the sources.
from lcp.numerics.jit import HAVE_NUMBA, njit

__all__ = ["HAVE_NUMBA", "THETA", "expmv", "nonnegative_expm", "onenorm", "taylor_parameters"]

#: theta_m of Al-Mohy and Higham (2011), Table 3.1, for a backward error of 2**-53: a Taylor
#: polynomial of degree m approximates exp(X) to that accuracy when ||X||_1 <= theta_m.
THETA = {5: 2.4e-3, 10: 1.44e-1, 15: 6.41e-1, 20: 1.44, 25: 2.43, 30: 3.54, 35: 4.7, 40: 6.0,
         45: 7.2, 50: 8.5, 55: 9.9}
_TOL = 2.0 ** -53


def onenorm(A: sp.csr_matrix) -> float:
    """||A||_1 (largest absolute column sum), exactly."""
    if A.nnz == 0:
        return 0.0
    return float(np.bincount(A.indices, weights=np.abs(A.data), minlength=A.shape[1]).max())


def taylor_parameters(norm_tA: float, power_norms=None) -> tuple:
    """(m, s): Taylor degree and number of sub-steps minimizing m*s with alpha / s <= theta_m.

    alpha is ||tA||_1, or, given upper bounds ``power_norms[p - 1] >= ||(tA)**p||_1**(1/p)``
    (p = 1, 2, ...), the smaller alpha_p = max(d_p, d_(p+1)) of Al-Mohy and Higham (2011),
    admissible for m >= p (p - 1) - 1: for non-normal matrices such as moment matrices
    ||A**p||**(1/p) falls below ||A||. Upper bounds keep the error guarantee.
    """
    if norm_tA == 0.0:
        return 0, 1
    candidates = [(1, norm_tA)]
    if power_norms is not None:
        d = list(power_norms)
        candidates += [(p, max(d[p - 1], d[p])) for p in range(2, len(d))]
    best = None
    for p, alpha in candidates:
        for m, theta in THETA.items():
            if m < p * (p - 1) - 1:
                continue
            s = max(1, math.ceil(alpha / theta))
            if best is None or m * s < best[0] * best[1]:
                best = (m, s)
    return best


def _taylor_numpy(A, B, t, m, s):
    F = B.copy()
    for _ in range(s):
        c1 = np.abs(B).max(initial=0.0)
        for j in range(1, m + 1):
            B = (A @ B) * (t / (s * j))
            c2 = np.abs(B).max(initial=0.0)
            F = F + B
            if c1 + c2 <= _TOL * np.abs(F).max(initial=0.0):
                break
            c1 = c2
        B = F
    return F


if HAVE_NUMBA:
    @njit(cache=True)
    def _power_norm_bounds(indptr, indices, data, pmax):  # pragma: no cover - compiled
        # ||A**p||_1 <= max_j (1^T |A|**p)_j: one product of a row vector with |A| per power
        d = indptr.size - 1
        r = np.ones(d)
        out = np.empty(pmax)
        for p in range(pmax):
            nxt = np.zeros(d)
            for k in range(d):
                for q in range(indptr[k], indptr[k + 1]):
                    nxt[indices[q]] += r[k] * abs(data[q])
            r = nxt
            out[p] = r.max() ** (1.0 / (p + 1)) if d else 0.0
        return out

    @njit(cache=True)
    def _taylor_compiled(indptr, indices, data, B, t, m, s, tol):  # pragma: no cover - compiled
        d, k = B.shape
        F = B.copy()
        X = B.copy()
        Y = np.empty_like(B)
        for _ in range(s):
            c1 = np.abs(X).max() if X.size else 0.0
            for j in range(1, m + 1):
                coef = t / (s * j)
                for r in range(d):
                    for c in range(k):
                        Y[r, c] = 0.0
                    for p in range(indptr[r], indptr[r + 1]):
                        a = data[p] * coef
                        col = indices[p]
                        for c in range(k):
                            Y[r, c] += a * X[col, c]
                c2 = 0.0
                fmax = 0.0
                for r in range(d):
                    for c in range(k):
                        X[r, c] = Y[r, c]
                        v = abs(Y[r, c])
                        c2 = max(c2, v)
                        F[r, c] += Y[r, c]
                        w = abs(F[r, c])
                        fmax = max(fmax, w)
                if c1 + c2 <= tol * fmax:
                    break
                c1 = c2
            for r in range(d):
                for c in range(k):
                    X[r, c] = F[r, c]
        return F


def expmv(A: sp.csr_matrix, B: np.ndarray, t: float, norm: float | None = None,
          compiled: bool = True) -> np.ndarray:
    """exp(t A) B for a CSR matrix A and a dense block B (d, k), by scaled Taylor series.

    Parameters
    ----------
    A : scipy.sparse.csr_matrix, shape (d, d)
    B : ndarray, shape (d, k)
    t : float
    norm : float, optional
        ||A||_1 if known (see :func:`onenorm`).
    compiled : bool
        Use the numba loop when installed (False: the NumPy loop, for tests).

    Returns
    -------
    ndarray, shape (d, k)
        Non-finite where the series overflows (the caller reports the blow-up).
    """
    B = np.ascontiguousarray(B, dtype=float)
    norm = onenorm(A) if norm is None else norm
    if compiled and HAVE_NUMBA and norm * abs(t) > THETA[55]:
        # more than one sub-step: bounds of the norms of powers may save some
        A = A.tocsr()
        bounds = _power_norm_bounds(A.indptr, A.indices, A.data, 8) * abs(t)
        m, s = taylor_parameters(norm * abs(t), bounds)
    else:
        m, s = taylor_parameters(norm * abs(t))
    if m == 0:
        return B.copy()
    if compiled and HAVE_NUMBA:
        A = A.tocsr()
        return _taylor_compiled(A.indptr, A.indices, A.data, B, float(t), m, s, _TOL)
    return _taylor_numpy(A, B, float(t), m, s)


def nonnegative_expm(M: np.ndarray) -> np.ndarray:
    """exp(M) of a small dense matrix with non-negative entries, by scaling and squaring.

    With M >= 0 every Taylor term is non-negative, so the series has no cancellation; the result
    matches :func:`scipy.linalg.expm` to ~1e-12 relative at ||M|| ~ 1e3 (the squarings) without
    its fixed overhead. It is called once per LEM segment, on the n x n Jacobian bound from which
    the moments' power-of-two scales are chosen.

    >>> import numpy as np
    >>> bool(np.allclose(nonnegative_expm(np.array([[0.0, 1.0], [1.0, 0.0]])),
    ...                  [[np.cosh(1), np.sinh(1)], [np.sinh(1), np.cosh(1)]], rtol=1e-15))
    True
    """
    M = np.asarray(M, dtype=float)
    if np.any(M < 0):
        raise ValueError("M must have non-negative entries")
    norm = float(M.sum(axis=1).max(initial=0.0))
    s = max(0, math.ceil(math.log2(norm)) + 1) if norm > 0 else 0
    X = M / 2.0**s
    term = np.eye(M.shape[0])
    E = term.copy()
    for k in range(1, 30):
        term = term @ X / k
        E = E + term
        if term.max(initial=0.0) <= 2.0**-54 * E.max(initial=0.0):
            break
    for _ in range(s):
        E = E @ E
    return E
