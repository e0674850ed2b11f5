"""Semismooth Newton (Alart-Curnier) for planar frictional contact on sparse linear algebra.

With u = W p + q (normals first, :class:`~lcp.contact.problem.ContactProblem`'s order) and the
natural-map weights rho = 1/diag(W), the Coulomb law is the nonsmooth equation Phi(p) = 0,

    Phi_N = p_N - max(0, z_N),                      z_N = p_N - rho_N u_N,
    Phi_T = p_T - proj_[-mu z_N+, mu z_N+](z_T),    z_T = p_T - rho_T u_T.

Phi is piecewise affine; on each piece (per contact: open, stick, slide+, slide-) its Jacobian is
J = A + B W with A, B sparse and diagonal except for the friction coupling of sliding contacts.
Each iteration solves J d = -Phi with SuperLU and takes the largest step 2^-i that decreases
||Phi||^2 (Armijo). On a piece containing the solution one full step lands on it exactly, so the
iteration ends at rounding level; from a poor start the line search keeps it from running away,
and a stall is reported, never hidden.
"""
from __future__ import annotations

import numpy as np
from lcp.numerics.lazy import issparse
from lcp.numerics.lazy import sparse as sp

__all__ = ["armijo", "alart_curnier", "newton_solve"]


def alart_curnier(W, q, mu, rho, p):
    """Phi(p) (see module doc) and the piece's coefficients: (phi, u, closed, stick, sgn)."""
    k = mu.size
    u = W @ p + q
    pN, pT = p[:k], p[k:]
    zN = pN - rho[:k] * u[:k]
    zT = pT - rho[k:] * u[k:]
    closed = zN > 0
    s = mu * np.maximum(zN, 0.0)
    stick = closed & (np.abs(zT) < s)
    phi = np.concatenate([pN - np.maximum(zN, 0.0), pT - np.clip(zT, -s, s)])
    return phi, u, closed, stick, np.sign(zT)


def _jacobian(W, mu, rho, closed, stick, sgn):
    """J = A + B W on the current piece (sparse, CSC)."""
    k = mu.size
    j = np.arange(k)
    slide = closed & ~stick
    # Phi_N: closed -> rho_N u_N (row rho_N W_N), open -> p_N (identity)
    # Phi_T: stick -> rho_T u_T; slide -> p_T - sgn mu (p_N - rho_N u_N); open -> p_T
    a_diag = np.concatenate([np.where(closed, 0.0, 1.0), np.where(stick, 0.0, 1.0)])
    b_diag = np.concatenate([np.where(closed, rho[:k], 0.0), np.where(stick, rho[k:], 0.0)])
    js = j[slide]
    c = sgn[slide] * mu[slide]
    A = sp.csr_matrix((np.concatenate([a_diag, -c]), (np.concatenate([np.arange(2 * k), k + js]),
                                                      np.concatenate([np.arange(2 * k), js]))), shape=(2 * k, 2 * k))
    B = sp.csr_matrix((np.concatenate([b_diag, c * rho[js]]), (np.concatenate([np.arange(2 * k), k + js]),
                                                               np.concatenate([np.arange(2 * k), js]))),
                      shape=(2 * k, 2 * k))
    return (A + B @ W).tocsc()


def newton_solve(W, q, mu, rho, p0, tol: float, max_iter: int = 50, residual=None, max_damped: int = 8):
    """Semismooth Newton from p0 until ``residual(p) <= tol``.

    Parameters
    ----------
    W : ndarray or scipy.sparse matrix, shape (2k, 2k)
    q, rho : ndarray, shape (2k,)
    mu : ndarray, shape (k,)
    p0 : ndarray, shape (2k,)
        Start (e.g. a few NSGS sweeps, or the previous step's impulses).
    tol : float
        Stopping value of ``residual``.
    residual : callable, optional
        The stopping measure (default: max |Phi|).
    max_damped : int
        Stop after this many damped (t < 1) steps in a row.

    Returns
    -------
    p, iterations, residual value, message ("converged" or why it stopped)
    """
    from scipy.sparse.linalg import splu

    W = sp.csr_matrix(W) if not issparse(W) else W
    p = np.array(p0, dtype=float)
    resid = residual or (lambda x: float(np.max(np.abs(alart_curnier(W, q, mu, rho, x)[0]))))
    res = resid(p)
    if res <= tol:
        return p, 0, res, "converged"
    phi, _, closed, stick, sgn = alart_curnier(W, q, mu, rho, p)
    merit = float(phi @ phi)
    damped = 0
    for it in range(1, max_iter + 1):
        J = _jacobian(W, mu, rho, closed, stick, sgn)
        try:
            d = splu(J).solve(-phi)
        except RuntimeError:
            # a singular piece (redundant contacts): a tiny Levenberg shift keeps the direction
            J = J + 1e-12 * max(1.0, float(abs(J).max())) * sp.identity(J.shape[0], format="csc")
            try:
                d = splu(J).solve(-phi)
            except RuntimeError as exc:
                return p, it, res, f"singular Newton matrix at iteration {it}: {exc}"
        if not np.all(np.isfinite(d)):
            return p, it, res, f"non-finite Newton direction at iteration {it}"
        step = armijo(lambda x: alart_curnier(W, q, mu, rho, x), p, d, merit)
        if step is None:
            return p, it, res, f"line search failed at iteration {it} (merit {merit:.3g})"
        t, p, merit, (phi, _, closed, stick, sgn) = step
        res = resid(p)
        if res <= tol:
            return p, it, res, "converged"
        # near a solution the full step is taken; a run of damped steps means Newton is far from
        # one (or the problem is degenerate): hand back to the caller rather than factorize on
        damped = damped + 1 if t < 1.0 else 0
        if damped >= max_damped:
            return p, it, res, f"{damped} damped steps in a row at iteration {it} (residual {res:.3g})"
    return p, max_iter, res, f"no convergence in {max_iter} Newton iterations (residual {res:.3g})"


def armijo(evaluate, p, d, merit):
    """Backtracking (Armijo) line search on the merit |Phi|^2 along the Newton direction d.

    ``evaluate(x)`` returns a tuple whose first member is Phi(x). Steps 1, 1/2, 1/4, ... (40 at
    most) until the merit falls by the Armijo fraction 1e-4 t, or reaches zero. Returns
    (t, p + t d, its merit, evaluate's tuple there), or None when no step is accepted. Shared by
    the planar and the disk law's Newton iterations.
    """
    t = 1.0
    for _ in range(40):
        p_new = p + t * d
        out = evaluate(p_new)
        phi_new = out[0]
        m_new = float(phi_new @ phi_new)
        if m_new <= (1 - 1e-4 * t) * merit or m_new == 0.0:
            return t, p_new, m_new, out
        t *= 0.5
    return None
