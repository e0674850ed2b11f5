"""The event-driven integrator for systems with spatial contacts (the Coulomb disk).

Between events every closed contact sticks or slides, and the motion is smooth. A sliding contact
j carries its **signed sliding speed** s_j as an extra state with s_j' = d_j . U_j', and its
friction direction is d_j = sign(s_j) U_j / |U_j| (U_j the sliding velocity): U_j / |U_j| while
s_j > 0, with a sign that continues smoothly through zero, where U_j and s_j change sign together.
(The quotient U_j / s_j would do the same in exact arithmetic, but its length drifts from 1 and
the drift grows like 1 / s_j^2 toward the stop.) The phase's equations are then smooth through the stop,
and the stop is the simple sign change s_j = 0, located by root finding on the dense output of
SciPy's ``solve_ivp`` (DOP853, rtol 1e-13 and atol 1e-16 of the scene's scales by default here). A phase that starts sliding from rest
has s_j = 0 and U_j = 0; its direction d_j is then the one the mode decision found, until the
motion defines it. The drift between s_j and |U_j| is checked at the end of each phase
(``stats``-like note in the message when it exceeds 1e-8 of the velocity scale).

Where the law allows, a phase is a quadratic in closed form instead
(:mod:`lcp.events.spatial_closed_form`, integrator ``"closed-form"``): in a constant system (constant
mass matrix, kinematics and forces), a straight slide (one closed contact, sliding, its tangential
acceleration parallel to U to rounding, so that d and the friction force stay constant; the stop
t0 + |U| / (-d . a_T) is exact) and a rest of sticking contacts. A curved slide stays numerical.

The normal forces (and the sticking contacts' friction) come from the acceleration-level equations
of the closed contacts at each evaluation: one small linear solve
(:meth:`~lcp.events.spatial_modes.SpatialModel.phase_accel`; for constant mass matrix and
kinematics the inverse mass matrix and S H' are assembled once).

Events: a stop (s_j = 0), a lift-off (N_j = 0), a slip (|f_j| = mu_j N_j), a gap closing (impact:
the velocity-level disk problem with Newton restitution), a breakpoint of the forces. A sliding
contact whose direction turns into the Painleve region (its effective normal mass
H_N S (H_N' - mu H_T' d) falls to zero, so N grows without bound: the Jean-Pratt block launched
obliquely with kappa >= 1) ends the run with status -3 and the time in the message, when that mass
has fallen to 1e-6 of its two terms (``"painleve"`` event).

At each event the next modes come from the acceleration-level disk problem
(:class:`~lcp.events.spatial_modes.AccelDisk`): a contact at rest sticks if that is admissible, else
slides along its tangential acceleration (a_T = lambda d, lambda > 0: d is the new slip
direction), or opens. At a slip event the contact that reached its friction bound slides (its
direction is opposite to the friction force on the bound, the limit of the sliding solution).
When the problem has no solution or several (Painleve), the impulsive fallback applies: the
velocity-level problem of a vanishing Moreau-Jean step; if it gives a sticking impulse it is
applied (a tangential impact), otherwise the run stops with status -3 and the time in the message.
With several closed contacts the problem is solved by nonsmooth Gauss-Seidel (one solution, no
uniqueness check).

The result is an :class:`~lcp.events.records.EventResult`; ``p_T`` and ``force_T`` have one column
per tangent row (``system.tangent_offsets``), and an impulse's ``P_T`` is the array of its tangent
components for a spatial contact.
"""
from __future__ import annotations

import math

import numpy as np

from lcp.contact.problem import MODE_NAMES, OPEN, SLIDE, SLIDE_NEG, SLIDE_POS, STICK
from lcp.result import SolverStats
from lcp.events.accumulation import BounceSequence
from lcp.events.event_location import approach_gap, first_terminal_event, too_many_events
from lcp.events.kinematic_ode import normalising_method
from lcp.events.model import EPS, coordinate_rows, mass_projection
from lcp.events.options import CASCADE_ROUNDS, EVENT_STATUS_MESSAGES, cascade_round
from lcp.events.records import Event, EventResult, Impact, Impulse, Phase
from lcp.events.spatial_accumulation import watch_bounces
from lcp.events.spatial_closed_form import straight_slide
from lcp.model.start import consistent_start
from lcp.events.spatial_modes import AccelDisk, SpatialModel, group_motions, impact_impulse

__all__ = ["SpatialIntegrator", "SpatialPhase", "spatial_event_driven"]

#: default relative tolerance of the smooth phases (tighter than the planar integrator's)
SPATIAL_RTOL = 1e-13
#: default absolute tolerance, relative to the scene's scales: a velocity component that tends to
#: zero (the cross-slope velocity on an incline) must still be integrated to rtol of the motion
SPATIAL_ATOL = 1e-16
#: a sliding contact whose relative effective normal mass (:meth:`SpatialPhase.normal_mass`) falls
#: to this value is reported as reaching the Painleve singularity (status -3)
PAINLEVE_MARGIN = 1e-6
_EXPLICIT = ("DOP853", "RK45", "RK23")
#: a slide from rest keeps its initial direction over this fraction of the scene's time scale
FROZEN_START = 1e-6
#: a rigid body's slide from rest keeps its decided direction until it slides at this fraction of
#: the velocity scale (:meth:`SpatialPhase._run_kinematic_from_rest`)
FROZEN_SPEED = 1e-6
#: right-hand side evaluations allowed in one phase of a system with kinematics before it ends
#: with status -2 (a phase that cannot be integrated at its tolerances is said, not run for ever)
MAX_PHASE_EVALUATIONS = 200_000


class Inconsistent(Exception):
    """No motion can be continued from the current state (status -3)."""


def _scales(model, q0, v0, t_end):
    """Scales of the zero tests (as :func:`lcp.events.model.zero_test_scales`)."""
    fr = model.frame(0.0, q0, v0)
    n = model.n
    acc = float(np.max(np.abs(fr.qdd_free))) if n else 0.0
    A_max = float(np.max(np.abs(fr.A)))
    V0, L0 = float(np.max(np.abs(v0))), float(np.max(np.abs(q0)))
    T = t_end
    if acc > 0:
        T_own = 100.0 * max(math.sqrt(L0 / acc), V0 / acc)
        T = min(t_end, T_own) if T_own > 0 else t_end
    V = max(V0, acc * T, 1e-300)
    return {"V": V, "L": max(V * T, L0, 1e-300), "A": max(acc, V / T), "P": max(A_max * V, 1e-300),
            "F": max(A_max * max(acc, V / T), 1e-300)}


class SpatialPhase:
    """One smooth phase: closed contacts ``idx`` with modes (STICK or a slide) and the sliding
    directions at its start; y = (q, v, cumulative forces (m normals, then the tangent rows),
    signed sliding speeds)."""

    def __init__(self, integ, t0, q0, v0, P0, idx, modes, dirs):
        self.integ = integ
        model = self.model = integ.model
        self.t0, self.q0, self.v0, self.P0 = t0, q0, v0, P0
        self.idx = list(idx)
        self.modes = list(modes)
        self.stick = [md == STICK for md in modes]
        self.slide = [i for i, md in enumerate(modes) if md != STICK]
        self.d0 = [None if self.stick[i] else np.asarray(dirs[i], dtype=float) for i in range(len(idx))]
        m = model.m
        full = np.full(m, OPEN, dtype=np.int8)
        for j, md in zip(self.idx, self.modes):
            full[j] = md
        self.full_modes = full
        self._names = tuple(MODE_NAMES[int(c)] for c in full)
        self.open_idx = [j for j in range(m) if j not in set(self.idx)]
        H = model.jac(q0, t0)
        b = model.sys.contact_rates(q0, t0) if model.moving else None  # u = H v + b on a moving contact
        s0 = []
        for i in self.slide:
            tr = model.trows[self.idx[i]]
            U = H[tr] @ v0 if b is None else H[tr] @ v0 + b[tr]
            if model.kinematic and math.hypot(*U.tolist()) <= integ.vel_tol:
                # at rest to the zero test (a rigid body's corner after a stick: rounding-level U
                # that no coordinate snap zeroes): a slide from rest along the decided direction,
                # not along the direction of rounding
                U = np.zeros_like(U)
            s0.append(float(U @ self.d0[i]))
        self.s0 = np.array(s0)
        # A slide from rest starts at s = 0 with s' = 0 at a slip (the force on its bound), and
        # rounding may dip s below zero at once: its stop (and the sign of its direction) is
        # a fall below -1e-3 of the velocity zero test.
        self.s_off = np.where(self.s0 == 0.0, 1e-3 * integ.vel_tol, 0.0)
        self.from_rest = bool(np.any(self.s0 == 0.0))
        self.frozen = False
        self.o = integ.o
        self.integrator = integ.o.ode_method
        self.nfev = 0
        self._key = None
        self.t_left = np.inf
        self.closed = None

    def names(self):
        return self._names

    def evaluate(self, t, y):
        """(ydot, N (m), f (n_tangent)) at (t, y), cached per point."""
        key = (t, y.tobytes())
        if key == self._key:
            return self._cache
        model = self.model
        n, m, nq = model.n, model.m, model.nq
        q, v = y[:nq], y[nq:nq + n]
        ns = len(self.slide)
        s = y[y.size - ns:] if ns else y[:0]
        fr = model.frame(min(t, self.t_left), q, v)
        dirs = list(self.d0)
        for k_, i in enumerate([] if self.frozen else self.slide):
            U = fr.velocity(v, model.trows[self.idx[i]])
            nU = math.hypot(*U.tolist())
            if nU != 0.0:
                # U/|U| with the sign of s: continuous through the stop (U and s change sign
                # together), and of unit length (U/s drifts off it, unstably as s -> 0)
                dirs[i] = U / (nU if s[k_] >= -self.s_off[k_] else -nU)
        qdd, N, f_st, _ = model.phase_accel(fr, self.idx, self.stick, dirs)
        Nm = np.zeros(m)
        fm = np.zeros(model.H_rows - m)
        sdot = np.empty(ns)
        fi = 0
        for i, j in enumerate(self.idx):
            Nm[j] = N[i]
        for i, j in enumerate(self.idx):
            tr = model.trows[j]
            if self.stick[i]:
                fm[tr - m] = f_st[fi:fi + tr.size]
                fi += tr.size
            else:
                fm[tr - m] = -model.mu[j] * N[i] * dirs[i]
        for k_, i in enumerate(self.slide):
            tr = model.trows[self.idx[i]]
            aT = fr.H[tr] @ qdd + fr.Hdv[tr]
            sdot[k_] = float(dirs[i] @ aT)
        out = (np.concatenate([model.qdot(min(t, self.t_left), q, v), qdd, Nm, fm, sdot]), Nm, fm)
        self._key, self._cache = key, out
        return out

    def _rhs(self, t, y):
        if self.model.kinematic:
            self.n_rhs = getattr(self, "n_rhs", 0) + 1
            if self.n_rhs > MAX_PHASE_EVALUATIONS:
                raise FloatingPointError(f"the phase with modes {self.names()} needed more than "
                                         f"{MAX_PHASE_EVALUATIONS} evaluations by t = {t:.17g} (its step size "
                                         "collapsed: a slide the integrator cannot follow at its tolerances)")
        return self.evaluate(t, y)[0]

    def _events(self, y0):
        model, n, m = self.model, self.model.n, self.model.m
        force_tol = self.o.tol * self.integ.scales["F"]
        evs, meta = [], []
        ev = self.evaluate

        def make(fun, kind, j, force=False):
            if force and force_tol > 0 and abs(fun(self.t0, y0)) <= force_tol:
                inner = fun

                def fun(t, y):
                    return inner(t, y) + force_tol
            fun.terminal, fun.direction = True, -1
            evs.append(fun)
            meta.append((kind, int(j)))

        base = y0.size - len(self.slide)
        for k_, i in enumerate(self.slide):
            make(lambda t, y, c=base + k_, off=self.s_off[k_]: float(y[c]) + off, "stop", self.idx[i])
        for i, j in enumerate(self.idx):
            make(lambda t, y, j=j: float(ev(t, y)[1][j]), "lift-off", j, force=True)
            if self.stick[i]:
                tr, mu = model.trows[j] - m, model.mu[j]
                make(lambda t, y, j=j, tr=tr, mu=mu: float(mu * ev(t, y)[1][j] - np.linalg.norm(ev(t, y)[2][tr])),
                     "slip", j, force=True)
        for k_, i in enumerate(self.slide):
            make(lambda t, y, i=i: self.normal_mass(t, y, i) - PAINLEVE_MARGIN, "painleve", self.idx[i])
        for j in self.open_idx:
            make(lambda t, y, j=j: approach_gap(model, y, n, j, t), "impact", j)
        return evs, meta

    def normal_mass(self, t, y, i):
        """H_N,j S (H_N,j' - mu_j H_T,j' d_j) / (|H_N,j S H_N,j'| + mu_j |H_N,j S H_T,j' d_j|) of sliding
        contact i: 1 without friction coupling, 0 at the Painleve singularity (N_j -> inf)."""
        model, n, nq = self.model, self.model.n, self.model.nq
        q, v = y[:nq], y[nq:nq + n]
        fr = model.frame(min(t, self.t_left), q, v)
        j = self.idx[i]
        tr = model.trows[j]
        U = fr.velocity(v, tr)
        nU = math.hypot(*U.tolist())
        d = self.d0[i] if nU == 0.0 else U / nU
        a = float(fr.H[j] @ fr.SH[:, j])
        c = model.mu[j] * float(fr.H[j] @ (fr.SH[:, tr] @ d))
        ref = abs(a) + abs(c)
        return (a - c) / ref if ref > 0 else 1.0

    def run(self, t_stop, breakpoint=False):
        """Integrate to the first event before t_stop: (t, kind, contact) or None."""

        if breakpoint:
            self.t_left = float(np.nextafter(t_stop, -np.inf))
        cf = straight_slide(self, self.o.tol * self.integ.scales["F"], PAINLEVE_MARGIN)
        if cf is not None:
            return self._closed_form(cf, t_stop)
        n, nq = self.model.n, self.model.nq
        y0 = np.concatenate([self.q0, self.v0, self.P0, self.s0])
        evs, meta = self._events(y0)
        o, sc = self.o, self.integ.scales
        a = self.integ.atol
        atol = np.concatenate([np.full(nq, a * sc["L"]), np.full(n, a * sc["V"]),
                               np.full(self.P0.size, a * sc["P"]), np.full(self.s0.size, a * sc["V"])])
        method, rtol = o.ode_method, self.integ.rtol
        self.segments = []
        t_start = self.t0
        if self.from_rest and method in _EXPLICIT:
            # Sliding from rest: the direction's transverse dynamics has the rate mu N / (m |U|),
            # unbounded while |U| grows from 0 (no explicit method follows it stably), and U/|U|
            # jumps at U = 0 (no Newton iteration of an implicit one converges there). The first
            # FROZEN_START of the scene's time scale slides along the decided direction; Radau
            # continues with U/|U|.
            if self.model.kinematic:
                return self._run_kinematic_from_rest(t_stop, y0, method, rtol, atol, evs, meta)
            t_fr = min(t_stop, self.t0 + FROZEN_START * self.integ.scales["L"] / self.integ.scales["V"])
            self.frozen = True
            out = self._solve(t_start, t_fr, y0, method, rtol, atol, evs, meta)
            self.frozen = False
            if out is not None or t_fr >= t_stop:
                return out
            t_start, y0 = t_fr, self.y1
            method, rtol = "Radau", max(rtol, 1000 * EPS)
            self.integrator = f"{o.ode_method}+Radau"
        return self._solve(t_start, t_stop, y0, method, rtol, atol, evs, meta)

    def _run_kinematic_from_rest(self, t_stop, y0, method, rtol, atol, evs, meta):
        """A slide from rest of a system with Newton-Euler kinematics (a rigid body's corner that
        slips): at a slip the tangential acceleration is zero (the stick force reaches its bound
        continuously), so |U| grows like t^2 and U/|U| is set by rounding at first. The decided
        direction is held until the fastest such contact slides at FROZEN_SPEED of the velocity
        scale (an event), then the phase continues with U/|U| by the same explicit method (the
        transverse rate mu N / (m |U|) falls as |U| grows, and an explicit step grows with it)."""
        model, thr = self.model, FROZEN_SPEED * self.integ.scales["V"]
        rows = [model.trows[self.idx[i]] for k_, i in enumerate(self.slide) if self.s0[k_] == 0.0]
        nq, n = model.nq, model.n

        def speed(t, y):
            fr_v = model.local_velocity(min(t, self.t_left), y[:nq], y[nq:nq + n])
            return thr - max(math.hypot(*fr_v[tr].tolist()) for tr in rows)

        speed.terminal, speed.direction = True, -1
        self.frozen = True
        out = self._solve(self.t0, t_stop, y0, method, rtol, atol, evs + [speed], meta + [("unfreeze", -1)])
        self.frozen = False
        if out is None or out[1] != "unfreeze":
            return out
        self.integrator = f"{self.o.ode_method}+{self.o.ode_method}"
        # the sliding speeds restart from |U|: while the direction was held, s followed d0 . U,
        # which lags |U| by the angle between them (the stop is located on s)
        y1 = self.y1.copy()
        u = model.local_velocity(min(out[0], self.t_left), y1[:nq], y1[nq:nq + n])
        base = y1.size - len(self.slide)
        for k_, i in enumerate(self.slide):
            y1[base + k_] = math.copysign(math.hypot(*u[model.trows[self.idx[i]]].tolist()), y1[base + k_])
        return self._solve(out[0], t_stop, y1, method, rtol, atol, evs, meta)

    def _closed_form(self, cf, t_stop):
        """A straight slide (:mod:`lcp.events.spatial_closed_form`): the quadratic to t_stop or to
        its stop, which is exact (s = 0 there)."""
        self.closed, self.integrator = cf, "closed-form"
        self.segments = [(self.t0, cf)]
        if cf.t_stop < t_stop:
            self.t1 = cf.t_stop
            self.y1 = cf.sol(cf.t_stop)
            self.y1[-1] = 0.0
            return self.t1, "stop", self.idx[0]
        self.t1, self.y1 = t_stop, cf.sol(t_stop)
        return None

    def _solve(self, ta, tb, y0, method, rtol, atol, evs, meta):
        from scipy.integrate import solve_ivp

        if self.model.kinematic:  # unit quaternions renormalised after every accepted step
            method = normalising_method(self.model.sys, method)
        sol = solve_ivp(self._rhs, (ta, tb), y0, method=method, rtol=rtol, atol=atol, events=evs,
                        dense_output=True)
        self.nfev += sol.nfev
        self.segments.append((ta, sol))
        self.sol = sol
        if sol.status < 0:
            raise FloatingPointError(f"solve_ivp ({method}) failed at t = {sol.t[-1]:.10g}: {sol.message}")
        self.y1 = sol.y[:, -1]
        if sol.status == 1:
            self.t1, self.y1, kind, j = first_terminal_event(sol, meta)
            self.model.normalize(self.y1[:self.model.nq])
            return self.t1, kind, j
        self.t1 = tb
        return None

    def speed_drift(self) -> float:
        """max_j | |s_j| - |U_j| | at the end of the phase (the extra states' consistency)."""
        if not self.slide:
            return 0.0
        model, n, nq = self.model, self.model.n, self.model.nq
        y = self.y1
        u = model.local_velocity(self.t1, y[:nq], y[nq:nq + n])
        s = y[y.size - len(self.slide):]
        return max(abs(abs(float(s[k_])) - float(np.linalg.norm(u[model.trows[self.idx[i]]])))
                   for k_, i in enumerate(self.slide))

    def end_state(self):
        n, nq = self.model.n, self.model.nq
        y = self.y1
        return y[:nq].copy(), y[nq:nq + n].copy(), y[nq + n:nq + n + self.model.H_rows].copy()

    def output(self, t, out):
        """Write (q, v, cumulative forces) at the times t into ``out``; return (N, f) there."""
        model = self.model
        r = out.shape[0]
        Y = np.zeros((self.y1.size, t.size))
        starts = [ta for ta, _ in self.segments]
        seg = np.searchsorted(starts, t, "right") - 1
        for i, (_, sol) in enumerate(self.segments):
            sel = np.flatnonzero(np.maximum(seg, 0) == i)
            if sel.size:
                Y[:, sel] = sol.sol(t[sel])
        out[:] = Y[:r]
        if model.kinematic:
            for i in range(t.size):
                model.normalize(out[:model.nq, i])
        N = np.zeros((t.size, model.m))
        f = np.zeros((t.size, model.H_rows - model.m))
        if self.closed is not None:
            N[:], f[:] = self.closed.N, self.closed.f
            return N, f
        for i in range(t.size):
            _, N[i], f[i] = self.evaluate(float(t[i]), Y[:, i])
        return N, f


class SpatialIntegrator:
    """One event-driven integration of a System with spatial contacts over [0, t_end]."""

    def __init__(self, system, q0, v0, t_end, options, rtol, atol):
        self.sys = system
        self.model = model = SpatialModel(system)
        model.H_rows = system.n_contact_rows
        self.o, self.rtol, self.atol, self.t_end = options, rtol, atol, t_end
        self.m = system.n_contacts
        self.stats = SolverStats()
        self.events, self.impulses, self.phases, self.impact_list = [], [], [], []
        self.notes = []
        self.scales = _scales(model, q0, v0, t_end)
        self.vel_tol = options.tol * self.scales["V"]
        self.gap_tol = options.tol * self.scales["L"]
        bp = np.asarray(getattr(system, "breakpoints", []), dtype=float).ravel()
        self.breakpoints = np.unique(bp[(bp > 0) & (bp < t_end)]).tolist()
        self.max_drift = 0.0
        self.bounces, self.accumulations = BounceSequence(), []
        self.penetrated = False
        self.nonunique = 0  # phases of redundant contacts (least-norm forces)

    # ------------------------------------------------------------------ decisions
    def record_impulse(self, t, contacts, P, kind, reason):
        model, k = self.model, len(contacts)
        off = 0
        for i, j in enumerate(contacts):
            d = int(model.dims[j])
            pT = P[k + off:k + off + d]
            off += d
            pT_out = float(pT[0]) if d == 1 else pT.copy()
            if P[i] != 0.0 or np.any(pT != 0.0):
                self.impulses.append(Impulse(float(t), int(j), float(P[i]), pT_out, kind, reason))
                if kind == "impact":
                    self.impact_list.append(Impact(float(t), int(j), self.sys.contacts[j].name, float(P[i]), pT_out))
        if not (self.events and self.events[-1].t == t and self.events[-1].kind == kind):
            self.events.append(Event(float(t), kind, int(contacts[0]) if k == 1 else -1))

    def decide(self, t, q, v, last):
        """Impulses where needed, then the next modes: (v, closed contacts kept, modes, dirs)."""
        model, m = self.model, self.m
        rounds = tangential = 0
        while True:
            fr = model.frame(t, q, v)
            ul = fr.velocity(v)
            gtol, vtol = self.gap_tol, self.vel_tol
            closed, approaching, separating = [], [], []
            for j in range(m):
                if fr.gap[j] <= gtol:
                    if abs(ul[j]) <= vtol:
                        closed.append(j)
                    elif ul[j] < -vtol:
                        approaching.append(j)
                    else:
                        separating.append(j)
            if approaching:
                # a cascade goes round by round, as in the planar integrator (lcp.events.integrator)
                rounds += 1
                at, why = cascade_round(rounds, CASCADE_ROUNDS, t, closed, approaching, separating, self.notes)
                if at is None:
                    raise Inconsistent(why)
                out = impact_impulse(model, fr, v, at)
                self.stats.solver_calls += 1
                if out is None:
                    raise Inconsistent(f"the impact problem at t = {t:.17g} has no solution")
                dv, P, _ = out
                v = v + dv
                self.record_impulse(t, at, P, "impact", why)
                continue
            if not closed:
                return v, [], [], []
            dirs = []
            for j in closed:
                U = ul[model.trows[j]]
                nU = float(np.linalg.norm(U))
                dirs.append(U / nU if nU > vtol else None)
            acc = AccelDisk(model, fr, closed, dirs)
            sols = acc.solutions()
            self.stats.solver_calls += 1
            groups = group_motions(sols, self.scales["A"])
            if len(groups) == 1:
                sol = self._pick(groups[0], acc, last)
                keep = [i for i, md in enumerate(sol.modes) if md != OPEN]
                return v, [closed[i] for i in keep], [sol.modes[i] for i in keep], [sol.dirs[i] for i in keep]
            self.stats.ambiguous_steps += 1
            why = ("no consistent contact mode (Painleve: no solution)" if not groups else
                   f"{len(groups)} consistent contact modes (Painleve: non-uniqueness)")
            if acc.k > 1 and not groups:
                raise Inconsistent(f"at t = {t:.17g}: the acceleration-level problem of {acc.k} contacts was "
                                   "not solved")
            out = impact_impulse(model, fr, v, closed, restitution=False, delta_b=True)
            if out is not None and np.max(np.abs(out[1])) > 1e-12 * self.scales["P"]:
                tangential += 1
                if tangential > 8:
                    raise Inconsistent(f"at t = {t:.17g}: impulses did not lead to a consistent contact mode")
                self.stats.fallbacks += 1
                dv, P, _ = out
                v = v + dv
                self.record_impulse(t, closed, P, "tangential impact", why)
                continue
            raise Inconsistent(f"at t = {t:.17g}: {why}; the impulsive fallback gives no sticking impulse")

    def _pick(self, group, acc, last):
        """One solution of a motion with several mode sets (a tie at a mode boundary): at a slip
        event the slipping contact slides, otherwise the contacts stay closed and at rest."""
        kind, jev = last if last is not None else (None, -1)

        def key(s):
            n_open = sum(md == OPEN for md in s.modes)
            n_slide = sum(md not in (OPEN, STICK) for md in s.modes)
            return (n_open, -n_slide if kind == "slip" else n_slide)

        sol = min(group, key=key)
        if kind == "slip" and jev in acc.idx:
            i = acc.idx.index(jev)
            if sol.modes[i] == STICK:
                N, f = sol.p[i], acc.tangent(sol.p, i)
                nf = float(np.linalg.norm(f))
                if nf > 0 and nf >= acc.mu_true[i] * N * (1 - 1e-8):
                    modes, dirs = list(sol.modes), list(sol.dirs)
                    d = -f / nf
                    modes[i] = SLIDE if d.size == 2 else (SLIDE_POS if d[0] > 0 else SLIDE_NEG)
                    dirs[i] = d
                    sol = type(sol)(modes, dirs, sol.p, sol.qdd)
        return sol

    # ------------------------------------------------------------------ projection
    def project(self, t, q, v, gap_rows, normal_rows, tangent_contacts):
        """Smallest mass-metric corrections onto the closed contacts' gaps (and the bilateral
        constraints), then onto their normal velocities and the resting contacts' tangent
        velocities; coordinates fixed by one row are set exactly (a flat contact)."""
        model, sys_ = self.model, self.sys
        n, nb = model.n, model.nb
        gap_rows = sorted(set(gap_rows))
        for _ in range(1 if model.constant else 3):
            rows, res = [], []
            if nb:
                phi, G, _ = (np.array(x, dtype=float) for x in sys_.constraints_fn(t, q))
                rows.append(G.reshape(nb, n))
                res.append(phi.ravel())
            if gap_rows:
                rows.append(model.jac(q, t)[gap_rows])
                res.append(model.gaps(q, t)[gap_rows])
            if not rows:
                break
            J, r = np.vstack(rows), np.concatenate(res)
            if not np.any(r):
                break
            # v-space correction: q moves by T(q) dx under Newton-Euler kinematics (renormalised)
            q = model.advance(t, q, -mass_projection(sys_.mass(q, t), J, r))
        if model.constant and gap_rows:
            for i, val in coordinate_rows(model.HN[gap_rows], -model.gap0[gap_rows]):
                q[i] = val
        rows, res = [], []
        if nb:
            _, G, phi_t = (np.array(x, dtype=float) for x in sys_.constraints_fn(t, q))
            G = G.reshape(nb, n)
            rows.append(G)
            res.append(G @ v + phi_t.ravel())
        vr = list(normal_rows) + [r for j in tangent_contacts for r in model.trows[j].tolist()]
        if vr:
            H = model.jac(q, t)[vr]
            rows.append(H)
            res.append(H @ v if not model.moving else model.local_velocity(t, q, v)[vr])
        if rows:
            J, r = np.vstack(rows), np.concatenate(res)
            if np.any(r):
                v = v - mass_projection(sys_.mass(q, t), J, r)
            if model.constant and vr:
                for i, val in coordinate_rows(model.H[vr], np.zeros(len(vr))):
                    v[i] = val
        return q, v

    def _redundant(self, t, q, idx) -> bool:
        """Whether a rigid body's closed contacts ``idx`` have redundant normal rows (four corners of
        a face): their phase then has the least-norm forces (:meth:`SpatialModel.phase_accel`)."""
        if not (self.model.kinematic and len(idx) > 1):
            return False
        return int(np.linalg.matrix_rank(self.model.jac(q, t)[list(idx)])) < len(idx)

    def _redundant_note(self, t, q, idx) -> str:
        """Where the closed contacts of a chattering stop have redundant normal rows (a rigid box
        on four corners of a face): say so, their forces being the least-norm ones."""
        if len(idx) < 2:
            return ""
        Hn = self.model.jac(q, t)[list(idx)]
        rank = int(np.linalg.matrix_rank(Hn))
        if rank == len(idx):
            return ""
        names = ", ".join(repr(self.sys.contacts[j].name) for j in idx)
        return (f". The closed contacts {names} are redundant (their {len(idx)} normal rows have rank {rank}): "
                "their phases take the least-norm forces, and chattering between their modes may come from "
                "that choice (method='moreau-jean' resolves such contacts by impulses).")

    # ------------------------------------------------------------------ the loop
    def run(self, q0, v0):
        o = self.o
        t, q, v = 0.0, q0.copy(), v0.copy()
        P = np.zeros(self.model.H_rows)
        status, message = 0, EVENT_STATUS_MESSAGES[0]
        run_phases = []
        breakpoints = list(self.breakpoints)
        last = None
        short = 0
        while True:
            try:
                v, idx, modes, dirs = self.decide(t, q, v, last)
            except Inconsistent as exc:
                status, message = -3, f"{EVENT_STATUS_MESSAGES[-3]} {exc}"
                break
            if last is not None and last[0] == "impact":
                jump = watch_bounces(self, t, q, v, P, idx, modes, run_phases[-1])
                if jump is not None:
                    t, q, v, tail = jump
                    run_phases.append(tail)
                    self.phases.append(Phase(float(tail.t0), float(tail.t1), tail.names(), tail.integrator, 0))
                    last = None
                    continue
            elif last is not None:
                self.bounces.reset()
            if idx:
                # contacts closed by the zero tests (a bounce below the velocity tolerance): the
                # phase starts on them, as after an event (else their residual gap and normal
                # velocity drift through the whole phase)
                q, v = self.project(t, q, v, idx, idx, [c for c, md in zip(idx, modes) if md == STICK])
            while breakpoints and breakpoints[0] <= t:
                breakpoints.pop(0)
            t_stop = breakpoints[0] if breakpoints else self.t_end
            ph = SpatialPhase(self, t, q, v, P, idx, modes, dirs)
            try:
                ev = ph.run(t_stop, t_stop < self.t_end)
            except FloatingPointError as exc:
                status, message = -2, f"{EVENT_STATUS_MESSAGES[-2]} Phase from t = {t:.10g}: {exc}"
                break
            run_phases.append(ph)
            self.max_drift = max(self.max_drift, ph.speed_drift())
            unique = not self._redundant(t, q, idx)
            self.nonunique += not unique
            self.phases.append(Phase(float(ph.t0), float(ph.t1), ph.names(), ph.integrator, int(ph.nfev), unique))
            for name in ph.names():
                self.stats.mode_counts[name] += 1
            if ev is None:
                if t_stop >= self.t_end:
                    break
                ev = (t_stop, "breakpoint", -1)
            te, kind, j = ev
            last = (kind, j)
            if kind == "painleve":
                status = -3
                message = (f"{EVENT_STATUS_MESSAGES[-3]} At t = {te:.17g} contact {self.sys.contacts[j].name!r} "
                           "slides into the Painleve singularity (its effective normal mass tends to zero, the "
                           "normal force grows without bound); the integration stops there.")
                self.events.append(Event(float(te), kind, int(j)))
                t = te
                break
            q, v, P = ph.end_state()
            stick = [c for c, md in zip(idx, modes) if md == STICK]
            if kind == "stop":
                stick.append(j)
            gap_rows = list(idx) + ([j] if kind == "impact" else [])
            q, v = self.project(te, q, v, gap_rows, list(idx), stick)
            gap = self.model.gaps(q, te)
            if self.m and not self.penetrated and min(gap.tolist()) < -self.gap_tol:
                self.penetrated = True  # no silent success: an open contact penetrated unseen
                self.notes.append(f"At t = {te:.10g} contact {self.sys.contacts[int(np.argmin(gap))].name!r} penetrates "
                                  f"by {-float(np.min(gap)):.3g} (an impact was missed): the motion after it is not reliable.")
            if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
                status, message = -2, f"{EVENT_STATUS_MESSAGES[-2]} At t = {te:.10g}."
                break
            self.events.append(Event(float(te), kind, int(j)))
            short = short + 1 if te - t <= 64 * EPS * max(1.0, abs(te)) else 0
            t = te
            stop_message = too_many_events(len(self.events), short, t, o.max_events, EVENT_STATUS_MESSAGES[-4])
            if stop_message:
                status, message = -4, stop_message + self._redundant_note(t, q, idx)
                break
        self.stats.steps = len(run_phases)
        self.stats.free_steps = sum(1 for ph in run_phases if not ph.idx)
        if self.max_drift > 1e-8 * self.scales["V"]:
            self.notes.append(f"The sliding speeds drifted from |U| by up to {self.max_drift:.3g}.")
        return run_phases, status, message, t


def spatial_event_driven(system, q0, v0, t_end, opts, given, scene=None) -> EventResult:
    """:func:`lcp.events.driver.event_driven` for a system with spatial contacts.

    ``opts`` are the validated :class:`~lcp.events.options.EventOptions`, ``given`` the names of
    the options the caller set (rtol and atol default to 1e-13 and 1e-16 here). ``smooth="closed-form"`` and
    ``mode_solver``/``impact_solver``/``max_branches`` other than their defaults are rejected
    (ValueError naming them): phases are integrated by ``solve_ivp`` (or in closed form, see
    :mod:`lcp.events.spatial_closed_form`), and the disk problems by the
    solvers of :mod:`lcp.events.spatial_modes`.

    Examples
    --------
    A block launched at 2 m/s on a plane (mu 0.5, g 10) stops at t = 0.4 s and sticks:

    >>> import lcp
    >>> res = lcp.simulate(lcp.scenes.plane_slide(v0=2.0, mu=0.5, g=10.0), 1.0, method="event")
    >>> res.success, res.mode_sequence, abs(res.t_events[0] - 0.4) < 1e-15
    (True, [('slide',), ('stick',)], True)
    """
    for name, default in (("smooth", "auto"), ("mode_solver", "auto"), ("impact_solver", "auto"),
                          ("max_branches", 4096)):
        val = getattr(opts, name)
        if name in given and getattr(val, "value", val) != default:
            raise ValueError(f"{name}={getattr(val, 'value', val)!r} is not supported for spatial contacts "
                             f"(the event method integrates their phases with solve_ivp and solves the disk "
                             f"problems itself); leave {name} at {default!r}")
    q0, v0 = system.check_state(q0, v0)
    q0, v0, start_note = consistent_start(system, q0, v0)  # the one check of a start (lcp.model.start)
    rtol = opts.rtol if "rtol" in given else SPATIAL_RTOL
    atol = opts.atol if "atol" in given else SPATIAL_ATOL
    t_out = opts.output_times(t_end)
    integ = SpatialIntegrator(system, q0, v0, t_end, opts, rtol, atol)
    phases, status, message, t_fail = integ.run(q0, v0)
    if start_note is not None:
        message = f"{message} {start_note}"
    for note in integ.notes:
        message = f"{message} {note}"
    if integ.nonunique:
        message = (f"{message} Contact forces are not unique in {integ.nonunique} phase(s) (redundant "
                   "contacts): the least-norm forces are reported.")
    if status < 0:
        t_out = t_out[t_out <= t_fail]
        if scene is not None:
            message = f"{message} (scene '{scene.name}')"
    n, m, R = system.n, system.n_contacts, system.n_contact_rows
    nq = system.n_q  # rows: q (n_q), v (n), cumulative forces (R)
    N_out = t_out.size
    Y = np.empty((nq + n + R, N_out))
    FN, FT = np.zeros((N_out, m)), np.zeros((N_out, R - m))
    MD = np.full((N_out, m), -1, dtype=np.int8)
    Y[:nq + n] = np.nan
    Y[nq + n:] = 0.0
    for k_, ph in enumerate(phases):
        last = k_ == len(phases) - 1
        a = int(np.searchsorted(t_out, ph.t0, "left"))
        b = int(np.searchsorted(t_out, ph.t1, "right" if last else "left"))
        if a < b:
            FN[a:b], FT[a:b] = ph.output(t_out[a:b], Y[:, a:b])
            MD[a:b] = ph.full_modes
    for imp in integ.impulses:
        after = int(np.searchsorted(t_out, imp.t, "right"))
        Y[nq + n + imp.contact, after:] += imp.P_N
        tr = integ.model.trows[imp.contact]
        Y[nq + n + tr, after:] += np.atleast_1d(imp.P_T)[:, None]
    Q, V = np.ascontiguousarray(Y[:nq].T), np.ascontiguousarray(Y[nq:nq + n].T)
    dP = np.diff(Y[nq + n:], axis=1).T
    return EventResult(t=t_out, q=Q, v=V, p_N=dP[:, :m], p_T=dP[:, m:], modes=MD[:-1] if N_out else MD,
                       status=status, message=message, stats=integ.stats, method="event",
                       solver="disk", t_events=[ev.t for ev in integ.events], force_N=FN, force_T=FT,
                       events=integ.events, impulses=integ.impulses, phases=integ.phases,
                       impacts=integ.impact_list, accumulations=integ.accumulations,
                       nonunique_forces=integ.nonunique)
