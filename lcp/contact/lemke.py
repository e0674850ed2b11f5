"""Lemke's complementary pivoting algorithm for the linear complementarity problem.

No well-kept Python library offers a small, dependency-free Lemke solver with lexicographic
anti-cycling, so it lives here, kept short and tested hard (tests/test_lemke.py).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["LemkeResult", "lemke"]

STATUS = {
    0: "solution found",
    1: "ray termination: Lemke's method cannot process this LCP (no solution found)",
    2: "iteration limit reached (possible cycling)",
}


@dataclass
class LemkeResult:
    """Result of :func:`lemke`.

    Attributes
    ----------
    z : ndarray, shape (n,)
        The solution (valid only when ``status == 0``).
    w : ndarray, shape (n,)
        M z + q.
    status : int
        0 solution found, 1 ray termination, 2 iteration limit.
    message : str
    pivots : int
        Number of complementary pivots.
    residual : float
        max(|min(z, w)|) recomputed from M and q, not from the tableau.
    """

    z: np.ndarray
    w: np.ndarray
    status: int
    message: str
    pivots: int
    residual: float

    @property
    def success(self) -> bool:
        return self.status == 0


def lemke(M, q, max_pivots: int | None = None, tol: float = 1e-12) -> LemkeResult:
    """Solve LCP(M, q): find z >= 0 with w = M z + q >= 0 and z'w = 0.

    Lemke's method with covering vector d = 1 and a lexicographic ratio test (which excludes
    cycling on degenerate problems). The final basis is re-solved directly, so the answer carries
    the accuracy of one linear solve rather than the rounding accumulated over the pivots.

    Parameters
    ----------
    M : array_like, shape (n, n)
    q : array_like, shape (n,)
    max_pivots : int, optional
        Default 50 (n + 1).
    tol : float
        Pivot tolerance, relative to the column's largest entry.

    Returns
    -------
    LemkeResult

    References
    ----------
    C. E. Lemke, "Bimatrix equilibrium points and mathematical programming", Management Science 11
    (1965); K. G. Murty, "Linear Complementarity, Linear and Nonlinear Programming" (1988), ch. 2.

    Examples
    --------
    >>> import numpy as np
    >>> from lcp.contact.lemke import lemke
    >>> r = lemke(np.array([[2.0, 1.0], [1.0, 2.0]]), np.array([-5.0, -6.0]))
    >>> r.z, r.status
    (array([1.33333333, 2.33333333]), 0)
    """
    M = np.asarray(M, dtype=float)
    q = np.asarray(q, dtype=float)
    n = q.size
    if M.shape != (n, n):
        raise ValueError(f"M must have shape ({n}, {n}), got {M.shape}")
    if not (np.all(np.isfinite(M)) and np.all(np.isfinite(q))):
        raise ValueError("M and q must be finite")
    if max_pivots is None:
        max_pivots = 50 * (n + 1)
    if n == 0 or np.all(q >= 0):
        z = np.zeros(n)
        return LemkeResult(z, q.copy(), 0, STATUS[0], 0, _residual(M, q, z))

    # Tableau for  w - M z - d z0 = q ; columns 0..n-1: w, n..2n-1: z, 2n: z0, last: rhs.
    T = np.hstack([np.eye(n), -M, -np.ones((n, 1)), q[:, None]])
    basis = np.arange(n)
    z0 = 2 * n

    def pivot(r: int, c: int):
        T[r] /= T[r, c]
        col = T[:, c].copy()
        col[r] = 0.0
        T[:] -= np.outer(col, T[r])

    r = int(np.argmin(q))
    pivot(r, z0)
    leaving, basis[r] = basis[r], z0
    pivots = 0
    status = 2
    while pivots < max_pivots:
        entering = leaving + n if leaving < n else leaving - n
        col = T[:, entering]
        cand = np.flatnonzero(col > tol * max(1.0, np.max(np.abs(col))))
        if cand.size == 0:
            status = 1
            break
        ratios = T[cand, -1] / col[cand]
        rmin = ratios.min()
        ties = cand[ratios <= rmin + 1e-12 * max(1.0, abs(rmin))]
        if ties.size > 1:
            zrow = ties[basis[ties] == z0]
            if zrow.size:
                ties = zrow  # let z0 leave as soon as it can: that ends the algorithm
            else:
                # lexicographic rule on the rows of B^-1 (the w columns) scaled by the pivot column
                for j in range(n):
                    vals = T[ties, j] / col[ties]
                    ties = ties[vals <= vals.min() + 1e-14 * max(1.0, abs(vals.min()))]
                    if ties.size == 1:
                        break
        r = int(ties[0])
        pivot(r, entering)
        leaving, basis[r] = basis[r], entering
        pivots += 1
        if leaving == z0:
            status = 0
            break

    z = np.zeros(n)
    if status == 0:
        # Re-solve the final basis:  [I, -M][:, basis] x_B = q.
        B = np.hstack([np.eye(n), -M])[:, basis]
        try:
            xB = np.linalg.solve(B, q)
        except np.linalg.LinAlgError:
            xB = T[:, -1]
        zb = basis >= n
        z[basis[zb] - n] = np.maximum(xB[zb], 0.0)
    return LemkeResult(z, M @ z + q, status, STATUS[status], pivots, _residual(M, q, z))


def _residual(M, q, z) -> float:
    return float(np.max(np.abs(np.minimum(z, M @ z + q)))) if q.size else 0.0
