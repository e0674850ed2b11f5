"""Impact laws of the event integrator: the velocity-level problem solved at an impulse.

When a gap closes with approach velocity, or when the acceleration-level problem has no solution
or several (the Painleve cases: kappa >= 1 in the Jean-Pratt scene), the integrator applies an
impulse: the solution of the velocity-level problem ContactProblem(W, H_c v + e u_N, mu), the
problem Moreau-Jean solves in the limit h -> 0+ (Newton restitution on the normal velocity, as in
the Moreau-Jean step). Its trivial solution (no impulse) is excluded by taking the branch that
Moreau-Jean's problem selects for a vanishing step (free velocity H_c v + delta b with delta -> 0+)
and re-solving that branch at delta = 0.
"""
from __future__ import annotations

import numpy as np

from lcp.contact.problem import ContactProblem
from lcp.contact.solvers import make_solver
from lcp.events.indeterminate import branch_forces

__all__ = ["ImpactLaw"]


class ImpactLaw:
    """Newton restitution and Coulomb friction at the velocity level, for one integration."""

    def __init__(self, model, mu, e, stats, solver_name, t_end):
        self.model, self.mu, self.e, self.stats = model, mu, e, stats
        self.m = model.m
        self.solver_name, self.t_end = solver_name, t_end
        self._solver = None

    @property
    def solver(self):
        """The one-step solver of the velocity-level impact problems (built on first use)."""
        if self._solver is None:
            self._solver = make_solver(self.solver_name)
        return self._solver

    def solve(self, t, q, v, contacts, data):
        """Velocity-level impact problem on ``contacts``; returns (dv, p, modes) or None."""
        m = self.m
        idx = np.asarray(contacts, dtype=int)
        k = idx.size
        key = idx.tobytes()
        cached = self.model.impact_memo.get(key) if self.model.polynomial else None
        if cached is None:
            rows = np.concatenate([idx, m + idx])
            Hc = data.H[rows]
            SH = data.solve_dirs(Hc.T)
            W = Hc @ SH
            b = Hc @ data.qdd_free + data.Hdv[rows]
            cached = (Hc, SH, W, b)
            if self.model.polynomial:  # nothing here depends on the state
                for arr in cached:
                    arr.setflags(write=False)
                self.model.impact_memo[key] = cached
        Hc, SH, W, b = cached
        u = Hc @ v
        if self.model.moving:  # the relative velocity on a moving contact: u = H v + (dg/dt, ds/dt)
            u = u + self.model.sys.contact_rates(q, t)[np.concatenate([idx, m + idx])]
        qv = u.copy()
        # Newton restitution on the approaching contacts, as in the Moreau-Jean step: a separating
        # contact only must not approach (u_N+ >= 0); restitution would pull it back
        qv[:k] += self.e[idx] * np.minimum(u[:k], 0.0)
        # Moreau-Jean's problem for a vanishing step h = delta: free velocity u + delta b
        umax, bmax = float(np.max(np.abs(qv))), float(np.max(np.abs(b)))
        delta = 1e-8 * (umax / bmax if umax > 0 and bmax > 0 else self.t_end)
        pb_d = ContactProblem(W, qv + delta * b, self.mu[idx])
        sol = self.solver.solve(pb_d)
        self.stats.solver_calls += 1
        self.stats.iterations += sol.iterations
        self.stats.qp_solves += sol.qp_solves
        if not sol.success:
            return None
        modes = pb_d.modes(sol.p)
        pb0 = ContactProblem(W, qv, self.mu[idx])
        p = pb0.solve_branch(modes) if idx.size == 1 else None
        if p is None or not pb0.admissible(p, modes):
            # several contacts (possibly redundant: two corners landing flat), or a singular
            # branch: its least-norm admissible impulses, else the vanishing-step solution
            bf = branch_forces(pb0, modes, modes)
            p = bf.p if bf is not None and bf.admissible else sol.p
        self.stats.max_residual = max(self.stats.max_residual, pb0.residual(p))
        return SH @ p, p, modes

