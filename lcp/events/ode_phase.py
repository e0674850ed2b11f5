"""Smooth phases integrated by SciPy's ``solve_ivp`` (DOP853 by default, rtol 1e-12).

Used when the phase dynamics is not polynomial in t. Events are functions with ``.terminal`` and
``.direction`` (:func:`lcp.events.event_location.event_functions`), located by Brent's method on the
dense output. SciPy's integrators are imported on the first such phase only.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from lcp.contact.problem import ContactProblem
from lcp.events.compiled_branch import branch_rhs_function
from lcp.events.event_location import event_functions, first_terminal_event
from lcp.events.kinematic_ode import normalising_method
from lcp.events.indeterminate import admissibility_rows, branch_forces
from lcp.events.model import all_finite, mass_projection
from lcp.events.modes import AccelProblem
from lcp.events.options import EventOptions
from lcp.events.phases import SmoothPhase
from lcp.numerics.casadi_eval import evaluate_kept

__all__ = ["OdePhase"]


class OdePhase(SmoothPhase):
    """solve_ivp on y = (q, v, cumulative contact impulses), with terminal event functions."""

    def __init__(self, *args, options: EventOptions, scales, indeterminate=False):
        super().__init__(*args)
        self.options = options
        self.integrator = options.ode_method
        self.scales = scales
        self.indeterminate = indeterminate
        self._cache_key = None
        # affine forces: the whole phase is a linear ODE y' = L y + c (with unique forces)
        self.linear = self.model.constant and not indeterminate
        if self.linear:
            self._build_linear()
        # the state derivative as one compiled evaluation (lcp.events.compiled_branch); None: NumPy
        self.compiled = None if self.linear or indeterminate or options.rhs != "compiled" else branch_rhs_function(
            self.model.sys, self.model.m, self.idx_t, tuple(self.slide.tolist()), self.mu)

    # --- dynamics
    def _build_linear(self):
        """For a constant system with affine forces: y' = L y + c, built once per phase (under a
        piecewise-affine forcing, :mod:`lcp.events.forcing`: y' = L y + c + c1 (t - t0)).

        The branch solution is linear in the free contact acceleration b; its matrix comes from
        ``solve_branch`` on unit right-hand sides (the Coulomb law is not rewritten here).
        """
        model, n, m = self.model, self.model.n, self.model.m
        data = model.data(self.t0, np.zeros(n), np.zeros(n))
        acc = AccelProblem(data, self.idx, self.slide, self.mu)
        k = acc.k
        modes = acc.branch_modes(self.modes)
        Pi = np.zeros((2 * k, 2 * k))
        for i in range(2 * k):
            e = np.zeros(2 * k)
            e[i] = 1.0
            p = ContactProblem(acc.pb.W, e, acc.pb.mu).solve_branch(modes)
            if p is None:
                raise FloatingPointError("singular contact branch in a smooth phase")
            Pi[:, i] = p
        rows = np.concatenate([self.idx, m + self.idx])
        Hc = model.H[rows]
        # qdd_free = S (F0 + Kq q + Cv v): columns by solves; under a piecewise-affine forcing
        # F0 is its value at t0 and its rate the last column (c(t) = c + c1 (t - t0))
        forcing = model.forcing
        F0, F1 = (model.F0, None) if forcing is None else forcing.affine(self.t0)
        cols = [F0, model.Kq, model.Cv] + ([] if F1 is None else [F1])
        Sfree = data.solve_dirs(np.column_stack(cols))
        s0, Sq, Sv = Sfree[:, 0], Sfree[:, 1:n + 1], Sfree[:, n + 1:2 * n + 1]
        # p = Pi b, b = Hc qdd_free
        Pq, Pv, p0 = Pi @ Hc @ Sq, Pi @ Hc @ Sv, Pi @ Hc @ s0
        Qq, Qv, q0 = Sq + acc.SD @ Pq, Sv + acc.SD @ Pv, s0 + acc.SD @ p0
        # physical forces of all contacts: N = p[:k]; f = p[k:] or -mu s N
        fold = np.zeros((2 * m, 2 * k))
        fold[self.idx, np.arange(k)] = 1.0
        for jj, j in enumerate(self.idx):
            if self.slide[jj] != 0:
                fold[m + j, jj] = -self.mu[j] * self.slide[jj]
            else:
                fold[m + j, k + jj] = 1.0
        L = np.zeros((2 * n + 2 * m, 2 * n + 2 * m))
        c = np.zeros(2 * n + 2 * m)
        L[:n, n:2 * n] = np.eye(n)
        L[n:2 * n, :n], L[n:2 * n, n:2 * n], c[n:2 * n] = Qq, Qv, q0
        L[2 * n:, :n], L[2 * n:, n:2 * n], c[2 * n:] = fold @ Pq, fold @ Pv, fold @ p0
        self.L, self.c = L, c
        self.c1 = None
        if F1 is not None:
            s1 = Sfree[:, 2 * n + 1]
            p1 = Pi @ Hc @ s1
            self.c1 = np.concatenate([np.zeros(n), s1 + acc.SD @ p1, fold @ p1])

    def evaluate(self, t, y):
        """(ydot, N (m), f (m)) at (t, y), cached for the event functions at the same point."""
        key = (t, y.tobytes())
        if key == self._cache_key:
            return self._cache
        n, m = self.model.n, self.model.m
        if self.linear:
            yd = self.L @ y + self.c
            if self.c1 is not None:
                yd = yd + (min(t, self.t_left) - self.t0) * self.c1
            out = (yd, yd[2 * n:2 * n + m], yd[2 * n + m:])
        else:
            nq = self.model.nq
            q, v = y[:nq], y[nq:nq + n]
            tt = min(t, self.t_left)
            data = self.model.data(tt, q, v)
            qdd, N, f = self.accel(data)
            if self.indeterminate:
                qdd = self.constrained(data, qdd)
            Nm, fm = np.zeros(m), np.zeros(m)
            Nm[self.idx], fm[self.idx] = N, f
            out = (np.concatenate([self.model.qdot(tt, q, v), qdd, Nm, fm]), Nm, fm)
        self._cache_key, self._cache = key, out
        return out

    def constrained(self, data, qdd):
        """qdd with the residual of the phase's constraints at the acceleration level (closed
        normals, sticking tangents, bilateral constraints) removed in the mass metric. Redundant
        contacts' forces come from a least-squares solve whose rounding (1e-15 of the forces)
        would otherwise move a sticking body over a long phase and shift its events."""
        m = self.model.m
        rows = np.concatenate([self.idx, m + self.idx[self.slide == 0]])
        J = data.H[rows]
        r = J @ qdd + data.Hdv[rows]
        if data.nb:
            J = np.vstack([J, data.G])
            r = np.concatenate([r, data.G @ qdd + data.zeta])
        return qdd - mass_projection(data.A, J, r) if J.shape[0] and r.any() else qdd

    def _rhs(self, t, y):
        """The integrator's y' = (qdot, qdd, N, f): the compiled evaluation (``rhs="compiled"``, the
        default) where its values are finite, else :meth:`evaluate`'s. The event functions, the end
        acceleration and the reported forces always use :meth:`evaluate`, the NumPy arithmetic of
        the mode decisions, so that a force's root is located where the decision at the event sees
        it."""
        if self.compiled is not None:
            nq, n = self.model.nq, self.model.n
            yd = np.empty(y.size)
            evaluate_kept(self.compiled, (np.array([min(t, self.t_left)]), np.ascontiguousarray(y[:nq]),
                                          np.ascontiguousarray(y[nq:nq + n])), [yd])
            if all_finite(yd):
                return yd
        return self.evaluate(t, y)[0]

    # --- events
    #: the forces are evaluated at no later time than this: the left limit at a breakpoint that
    #: ends the phase (the last stage of a step, and the event functions, evaluate at t_stop)
    t_left = np.inf

    def run(self, t_stop, breakpoint=False):
        """First event before t_stop: (t_event, kind, contact) or None. With ``breakpoint`` the
        forces jump at t_stop: the phase sees their left limit there."""
        if breakpoint:
            self.t_left = float(np.nextafter(t_stop, -np.inf))
        n, nq = self.model.n, self.model.nq
        y0 = np.concatenate([self.q0, self.v0, self.P0])
        evs, meta = event_functions(self, self.t0, y0, self.options.tol * self.scales.get("F", 0.0),
                                    self.options.tol * self.scales.get("V", 0.0))
        o = self.options
        atol = np.concatenate([np.full(nq, o.atol * self.scales["L"]), np.full(n, o.atol * self.scales["V"]),
                               np.full(self.P0.size, o.atol * self.scales["P"])])
        # imported on the first non-polynomial phase only (keeps `import lcp` cheap)
        from scipy.integrate import solve_ivp

        method = o.ode_method if not self.model.kinematic else normalising_method(self.model.sys, o.ode_method)
        sol = solve_ivp(self._rhs, (self.t0, t_stop), y0, method=method, rtol=o.rtol, atol=atol,
                        events=evs, dense_output=True)
        self.nfev = sol.nfev
        self.sol = sol
        if sol.status < 0:
            raise FloatingPointError(f"solve_ivp ({o.ode_method}) failed at t = {sol.t[-1]:.10g}: {sol.message}")
        self.y1 = sol.y[:, -1]
        t_end = first_terminal_event(sol, meta)[0] if sol.status == 1 else t_stop
        crossed = self._passed_through(sol, t_end)
        if crossed is not None:  # a contact closed inside an ODE step and opened again before its end
            self.t1, j = crossed
            self.y1 = sol.sol(self.t1)
            self.model.normalize(self.y1[:nq])
            return self.t1, "impact", j
        if sol.status == 1:
            self.t1, self.y1, kind, j = first_terminal_event(sol, meta)
            self.model.normalize(self.y1[:nq])
            if kind == "force-limit":
                kind, j = self.binding(self.t1, self.y1)
            return self.t1, kind, j
        self.t1 = t_stop
        return None

    #: dense-output samples per ODE step at which the open contacts' gaps are checked
    GAP_SAMPLES = 8

    def _passed_through(self, sol, t_end):
        """(t, j) of the first closing of an open contact j that the event functions, evaluated at
        the ends of the ODE steps only, cannot see: a body carried through a thin obstacle within
        one step (two discs flying head-on passed through each other: the gap is positive at both
        ends of the step). Each step's gaps are sampled on the dense output (:data:`GAP_SAMPLES`
        per step); where a sample's gap is below its neighbours', the minimum between them is
        found by Brent's method (a fast pass-through lasts a fraction of the sampling interval),
        and a negative minimum's first crossing located. None when every contact stays open."""
        idx = self.open_idx
        if not idx.size or sol.t.size < 2:
            return None
        from scipy.optimize import brentq, minimize_scalar

        nq = self.model.nq
        moving = getattr(self.model, "moving", False)

        def gap(t, j):
            y = sol.sol(t)
            return float(self.model.gaps(y[:nq], t if moving else None)[j])

        steps = sol.t[sol.t <= t_end]
        if steps[-1] < t_end:
            steps = np.append(steps, t_end)
        K = self.GAP_SAMPLES
        for a, b in zip(steps[:-1], steps[1:]):
            ts = a + (b - a) * np.arange(K + 1) / K
            Y = sol.sol(ts)
            G = self._sample_gaps(ts, Y[:nq])
            scale = 1e-9 * (1.0 + float(np.max(np.abs(Y[:nq]), initial=0.0)))
            found = None
            for j in idx:
                g = G[:, j]
                i = int(np.argmin(g))
                if 0 < i < K:  # an interior minimum: refined between its neighbours
                    r = minimize_scalar(lambda s, j=j: gap(s, j), bounds=(ts[i - 1], ts[i + 1]), method="bounded",
                                        options={"xatol": 1e-12 * max(1.0, abs(b))})
                    t_min, g_min = float(r.x), float(r.fun)
                else:
                    t_min, g_min = float(ts[i]), float(g[i])
                if g_min >= -scale or g[0] <= 0:
                    continue  # (open throughout, or closed at the step's start: not a crossing here)
                tc = brentq(lambda s, j=j: gap(s, j), a, t_min, xtol=1e-14, rtol=1e-14)
                if found is None or tc < found[0]:
                    found = (tc, int(j))
            if found is not None:
                return found
        return None

    def _sample_gaps(self, ts, Q) -> np.ndarray:
        """The gaps at the columns of Q (times ts), shape (len(ts), m): in one call where the
        gaps do not move (a mapped CasADi function, kept on the model), else per sample."""
        model = self.model
        if getattr(model, "constant", False):
            return (model.gap0[:, None] + model.HN @ Q).T
        fn = getattr(model.sys, "gap_fn", None)
        if getattr(model, "moving", False) or not isinstance(fn, ca.Function):
            return np.array([model.gaps(Q[:, i], ts[i]) for i in range(Q.shape[1])])
        maps = model.__dict__.setdefault("_gap_maps", {})
        if Q.shape[1] not in maps:
            maps[Q.shape[1]] = fn.map(Q.shape[1])
        return np.array(maps[Q.shape[1]](Q), dtype=float).T

    def margin_at(self, t, y):
        """Force margin of the phase's modes at (t, y) (:meth:`SmoothPhase.margin`), cached."""
        key = (t, y.tobytes())
        if key != getattr(self, "_margin_key", None):
            n, nq = self.model.n, self.model.nq
            data = self.model.data(min(t, self.t_left), y[:nq], y[nq:nq + n])
            self._margin_key, self._margin = key, self.margin(data)
        return self._margin

    def binding(self, t, y):
        """(kind, contact) of what ends a phase of redundant contacts at (t, y): a contact whose
        normal force must vanish there (``"lift-off"``: tipping), else the friction bound or
        sliding direction with the least slack, both judged on the least-norm admissible forces."""
        n, nq = self.model.n, self.model.nq
        data = self.model.data(min(t, self.t_left), y[:nq], y[nq:nq + n])
        acc = AccelProblem(data, self.idx, self.slide, self.mu)
        check = acc.check_modes(self.modes)
        bf = branch_forces(acc.pb, check, acc.branch_modes(self.modes))
        G, h, _, labels = admissibility_rows(acc.pb, check)
        slack = G @ bf.p - h
        tol = 1e-9 * max(acc.pb.scale, float(np.max(np.abs(bf.p))))
        lift = [lab for x, lab in zip(slack, labels) if lab[0] == "lift-off" and x <= tol]
        kind, jj = lift[0] if lift else labels[int(np.argmin(slack))]
        return kind, int(self.idx[jj])

    def end_acceleration(self):
        """Acceleration at the end of the phase."""
        n, nq = self.model.n, self.model.nq
        return self.evaluate(self.t1, self.y1)[0][nq:nq + n].copy()

    def end_state(self):
        n, nq = self.model.n, self.model.nq
        y = self.y1
        return y[:nq].copy(), y[nq:nq + n].copy(), y[nq + n:].copy()

    def output(self, t, out):
        """Write (q, v, cumulative impulses) at the times t into the columns of ``out``; return (N, f)."""
        m = self.model.m
        Y = self.sol.sol(t) if t.size else np.zeros((out.shape[0], 0))
        out[:] = Y
        if self.model.kinematic:
            for i in range(t.size):
                self.model.normalize(out[:self.model.nq, i])
        N = np.zeros((t.size, m))
        f = np.zeros((t.size, m))
        for i in range(t.size):
            _, N[i], f[i] = self.evaluate(float(t[i]), Y[:, i])
        return N, f


