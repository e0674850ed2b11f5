"""The smooth step of the order-two scheme: RATTLE (velocity Verlet with SHAKE/RATTLE constraints).

Holds :class:`RattleStep`, one step of the constrained smooth dynamics

    A(t, q) v' = F(t, q, v) + G(t, q)' lambda,   phi(t, q) = 0,

without contacts, by the kick-drift-kick splitting of Andersen's RATTLE (the Lobatto IIIA-IIIB
pair), which is of order two for q and v, symmetric, and symplectic where A is constant and F
conservative (Hairer, Lubich, Wanner, Geometric Numerical Integration, VII.1):

    A~0 (v_1/2 - v0) = h/2 (F(t0, q0, v0) + G0' lambda),   A~0 = A(t0, q0) + h/2 C(t0, q0, v0),
    q1 = q0 + h v_1/2,   phi(t1, q1) = 0                          (SHAKE: lambda by Newton),
    A(t1, q1) (v1 - v_1/2) = h/2 (F(t1, q1, v_1/2) + G1' mu),
    G(t1, q1) v1 + phi_t(t1, q1) = 0                               (RATTLE: mu linear),

with C = -dF/dv: the first kick is implicit in v (linearized once: the term h^2/4 A^-1 dF/dv F
that order two needs where forces depend on v, e.g. the Coriolis terms of a q-dependent mass
matrix); the second is explicit. Springs are explicit (stable for h omega < 2).

The whole step (kick, drift, two Newton iterations of SHAKE, kick) is one CasADi Function; where two
iterations leave |phi_i| > tol s_i (s_i = sum_k |G_ik q_k|, the size of the row's terms), further
iterations follow, each one evaluation. Imports CasADi and NumPy only; never the loops, the contact
step or anything above :mod:`lcp.timestepping`.

References
----------
H. C. Andersen, Rattle: a "velocity" version of the Shake algorithm for molecular dynamics
calculations, J. Comput. Phys. 52 (1983) 24-34.
L. O. Jay, Symplectic partitioned Runge-Kutta methods for constrained Hamiltonian systems,
SIAM J. Numer. Anal. 33 (1996) 368-387.
"""
from __future__ import annotations

import weakref

import casadi as ca
import numpy as np

__all__ = ["Buffered", "RattleStep", "SHAKE_PER_EVAL", "SX_MAX_SIZE"]

#: Newton iterations of SHAKE unrolled in one evaluation (two bring an O(h^2) violation to rounding)
SHAKE_PER_EVAL = 2
#: beyond this many coordinates plus constraint rows the step is an MX graph (SX solves grow like n^3)
SX_MAX_SIZE = 30


def _newton(system, t1, q, P, iterations):
    """``iterations`` SHAKE Newton steps q <- q + P nu, (G(t1, q) P) nu = -phi(t1, q); then the
    residual and the size of each row's terms at the result."""
    for _ in range(iterations):
        phi, G, _ = system.constraints_fn(t1, q)
        q = q - ca.mtimes(P, ca.solve(ca.mtimes(G, P), phi))
    phi, G, _ = system.constraints_fn(t1, q)
    return q, phi, ca.mtimes(ca.fabs(G), ca.fabs(q))


def _kick2(system, t1, q0, q1, h, sym):
    """The closing kick: v1 from the drift's v_1/2 = (q1 - q0) / h, with G(t1, q1) v1 + phi_t = 0;
    then the gaps at q1 and the size of their terms (for the closing test)."""
    n, nb, m = system.n, system.n_bilateral, system.n_contacts
    vh = (q1 - q0) / h
    A1 = system.mass_fn(t1, q1)
    F1 = system.force_fn(t1, q1, vh)
    if nb:
        _, G1, phit1 = system.constraints_fn(t1, q1)
        KKT = ca.blockcat([[A1, G1.T], [G1, sym(nb, nb)]])
        dv = ca.solve(KKT, ca.vertcat(h / 2 * F1, -phit1 - ca.mtimes(G1, vh)))[:n]
    else:
        dv = ca.solve(A1, h / 2 * F1)
    if m:
        gap = system.gap_fn(q1)
        HN = system.H_fn(q1)[:m, :]
        gsize = ca.mtimes(ca.fabs(HN), ca.fabs(q1)) + ca.fabs(gap)
    else:
        gap = gsize = sym(0, 1)
    return vh + dv, gap, gsize


def rattle_functions(system):
    """(step, newton, kick) Functions of one system (module docstring).

    ``step(t0, q0, v0, h) -> (q1, v1, r, s, P, gap, gsize)``; ``newton(t1, q, P) -> (q, r, s)``
    (SHAKE_PER_EVAL more iterations); ``kick(t0, q0, q1, h) -> (v1, gap, gsize)``.
    """
    n, nb = system.n, system.n_bilateral
    sym = ca.SX if n + nb <= SX_MAX_SIZE else ca.MX
    t0, h = sym.sym("t0"), sym.sym("h")
    q0, v0 = sym.sym("q0", n), sym.sym("v0", n)
    t1 = t0 + h
    A0 = system.mass_fn(t0, q0)
    F0 = system.force_fn(t0, q0, v0)
    _, C0 = system.force_jac_fn(t0, q0, v0)
    At = A0 + h / 2 * C0
    qhat = q0 + h * (v0 + ca.solve(At, h / 2 * F0))
    if nb:
        _, G0, _ = system.constraints_fn(t0, q0)
        P = ca.solve(At, G0.T)
        q1, r, s = _newton(system, t1, qhat, P, SHAKE_PER_EVAL)
    else:
        P, q1, r, s = sym(n, 0), qhat, sym(0, 1), sym(0, 1)
    v1, gap, gsize = _kick2(system, t1, q0, q1, h, sym)
    dense = lambda xs: [ca.densify(x) for x in xs]  # noqa: E731 - dense buffers: one layout per output
    step = ca.Function("rattle_step", [t0, q0, v0, h], dense([q1, v1, r, s, P, gap, gsize]))
    ts, qs, Ps = sym.sym("t1"), sym.sym("q", n), sym.sym("P", n, nb)
    newton = ca.Function("shake_newton", [ts, qs, Ps], dense(_newton(system, ts, qs, Ps, SHAKE_PER_EVAL)
                                                             if nb else [qs, sym(0, 1), sym(0, 1)]))
    q1s = sym.sym("q1", n)
    kick = ca.Function("rattle_kick", [t0, q0, q1s, h], dense(_kick2(system, t0 + h, q0, q1s, h, sym)))
    return step, newton, kick


class Buffered:
    """A Function evaluated through preallocated NumPy buffers (a plain call costs ~100 us in
    argument conversions; this, a few)."""

    def __init__(self, fn):
        self.args = [np.zeros(fn.nnz_in(i)) for i in range(fn.n_in())]
        self.res = [np.zeros(fn.nnz_out(i)) for i in range(fn.n_out())]
        self._buf, self._run = fn.buffer()
        for i, a in enumerate(self.args):
            self._buf.set_arg(i, memoryview(a))
        for i, a in enumerate(self.res):
            self._buf.set_res(i, memoryview(a))

    def __call__(self, *args):
        for a, x in zip(self.args, args):
            a[:] = x
        self._run()
        return [r.copy() for r in self.res]


#: system -> its rattle_functions (weak keys: they live as long as the System)
_FUNCTIONS = weakref.WeakKeyDictionary()


class RattleStep:
    """One contact-free RATTLE step of a system (module docstring).

    Parameters
    ----------
    system : lcp.model.system.System
    tol : float
        Relative tolerance of SHAKE on the constraints, as the position projection's.
    max_evals : int
        Evaluations of SHAKE (each ``SHAKE_PER_EVAL`` Newton iterations) before the step is
        reported as failed.

    Examples
    --------
    A pendulum of length 1 released horizontally stays on its circle:

    >>> import casadi as ca, numpy as np
    >>> from lcp.model.system import System
    >>> from lcp.timestepping.rattle import RattleStep
    >>> q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    >>> s = System(q, v, ca.SX.eye(2), ca.vertcat(0, -9.81), constraints=q[0]**2 + q[1]**2 - 1)
    >>> q1, v1, gap, gsize, ok, iters, viol = RattleStep(s)(0.0, np.array([1.0, 0.0]), np.zeros(2), 1e-2)
    >>> ok, round(float(np.hypot(*q1)), 13), abs(float(q1 @ v1)) < 1e-14
    (True, 1.0, True)
    """

    def __init__(self, system, tol: float = 1e-12, max_evals: int = 8):
        fns = _FUNCTIONS.get(system)
        if fns is None:
            fns = _FUNCTIONS[system] = rattle_functions(system)
        self.step, self.newton, self.kick = (Buffered(f) for f in fns)
        self.nb, self.n, self.m = system.n_bilateral, system.n, system.n_contacts
        self.tol, self.max_evals = float(tol), int(max_evals)

    def __call__(self, t: float, q: np.ndarray, v: np.ndarray, h: float):
        """The step from (t, q, v).

        Returns
        -------
        q1, v1 : ndarray
        gap, gsize : ndarray
            The gaps at q1 and the size of their terms (m each).
        ok : bool
            False where SHAKE did not converge within ``max_evals`` evaluations.
        iterations : int
            SHAKE Newton iterations spent.
        violation : float
            max |phi_i(t + h, q1)|.
        """
        q1, v1, r, s, P, gap, gsize = self.step(t, q, v, h)
        if not self.nb:
            return q1, v1, gap, gsize, True, 0, 0.0
        evals = 1
        while not np.all(np.abs(r) <= self.tol * s):
            if evals >= self.max_evals or not np.all(np.isfinite(r)):
                return q1, v1, gap, gsize, False, evals * SHAKE_PER_EVAL, float(np.max(np.abs(r)))
            q1, r, s = self.newton(t + h, q1, P)
            evals += 1
        if evals > 1:  # the closing kick at the converged positions
            v1, gap, gsize = self.kick(t, q, q1, h)
        return q1, v1, gap, gsize, True, evals * SHAKE_PER_EVAL, float(np.max(np.abs(r)))
