"""Position projection for Moreau-Jean: the positions back onto the constraints after each step.

Moreau-Jean imposes the bilateral constraints and the closed contacts at the velocity level only
(G(q_k) v_{k+1} + phi_t = 0, u_N >= 0). A constraint that is affine in q is then kept exactly, but
one that is nonlinear drifts by O(h) over a fixed time: a pendulum written as x^2 + y^2 = L^2
lengthens, a ball rolling in a bowl sinks. The projected Moreau-Jean schemes (Acary 2013, the
"direct projection" of Siconos) correct the positions after each velocity step, by a small
correction in the kinetic (mass) metric, an approximation of

    minimize 1/2 dq' A dq   subject to  phi(t, q + dq) = 0,   g_j(q + dq) >= 0 (every contact j)

exact to first order in the violation: Newton's method whose steps are the least-norm
corrections of the constraints linearized at the current iterate,

    dq = A^-1 J' mu,   (J A^-1 J') mu = -r,   J = [G; H_N,W],   r = [phi(t, q); g_W(q)],

where W is a working set of contacts held at g_j = 0. The projection acts on the bilateral
constraints and on the contacts closed in the step (a normal impulse p_N > 0, no bounce, and a
normal velocity after the step that does not separate: the position-level form of
0 <= g_j perp p_N,j >= 0), held at g_j = 0 as equalities, so that a loaded pivot or a curved resting
contact neither sinks nor drifts open. A contact whose normal velocity separates after the step
(or that bounced by restitution) is *opening*: it is left alone whatever its gap, never pulled shut
nor pushed out (its own motion opens it; a cam follower thrown off at 16 m/s was held on the cam).
Any other contact enters W when its gap is negative beyond the tolerance, and leaves it when its
multiplier mu_j would pull (mu_j < 0). W starts afresh at every call: nothing of a previous step's
working set is carried over (a contact that entered it once was pulled shut from 2 mm away in the
next call).

Converged when |phi_i| <= tol s_i and g_j >= -tol s_j (contacts in W: |g_j| <= tol s_j), with

    s_i = sum_k |J_ik| (|q_k| + L_k) + |r_i(t, 0)|,

the size of the terms of the linearized constraint (for x^2 + y^2 - L^2, about 3 L^2), its own
constant r_i(t, 0) (a floor's height), and L the lengths of the coordinates: the system's length
(:func:`lcp.model.start.system_length`) plus the step's motion h |v|. With |J||q| alone the scale
vanished at q = 0, where a gap of -1e-199 was "not converged".

Cost: the whole Newton update (two iterations, unrolled) and the residuals and scales at its result
are one CasADi Function evaluated through a preallocated buffer, so a step that needs no working-set
change costs one evaluation and a few NumPy operations on (n_bilateral + m)-vectors. The velocities
are not projected (as in Siconos's direct projection): the next step's velocity constraint is
imposed at the projected positions.

With Newton-Euler kinematics (qdot = T(q) v) J is in v-space (the System's G and H), the
correction moves q by T(q) A^-1 J' mu and the unit quaternions are renormalised after it; the
scale's |q| + L is mapped to v-space by |T|' (as in :mod:`lcp.model.start`).

A system needs the projection (:func:`needs_projection`) when a constraint Jacobian depends on q or
t (curved or rheonomic constraints) or a contact's normal depends on q; systems whose constraints
are all affine and time-independent (every constant system) never pay for it.

References
----------
V. Acary, Projected event-capturing time-stepping schemes for nonsmooth mechanical systems with
unilateral contact and Coulomb's friction, Comput. Methods Appl. Mech. Engrg. 256 (2013) 224-250.
"""
from __future__ import annotations

import math
import weakref

import casadi as ca
import numpy as np

from lcp.model.kinematics import normalized_expr

__all__ = ["NEWTON_PER_EVAL", "PositionProjection", "needs_projection"]

#: Newton iterations unrolled in one evaluation (two bring an O(h^2) step drift to rounding)
NEWTON_PER_EVAL = 2
#: beyond this many coordinates plus constraint rows the update is built as an MX graph (a symbolic
#: SX solve would grow like the cube of the size)
_SX_MAX_SIZE = 30


#: needs_projection per System (decided once: a symbolic Jacobian costs ~0.1 ms)
_NEEDS = weakref.WeakKeyDictionary()


def needs_projection(system) -> bool:
    """Whether a constraint of ``system`` is nonlinear in q (or time-dependent beyond an affine
    phi(t, q) = G q + c): then Moreau-Jean drifts off it and the projection is worth its cost."""
    known = _NEEDS.get(system)
    if known is None:
        known = _NEEDS[system] = _needs_projection(system)
    return known


def _needs_projection(system) -> bool:
    q, t = system.q_sym, system.t_sym
    tq = ca.vertcat(t, q)
    nb, m = system.n_bilateral, system.n_contacts
    if nb:
        G = ca.jacobian(system.constraints_expr, q)
        phi_t = ca.jacobian(system.constraints_expr, t)
        if ca.depends_on(ca.vertcat(ca.vec(G), ca.vec(phi_t)), tq):
            return True
    if m and getattr(system, "contacts_depend_on_t", False) and ca.depends_on(system.contact_rate_expr[:m], tq):
        return True  # a moving gap of varying speed: held at the velocity level only, it drifts by O(h)
    return bool(m) and bool(ca.depends_on(ca.vec(system.H_expr[:m, :]), q))


def _update_function(system, iterations: int) -> ca.Function:
    """(t, q, w, L) -> (q_new, r, s, pull): ``iterations`` Newton steps towards phi = 0 and g_W = 0
    (w is the 0/1 mask of the working set), then the residuals r = [phi; g] and scales
    s = |J| (|q_new| + L) + |r(t, 0)| at q_new (L: the lengths of the coordinates, module docstring),
    and the multipliers of the last step in length units, mu_j (J A^-1 J')_jj (zero outside W;
    negative where the row pulls)."""
    n, nb, m = system.n, system.n_bilateral, system.n_contacts
    sym = ca.SX if n + nb + m <= _SX_MAX_SIZE else ca.MX
    qs, ts = system.q_sym, system.t_sym
    kin = getattr(system, "has_kinematics", False)
    nq = system.n_q if kin else n
    # with Newton-Euler kinematics (qdot = T v) the rows' Jacobians are in v-space (the System's G
    # and H), a correction dx moves q by T(q) dx, and unit quaternions are renormalised after it
    G = ca.jacobian(system.constraints_expr, qs)
    J_expr = ca.vertcat(ca.mtimes(G, system.kinematics_expr) if kin else G, system.H_expr[:m, :])
    outs = [system.mass_expr, ca.vertcat(system.constraints_expr, system.gap_expr), J_expr]
    data = ca.Function("projection_data", [ts, qs], outs + ([system.kinematics_expr] if kin else []))
    t, q, w, L = sym.sym("t"), sym.sym("q", nq), sym.sym("w", m), sym.sym("L", nq)
    mask = ca.vertcat(sym.ones(nb), w)
    free = ca.diag(1 - mask)  # rows outside W: mu = 0 there
    mu, d = sym.zeros(nb + m), sym.zeros(nb + m)
    qk = q
    for _ in range(iterations):
        A, r, J, *T = data(t, qk)
        Jm = ca.diag(mask) @ J
        AiJt = ca.solve(A, Jm.T)
        S = Jm @ AiJt + free
        # a tiny diagonal keeps S invertible for redundant contacts in W (a least-norm answer)
        S = S + 1e-14 * ca.mmax(ca.fabs(ca.diag(S))) * sym.eye(nb + m)
        mu = -ca.solve(S, mask * r)
        d = ca.diag(S)
        qk = qk + AiJt @ mu if not kin else normalized_expr(system, qk + T[0] @ (AiJt @ mu))
    _, r, J, *T = data(t, qk)
    _, r0, *_ = data(t, sym.zeros(nq))  # the rows' own constants (a floor's height, a rod's length squared)
    reach = ca.fabs(qk) + L if not kin else ca.mtimes(ca.fabs(T[0]).T, ca.fabs(qk) + L)  # as lcp.model.start
    s = ca.mtimes(ca.fabs(J), reach) + ca.fabs(r0)
    return ca.Function("position_projection", [t, q, w, L], [qk, r, s, mu * d], ["t", "q", "w", "L"],
                       ["q_new", "r", "s", "pull"])


class PositionProjection:
    """The position projection of one system (see the module docstring).

    Parameters
    ----------
    system : lcp.model.system.System
    tol : float
        Relative tolerance on the constraints (see the module docstring), in [1e-15, 1).
    max_evals : int
        Evaluations (each ``NEWTON_PER_EVAL`` Newton iterations) allowed per step before the
        projection is reported as failed.

    Examples
    --------
    A pendulum of length 1 started 1 % too long comes back onto the circle:

    >>> import casadi as ca, numpy as np
    >>> from lcp.model.system import System
    >>> from lcp.timestepping.projection import PositionProjection
    >>> q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    >>> s = System(q, v, ca.SX.eye(2), ca.vertcat(0, -9.81), constraints=q[0]**2 + q[1]**2 - 1)
    >>> P = PositionProjection(s)
    >>> qp, ok, iters, worst = P.project(0.0, np.array([0.6, -0.808]))
    >>> ok, round(float(np.hypot(*qp)), 14)
    (True, 1.0)
    """

    def __init__(self, system, tol: float = 1e-12, max_evals: int = 8):
        if not (isinstance(tol, (int, float, np.floating)) and 1e-15 <= tol < 1):
            raise ValueError(f"projection_tol must lie in [1e-15, 1), got {tol!r}")
        self.sys, self.tol, self.max_evals = system, float(tol), int(max_evals)
        self.nb, self.m, self.n = system.n_bilateral, system.n_contacts, system.n
        fn = self.function = _update_function(system, NEWTON_PER_EVAL)  # (the compiled general loop's C)
        self._buf, self._run = fn.buffer()
        k = self.nb + self.m
        self._t = np.zeros(1)
        nq = getattr(system, "n_q", self.n)
        self._q = np.zeros(nq)
        self._w = np.zeros(self.m)
        self._L = np.zeros(nq)
        self._qo, self._r, self._s, self._mu = np.zeros(nq), np.zeros(k), np.zeros(k), np.zeros(k)
        for i, a in enumerate((self._t, self._q, self._w, self._L)):
            self._buf.set_arg(i, memoryview(a))
        for i, a in enumerate((self._qo, self._r, self._s, self._mu)):
            self._buf.set_res(i, memoryview(a))
        self.length = None  # the system's length (lcp.model.start.system_length), found at the first call
        self.working = np.zeros(self.m, dtype=bool)  # the last call's working set (never carried over)

    def project(self, t: float, q: np.ndarray, closed=None, opening=None, lengths=None):
        """Project q at time t; ``closed`` (bool mask over the contacts, optional) are held at g = 0,
        ``opening`` (bool mask) are left alone whatever their gap; ``lengths`` (scalar or one per
        coordinate) is L of the tolerance's scale (module docstring), by default the system's length.

        Returns
        -------
        q_new : ndarray
        ok : bool
            False when ``max_evals`` evaluations did not converge (q_new is then the last iterate).
        iterations : int
            Newton iterations spent.
        violation : float
            max |phi_i| and max(0, -g_j) at q_new, in the constraints' units.
        """
        nb, tol = self.nb, self.tol
        self._t[0] = t
        self._q[:] = q
        if lengths is None:
            if self.length is None:
                from lcp.model.start import system_length

                self.length = system_length(self.sys, q, t)
            lengths = self.length
        self._L[:] = lengths
        hold = np.zeros(self.m, dtype=bool) if closed is None else np.asarray(closed, dtype=bool)
        free = np.ones(self.m, dtype=bool) if opening is None else ~np.asarray(opening, dtype=bool)
        hold = hold & free
        w = hold.copy()
        ok = False
        evals = 0
        while evals < self.max_evals:
            self._w[:] = w
            self._run()
            evals += 1
            r, lim = self._r, tol * self._s
            bil_ok = nb == 0 or bool(np.all(np.abs(r[:nb]) <= lim[:nb]))
            if self.m:
                g, lg = r[nb:], lim[nb:]
                pull = w & ~hold & (self._mu[nb:] < -lg)  # would pull the gap shut by more than tol
                pen = ~w & free & (g < -lg)  # an opening contact is never moved: its motion opens it
                closed_ok = bool(np.all(np.abs(g[w]) <= lg[w])) if w.any() else True
                changed = bool(pull.any() or pen.any())
                if changed:
                    w = (w & ~pull) | pen
            else:
                changed, closed_ok = False, True
            self._q[:] = self._qo
            if bil_ok and closed_ok and not changed:
                ok = True
                break
        self.working = w
        violation = float(np.max(np.abs(self._r[:nb]))) if nb else 0.0
        if self.m:
            violation = max(violation, float(-np.min(self._r[nb:])), 0.0)
        return self._qo.copy(), ok, evals * NEWTON_PER_EVAL, violation

    def reset(self):
        """Forget the last call's working set (nothing of it is used by the next call)."""
        self.working = np.zeros(self.m, dtype=bool)


def violation_function(system):
    """A callable Q (k, n), t (k,) -> worst violation over the states, for results computed without
    projection (evaluated on first access of ``max_constraint_violation``)."""
    nb, m = system.n_bilateral, system.n_contacts
    if nb + m == 0:
        return lambda Q, t: 0.0
    f = ca.Function("violation", [system.t_sym, system.q_sym], [ca.vertcat(system.constraints_expr, system.gap_expr)])

    def worst(Q, t):
        if Q.shape[0] == 0:
            return 0.0
        R = np.array(f.map(Q.shape[0])(np.asarray(t).reshape(1, -1), np.asarray(Q).T), dtype=float)
        out = float(np.max(np.abs(R[:nb]))) if nb else 0.0
        if m:
            out = max(out, float(-np.min(R[nb:])), 0.0)
        return out if math.isfinite(out) else float("nan")
    return worst
