"""A smooth phase's whole right-hand side as one CasADi Function.

An ODE phase (:class:`~lcp.events.ode_phase.OdePhase`) of a system whose mass matrix or contacts
depend on q evaluates, at every stage of every step, the System's data (mass matrix, forces,
Jacobians), then the branch of its fixed modes (:class:`~lcp.events.modes.PhaseBranch`): two
dense solves and a small branch system, a few dozen NumPy calls. For small systems those calls
cost far more than the arithmetic (measured on the cart-pole: about 90 us per evaluation). Here
the same equations are written once symbolically, per system and branch, and the state derivative
(qdot, qdd, N, f) is one evaluation of one Function (about 5 us). Used under the event option
``rhs="compiled"``, the default (:class:`~lcp.events.options.EventOptions`); the decisions, the
event functions and the reported forces keep the NumPy arithmetic.

The linear solves are Gaussian elimination with partial pivoting written out symbolically
(:func:`lu_solve`), as LAPACK's LU solves them in the NumPy path, not CasADi's own symbolic
``solve`` (QR without pivoting, measured 100 to 10000 times less accurate on systems of condition
1e4 to 1e8); the two paths agree to rounding, not bit for bit. Where a value
is not finite (a singular branch, a force that is not finite) the caller evaluates the NumPy path,
which says what went wrong. Larger systems keep the NumPy path (:data:`MAX_SIZE`): a symbolic
solve grows as the cube of its size.
"""
from __future__ import annotations

import functools
import weakref

import casadi as ca
from lcp.events.model import accel_function, qdot_function

__all__ = ["MAX_SIZE", "branch_function", "branch_rhs_function", "lu_solve"]

#: the largest n + n_bilateral (and 2 x closed contacts) compiled; above it the NumPy path
MAX_SIZE = 12

#: system -> {(closed contacts, slide signs, friction coefficients): Function}
_FUNCTIONS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def branch_rhs_function(system, m: int, idx: tuple, slide: tuple, mu) -> ca.Function | None:
    """(t, q, v) -> (qdot, qdd, N (m), f (m)) stacked, of the phase whose closed contacts are
    ``idx`` with slide signs ``slide`` (0: sticking), built once per system and branch; None where
    the system is too large to compile (:data:`MAX_SIZE`)."""
    k = len(idx)
    if system.n + system.n_bilateral > MAX_SIZE or 2 * k > MAX_SIZE:
        return None
    key = (tuple(idx), tuple(slide), tuple(float(mu[j]) for j in idx))
    per = _FUNCTIONS.get(system)
    if per is None:
        per = _FUNCTIONS[system] = {}
    fn = per.get(key)
    if fn is None:
        fn = per[key] = _build(system, m, *key)
    return fn


def _build(system, m: int, idx: tuple, slide: tuple, mu: tuple) -> ca.Function:
    """The system's data (:func:`~lcp.events.model.accel_function`) fed to the branch's
    (:func:`branch_function`), inlined into one Function of (t, q, v)."""
    n, nq = system.n, system.n_q
    t, q, v = ca.SX.sym("t"), ca.SX.sym("q", nq), ca.SX.sym("v", n)
    A, F, G, zeta, H, Hdv, _ = accel_function(system)(t, q, v)
    qdd_N_f = branch_function(n, system.n_bilateral, m, idx, slide, mu)(
        ca.densify(A), ca.densify(F), ca.densify(G), ca.densify(zeta), ca.densify(H), ca.densify(Hdv))
    qfn = qdot_function(system)
    qdot = v if qfn is None else qfn(t, q, v)
    return ca.Function("phase_rhs", [t, q, v], [ca.densify(ca.vertcat(qdot, qdd_N_f))])


@functools.lru_cache(maxsize=256)
def branch_function(n: int, nb: int, m: int, idx: tuple, slide: tuple, mu: tuple) -> ca.Function:
    """(A, F, G, zeta, H, Hdv) -> (qdd, N (m), f (m)) stacked: the accelerations and forces of the
    branch of :class:`~lcp.events.modes.PhaseBranch` (closed contacts ``idx``, slide signs
    ``slide``, their friction coefficients ``mu``), for any system of these sizes (dense
    arguments), built once per structure."""
    k = len(idx)
    A, F, G = ca.SX.sym("A", n, n), ca.SX.sym("F", n), ca.SX.sym("G", nb, n)
    zeta, H, Hdv = ca.SX.sym("zeta", nb), ca.SX.sym("H", 2 * m, n), ca.SX.sym("Hdv", 2 * m)
    K = ca.blockcat([[A, G.T], [G, ca.SX(nb, nb)]]) if nb else A
    rows = list(idx) + [m + j for j in idx]
    Hc = H[rows, :]
    # a sliding contact's normal column carries its friction: d_j = H_N,j' - mu_j s_j H_T,j'
    cols = []
    for jj in range(k):
        col = Hc[jj, :].T
        if slide[jj] != 0:
            col = col - mu[jj] * slide[jj] * Hc[k + jj, :].T
        cols.append(col)
    cols += [Hc[k + jj, :].T for jj in range(k)]
    rhs = ca.horzcat(F, *cols) if k else F
    if nb:
        rhs = ca.vertcat(rhs, ca.horzcat(-zeta, ca.SX(nb, 2 * k)))
    X = lu_solve(K, rhs)[:n, :]
    qdd_free = X[:, 0]
    if k:
        SD = X[:, 1:]
        W = ca.mtimes(Hc, SD)
        b = ca.mtimes(Hc, qdd_free) + Hdv[rows]
        # the branch system of dense_branch_solution: normal rows w_N = 0; sticking tangents w_T = 0;
        # a sliding tangent's unknown is zero (its friction is folded into the normal column)
        E, r = ca.SX(2 * k, 2 * k), ca.SX(2 * k, 1)
        for jj in range(k):
            E[jj, :], r[jj] = W[jj, :], -b[jj]
            if slide[jj] == 0:
                E[k + jj, :], r[k + jj] = W[k + jj, :], -b[k + jj]
            else:
                E[k + jj, k + jj] = 1.0
        p = lu_solve(E, r)
        qdd = qdd_free + ca.mtimes(SD, p)
        N = p[:k]
        f = ca.vertcat(*[(-mu[jj] * slide[jj]) * N[jj] if slide[jj] != 0 else p[k + jj] for jj in range(k)])
    else:
        qdd, N, f = qdd_free, ca.SX(0, 1), ca.SX(0, 1)
    Nm, fm = ca.SX(m, 1), ca.SX(m, 1)
    for jj, j in enumerate(idx):
        Nm[j], fm[j] = N[jj], f[jj]
    return ca.Function("branch_accel", [A, F, G, zeta, H, Hdv], [ca.densify(ca.vertcat(qdd, Nm, fm))])


def lu_solve(A: ca.SX, B: ca.SX) -> ca.SX:
    """X with A X = B, by Gaussian elimination with partial pivoting on the symbolic dense matrices
    (the pivot row chosen at evaluation by comparisons, ``if_else``, which select values exactly).
    A singular pivot divides by zero: the result is not finite.

    Examples
    --------
    >>> import casadi as ca, numpy as np
    >>> A, b = ca.SX.sym("A", 2, 2), ca.SX.sym("b", 2)
    >>> f = ca.Function("f", [A, b], [lu_solve(A, b)])
    >>> np.array(f(np.array([[1e-20, 1.0], [1.0, 1.0]]), np.array([1.0, 2.0]))).ravel().tolist()
    [1.0, 1.0]
    """
    s = A.shape[0]
    M = ca.horzcat(ca.densify(A), ca.densify(B))
    rows = [M[i, :] for i in range(s)]
    for c in range(s):
        # the largest |entry| of column c at or below the diagonal comes to row c (the first of equals)
        for i in range(c + 1, s):
            bigger = ca.fabs(rows[i][c]) > ca.fabs(rows[c][c])
            rows[c], rows[i] = ca.if_else(bigger, rows[i], rows[c]), ca.if_else(bigger, rows[c], rows[i])
        for i in range(c + 1, s):
            factor = rows[i][c] / rows[c][c]
            rows[i] = ca.horzcat(ca.SX(1, c + 1), rows[i][c + 1:] - factor * rows[c][c + 1:])
    X = [None] * s
    for i in reversed(range(s)):
        acc = rows[i][s:]
        for j in range(i + 1, s):
            acc = acc - rows[i][j] * X[j]
        X[i] = acc / rows[i][i]
    return ca.vertcat(*X)
