"""Smooth phases of a constant system under a force affine in t: cubic positions, exact events.

A system that is constant apart from a scheduled control force (:mod:`lcp.events.forcing`) has,
between two breakpoints of its schedule, the force F(t) = F(t0) + F' (t - t0). With the contact
modes fixed, the accelerations and the contact forces are linear in the force (the branch of the
acceleration-level problem is a linear system), so over a phase

    qdd(t) = qdd0 + qdd1 dt,   (N, f)(t) = (N0, f0) + (N1, f1) dt,   dt = t - t0,

velocities are quadratic and positions cubic in dt. Every event is the first root of a polynomial
(:func:`~lcp.events.event_location.first_descent`): a stop (a sliding velocity, quadratic), a
lift-off (a normal force, linear), a slip (a stick force reaching the friction bound, mu N -+ f,
linear) and a landing (a gap, cubic). Nothing here calls CasADi or an ODE solver.
"""
from __future__ import annotations

import math

import numpy as np

from lcp.contact.problem import ContactProblem
from lcp.events.event_location import first_descent
from lcp.events.model import EPS, coordinate_rows, mass_projection
from lcp.events.modes import AccelProblem
from lcp.events.phases import SmoothPhase

__all__ = ["CubicPhase"]


class CubicPhase(SmoothPhase):
    """q = q0 + v0 dt + qdd0 dt^2/2 + qdd1 dt^3/6 with forces affine in dt; events are polynomial roots.

    ``start`` = (qdd, N, f) of the phase's closed contacts at t0, when known; by default solved
    here (the mode decision's solution may come from a look ahead, at a later time, where the
    forces differ); ``force_tol``: a force that starts within it of its bound ends the
    phase only when it passes the bound by as much (as in :func:`~lcp.events.event_location.event_functions`).
    """

    integrator = "closed-form"
    nfev = 0

    def __init__(self, *args, start=None, force_tol: float = 0.0):
        super().__init__(*args)
        model = self.model
        self.force_tol = force_tol
        F1 = model.forcing.affine(self.t0)[1]
        data = model.data(self.t0, self.q0, self.v0)
        k = self.idx.size
        # the rates: the same branch, with the force's rate as the only load
        s1 = data.solve_dirs(F1[:, None])[:, 0]
        if k:
            acc = AccelProblem(data, self.idx, self.slide, self.mu)
            if start is not None:
                self.qdd, N, f = start
            else:
                p0 = acc.pb.solve_branch(acc.branch_modes(self.modes))
                if p0 is None:
                    raise FloatingPointError("singular contact branch in a smooth phase")
                N, f = acc.forces(p0)
                self.qdd = acc.qdd(p0)
            rows = np.concatenate([self.idx, model.m + self.idx])
            pb = ContactProblem(acc.pb.W, model.H[rows] @ s1, acc.pb.mu)
            p1 = pb.solve_branch(acc.branch_modes(self.modes))
            if p1 is None:
                raise FloatingPointError("singular contact branch in a smooth phase")
            self.qdd1 = s1 + acc.SD @ p1
            N1, f1 = acc.forces(p1)
        else:
            self.qdd = data.qdd_free if start is None else start[0]
            N, f = np.zeros(0), np.zeros(0)
            self.qdd1, N1, f1 = s1, np.zeros(0), np.zeros(0)
        # the phase's constraints hold at the acceleration level up to rounding; one mass-metric
        # projection of both coefficients keeps them over long phases (as in ClosedFormPhase)
        J = np.vstack([model.G, model.H[self.idx], model.H[model.m + self.idx[self.slide == 0]]])
        qdd = np.array(self.qdd, dtype=float)
        if J.shape[0]:
            qdd = qdd - mass_projection(model.A, J, J @ qdd)
            self.qdd1 = self.qdd1 - mass_projection(model.A, J, J @ self.qdd1)
            for i, val in coordinate_rows(J, np.zeros(J.shape[0])):
                qdd[i] = val
                self.qdd1[i] = val
        self.qdd = qdd
        m = model.m
        self.N, self.f = np.zeros(m), np.zeros(m)
        self.N1, self.f1 = np.zeros(m), np.zeros(m)
        self.N[self.idx], self.f[self.idx] = N, f
        self.N1[self.idx], self.f1[self.idx] = N1, f1
        self.NF = np.concatenate([self.N, self.f])
        self.NF1 = np.concatenate([self.N1, self.f1])

    def _force_event(self, g0: float, g1: float, T: float) -> float:
        """First time the affine force margin g0 + g1 dt falls to zero (-force_tol if it starts on it)."""
        if abs(g0) <= self.force_tol:
            g0 += self.force_tol
        return first_descent((g0, g1), T)

    def run(self, t_stop, breakpoint=False):
        """First event before t_stop: (t_event, kind, contact) or None (the phase then ends at
        t_stop, where a breakpoint changes the force's slope or value)."""
        model, H = self.model, self.model.H
        T = t_stop - self.t0
        best = (math.inf, None, -1)
        v0, a0, a1 = self.v0, self.qdd, self.qdd1
        for jj, j in enumerate(self.idx.tolist()):
            s = float(self.slide[jj])
            if s != 0.0:
                row = H[model.m + j]
                dt = first_descent((s * float(row @ v0), s * float(row @ a0), 0.5 * s * float(row @ a1)), T)
                if dt < best[0]:
                    best = (dt, "stop", j)
            dt_lift = self._force_event(float(self.N[j]), float(self.N1[j]), T)
            if dt_lift < best[0]:
                best = (dt_lift, "lift-off", j)
            if s == 0.0:
                mu = float(self.mu[j])
                for sign in (1.0, -1.0):
                    dt = self._force_event(mu * float(self.N[j]) - sign * float(self.f[j]),
                                           mu * float(self.N1[j]) - sign * float(self.f1[j]), T)
                    # the friction bound reached with the normal force (both vanish): a lift-off
                    if dt < best[0] and not math.isclose(dt, dt_lift, rel_tol=1e-12):
                        best = (dt, "slip", j)
        if len(self.open_idx):
            gap = model.gaps(self.q0)
            # a gap at the rounding level of its own evaluation is zero (a contact just left)
            noise = 8 * EPS * (np.abs(model.gap0) + np.abs(model.HN) @ np.abs(self.q0))
            for j in self.open_idx.tolist():
                g0 = float(gap[j]) if abs(gap[j]) > noise[j] else 0.0
                row = H[j]
                dt = first_descent((g0, float(row @ v0), 0.5 * float(row @ a0), float(row @ a1) / 6.0), T)
                if dt < best[0]:
                    best = (dt, "impact", j)
        return self.end_at(best, t_stop)

    def end_acceleration(self):
        return self.qdd + (self.t1 - self.t0) * self.qdd1

    def end_state(self):
        dt = self.t1 - self.t0
        h = 0.5 * dt
        v1 = self.v0 + dt * (self.qdd + h * self.qdd1)
        q1 = self.q0 + dt * (self.v0 + h * (self.qdd + (dt / 3.0) * self.qdd1))
        return q1, v1, self.P0 + dt * (self.NF + h * self.NF1)

    def output(self, t, out):
        """Write (q, v, cumulative impulses) at the times t into the columns of ``out`` (shape
        (2n + 2m, t.size)); return the forces (N, f) at those times, shape (t.size, m) each."""
        n = self.q0.size
        dt = np.asarray(t, dtype=float) - self.t0
        h = 0.5 * dt
        q0, v0, a0, a1 = (x[:, None] for x in (self.q0, self.v0, self.qdd, self.qdd1))
        out[:n] = q0 + dt * (v0 + h * (a0 + (dt / 3.0) * a1))
        out[n:2 * n] = v0 + dt * (a0 + h * a1)
        out[2 * n:] = self.P0[:, None] + dt * (self.NF[:, None] + h * self.NF1[:, None])
        return self.N + dt[:, None] * self.N1, self.f + dt[:, None] * self.f1
