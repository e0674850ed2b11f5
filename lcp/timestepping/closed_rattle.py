"""The order-two step while contacts stay closed: RATTLE with the closed contacts as constraints.

Holds :class:`ClosedRattle` (and :func:`closed_functions`, the CasADi Functions it evaluates): one
step of the smooth dynamics in which a set of planar contacts stays closed, each held as a
constraint of the step,

- a **frictionless** or **sliding** contact j: its gap as a position constraint g_j(q1) = 0 (SHAKE)
  and H_N,j(q1) v1 = 0 (RATTLE), with the force (H_N,j - mu_j s_j H_T,j)' lambda_j: Coulomb's
  sliding friction -mu_j lambda_j s_j, s_j = sign(u_T,j) fixed over the step, coupled to the
  normal multiplier (the constraint force no longer lies along the constraint's gradient, so
  SHAKE's Newton iteration uses the projector A~^-1 D' with D the force directions);
- a **sticking** contact j: besides its gap, the tangent as a constraint, at the position level
  H_T,j((q0 + q1)/2)(q1 - q0) = 0 (the midpoint rule for the non-integrable row H_T,j q' = 0, of
  order two), at the velocity level H_T,j(q1) v1 = 0, with the force H_T,j' lambda_T,j.

The step is :mod:`lcp.timestepping.rattle`'s (kick, drift, SHAKE by Newton, kick) with these rows
appended to the bilateral constraints. It returns the multipliers of both kicks (lambda at the
start, mu at the end: forces), so that the caller can check that the step is what it assumed:
every closed normal multiplier >= 0 (no lift-off), every stick strictly inside the friction cone,
every slide still sliding the same way (:mod:`lcp.timestepping.second_order` decides; a step that
fails a check is taken again by Moreau-Jean). Imports CasADi, NumPy and
:mod:`lcp.timestepping.rattle`; never the loops, the contact step or anything above
:mod:`lcp.timestepping`.
"""
from __future__ import annotations

import weakref

from dataclasses import dataclass

import casadi as ca
import numpy as np

from lcp.timestepping.rattle import SHAKE_PER_EVAL, SX_MAX_SIZE, Buffered

__all__ = ["ClosedRattle", "ClosedStep", "closed_functions"]


def _rows(system, key, t, q, H):
    """The force directions D (bilateral rows, then one normal row per closed contact with its
    sliding friction, then the sticking tangents) and the velocity-constraint rows V at (t, q)."""
    m = system.n_contacts
    mu, off = system.mu, system.tangent_offsets
    D, V = [], []
    if system.n_bilateral:
        _, G, _ = system.constraints_fn(t, q)
        D.append(G)
        V.append(G)
    for j, s, _ in key:
        D.append(H[j, :] - (mu[j] * s) * H[m + off[j], :] if s else H[j, :])
        V.append(H[j, :])
    for j, _, stick in key:
        if stick:
            D.append(H[m + off[j], :])
            V.append(H[m + off[j], :])
    return ca.vertcat(*D), ca.vertcat(*V)


def _constraints(system, key, t1, q0, q):
    """The position constraints of the step at its end point q: phi(t1, q), the closed gaps, and
    the sticking tangents' midpoint rows H_T((q0 + q)/2)(q - q0)."""
    m, off = system.n_contacts, system.tangent_offsets
    c = []
    if system.n_bilateral:
        c.append(system.constraints_fn(t1, q)[0])
    g = system.gap_fn(q)
    c += [g[j] for j, _, _ in key]
    if any(stick for _, _, stick in key):
        Hm = system.H_fn((q0 + q) / 2)
        c += [ca.mtimes(Hm[m + off[j], :], q - q0) for j, _, stick in key if stick]
    return ca.vertcat(*c)


def _newton(system, key, t1, q0, q, P, sym, iterations):
    """SHAKE's Newton iterations q <- q - P nu, (dc/dq P) nu = c(q); then (q, residual, size of each
    row's terms, the sum of the nu)."""
    qs, q0s, ts = sym.sym("qs", system.n), sym.sym("q0s", system.n), sym.sym("ts")
    cs = _constraints(system, key, ts, q0s, qs)
    cfun = ca.Function("c", [ts, q0s, qs], [cs, ca.jacobian(cs, qs)])
    nu_sum = 0
    for _ in range(iterations):
        c, Gc = cfun(t1, q0, q)
        nu = ca.solve(ca.mtimes(Gc, P), c)
        q = q - ca.mtimes(P, nu)
        nu_sum = nu_sum + nu
    c, Gc = cfun(t1, q0, q)
    return q, c, ca.mtimes(ca.fabs(Gc), ca.fabs(q) + ca.fabs(q0)), nu_sum


def _kick2(system, key, t1, q0, q1, h, sym):
    """The closing kick from v_1/2 = (q1 - q0)/h with V(q1) v1 + (phi_t, 0) = 0: (v1, the end
    multipliers mu, the gaps at q1 and their size, the tangent velocities H_T(q1) v1)."""
    n, nb, m = system.n, system.n_bilateral, system.n_contacts
    vh = (q1 - q0) / h
    A1 = system.mass_fn(t1, q1)
    F1 = system.force_fn(t1, q1, vh)
    H1 = system.H_fn(q1)
    D1, V1 = _rows(system, key, t1, q1, H1)
    r = D1.shape[0]
    rhs_v = -ca.mtimes(V1, vh)
    if nb:
        rhs_v[:nb] = rhs_v[:nb] - system.constraints_fn(t1, q1)[2]
    KKT = ca.blockcat([[A1, D1.T], [V1, sym(r, r)]])  # A1 dv + D1' x = h/2 F1: x = -h/2 mu
    sol = ca.solve(KKT, ca.vertcat(h / 2 * F1, rhs_v))
    v1 = vh + sol[:n]
    gap = system.gap_fn(q1)
    gsize = ca.mtimes(ca.fabs(H1[:m, :]), ca.fabs(q1)) + ca.fabs(gap)
    return v1, sol[n:] * (-2 / h), gap, gsize, ca.mtimes(H1[m:, :], v1)


def closed_functions(system, key):
    """(step, newton, kick) Functions of one system and one closed set ``key`` (tuples (j, s,
    stick): contact j, its sliding direction s in {-1, 0, 1} (0: frictionless or sticking), and
    whether it sticks).

    ``step(t0, q0, v0, h) -> (q1, v1, r, s, P, lam, mu, gap, gsize, uT)``;
    ``newton(t1, q0, q, P) -> (q, r, s, nu)`` (SHAKE_PER_EVAL more iterations);
    ``kick(t0, q0, q1, h) -> (v1, mu, gap, gsize, uT)``.
    """
    n = system.n
    r = system.n_bilateral + len(key) + sum(1 for *_, stick in key if stick)
    sym = ca.SX if n + r <= SX_MAX_SIZE else ca.MX
    t0, h = sym.sym("t0"), sym.sym("h")
    q0, v0 = sym.sym("q0", n), sym.sym("v0", n)
    t1 = t0 + h
    A0 = system.mass_fn(t0, q0)
    F0 = system.force_fn(t0, q0, v0)
    _, C0 = system.force_jac_fn(t0, q0, v0)
    At = A0 + h / 2 * C0
    qhat = q0 + h * (v0 + ca.solve(At, h / 2 * F0))
    D0, _ = _rows(system, key, t0, q0, system.H_fn(q0))
    P = ca.solve(At, D0.T)
    q1, res, size, nu = _newton(system, key, t1, q0, qhat, P, sym, SHAKE_PER_EVAL)
    v1, mu, gap, gsize, uT = _kick2(system, key, t1, q0, q1, h, sym)
    lam = -2 / (h * h) * nu  # q1 = qhat + h^2/2 A~^-1 D0' lambda = qhat - P sum(nu)
    dense = lambda xs: [ca.densify(x) for x in xs]  # noqa: E731 - dense buffers: one layout per output
    step = ca.Function("closed_rattle_step", [t0, q0, v0, h], dense([q1, v1, res, size, P, lam, mu, gap, gsize, uT]))
    ts, qs, Ps = sym.sym("t1"), sym.sym("q", n), sym.sym("P", n, r)
    newton = ca.Function("closed_shake_newton", [ts, q0, qs, Ps],
                         dense(_newton(system, key, ts, q0, qs, Ps, sym, SHAKE_PER_EVAL)))
    q1s = sym.sym("q1", n)
    kick = ca.Function("closed_rattle_kick", [t0, q0, q1s, h], dense(_kick2(system, key, t0 + h, q0, q1s, h, sym)))
    return step, newton, kick


@dataclass
class ClosedStep:
    """The outcome of one :class:`ClosedRattle` step.

    Attributes
    ----------
    q1, v1 : ndarray
        The end state.
    lam, mu : ndarray
        The multipliers (forces) of the first and of the closing kick: bilateral rows, then one
        normal per closed contact (the order of the key), then the sticking tangents.
    gap, gsize : ndarray
        Every contact's gap at q1 and the size of its terms.
    uT : ndarray
        Every tangent row's velocity H_T(q1) v1.
    ok : bool
        SHAKE converged within its evaluations.
    iterations : int
        SHAKE's Newton iterations.
    violation : float
        max |c_i(q1)| over the step's position constraints.
    """

    q1: np.ndarray
    v1: np.ndarray
    lam: np.ndarray
    mu: np.ndarray
    gap: np.ndarray
    gsize: np.ndarray
    uT: np.ndarray
    ok: bool
    iterations: int
    violation: float


#: system -> {key: its Buffered (step, newton, kick)}
_FUNCTIONS = weakref.WeakKeyDictionary()


class ClosedRattle:
    """RATTLE steps of a system with some contacts held closed (module docstring); the CasADi
    Functions are built once per closed set.

    Parameters
    ----------
    system : lcp.model.system.System
        A system with planar contacts whose gaps and tangents do not depend on t.
    tol : float
        Relative tolerance of SHAKE, as :class:`~lcp.timestepping.rattle.RattleStep`'s.
    max_evals : int
        SHAKE evaluations before the step is reported as not converged.

    Examples
    --------
    A point mass inside a circular bowl of radius 1, released at 60 degrees from the bottom, held
    on the bowl by its contact for one step:

    >>> import casadi as ca, math, numpy as np
    >>> from lcp.model.system import Contact, System
    >>> from lcp.timestepping.closed_rattle import ClosedRattle
    >>> q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    >>> bowl = Contact(gap=1 - ca.norm_2(q), tangent=ca.atan2(q[0], -q[1]), name="bowl")
    >>> s = System(q, v, ca.SX.eye(2), ca.vertcat(0, -9.81), contacts=[bowl])
    >>> out = ClosedRattle(s)(((0, 0, False),), 0.0, np.array([math.sin(1.0), -math.cos(1.0)]), np.zeros(2), 1e-2)
    >>> out.ok, round(float(np.hypot(*out.q1)), 14), bool(out.lam[0] > 0 and out.mu[0] > 0)
    (True, 1.0, True)
    """

    def __init__(self, system, tol: float = 1e-12, max_evals: int = 8):
        self.system = system
        self.tol, self.max_evals = float(tol), int(max_evals)
        self.fns = _FUNCTIONS.setdefault(system, {})

    def __call__(self, key, t: float, q: np.ndarray, v: np.ndarray, h: float) -> ClosedStep:
        """The step from (t, q, v) with the contacts of ``key`` (see :func:`closed_functions`) held."""
        fns = self.fns.get(key)
        if fns is None:
            fns = self.fns[key] = tuple(Buffered(f) for f in closed_functions(self.system, key))
        step, newton, kick = fns
        q1, v1, r, s, P, lam, mu, gap, gsize, uT = step(t, q, v, h)
        evals = 1
        while not np.all(np.abs(r) <= self.tol * s):
            if evals >= self.max_evals or not np.all(np.isfinite(r)):
                return ClosedStep(q1, v1, lam, mu, gap, gsize, uT, False, evals * SHAKE_PER_EVAL,
                                  float(np.max(np.abs(r))))
            q1, r, s, nu = newton(t + h, q, q1, P)
            lam = lam - 2 / (h * h) * nu
            evals += 1
        if evals > 1:  # the closing kick at the converged positions
            v1, mu, gap, gsize, uT = kick(t, q, q1, h)
        return ClosedStep(q1, v1, lam, mu, gap, gsize, uT, True, evals * SHAKE_PER_EVAL,
                          float(np.max(np.abs(r))) if r.size else 0.0)
