"""Exact-phase multiple shooting: the optimal control on a fixed sequence of contact modes.

The transcriptions (:mod:`lcp.ocp.transcription`, :mod:`lcp.ocp.collocation`) find the contact
phases and a control near the optimum, but their steps carry a discretisation error: the event
replay of their control misses their own final state (nosnoc's motor at N = 30: 0.50 with the
theta step, 4.6e-4 with Radau IIA). This module removes that error. It takes the sequence of
smooth phases that the event method finds when it replays the transcription's control (each
control interval k split into segments j of one contact mode each, with their switch times), and
solves the optimal control problem again with that sequence fixed:

- each segment is integrated by CVODES to a tolerance of 1e-12 (the event method's DOP853 replay
  uses rtol 1e-12), in the mode's dynamics: with C the closed contacts, S the sticking ones and
  s_j = +1 (slide+, u_T > 0) or -1 (slide-) on the sliding ones,

      M a = F + B u + sum_{j in C} (H_Nj' - s_j mu_j H_Tj' [j slides]) lambda_Nj + sum_{j in S} H_Tj' lambda_Tj,
      H_Nj a + (dH_Nj/dt) v = 0 (j in C),     H_Tj a + (dH_Tj/dt) v = 0 (j in S),

  (bilateral constraints as closed frictionless contacts), and the impulses of a control
  interval are the integrals of the forces (quadratures);
- the segment durations are unknowns (summing to the interval's length, itself an unknown with
  free steps): the switch times move;
- each mode is kept admissible at both ends of its segment (lambda_N >= 0 on a closed contact,
  |lambda_T| <= mu lambda_N on a sticking one, s u_T >= 0 on a sliding one, g >= 0 on an open
  one at the segment's end), and each switch is one the event method takes: a stop (slide to
  stick or reversal) at u_T = 0, a slip from stick with the tangential acceleration along the
  slide, a lift-off with the free normal acceleration >= 0;
- the costs, constraints and control holds are the problem's own (its ``Step`` callables on the
  interval's end states and impulses).

Redundant rows (a box resting on two stuck corners: four rows on three velocities): each
segment's mode holds a maximal independent subset of its rows, chosen at the segment's start
state on a CVODES walk through the plan (:func:`plan_keys`,
:func:`~lcp.ocp.phase_dynamics.independent_rows`); the accelerations are unique, the forces are
not: at each check point free variables z move the forces along the null space of the force
columns, so the admissibility above asks that SOME distribution of the forces be admissible. The
interval's mean forces (``pN``, ``fT``, the result's impulses) are those of one such distribution:
the kept rows' forces integrated by the integrator plus the Newton-Cotes integral of the free part
over the check points (admissible at the check points, as the modes are). The dropped rows'
conditions (their velocities and accelerations, the null space's zero generalized force) are
constraints of the check of every solution, so a dependency that does not hold along the phase
shows as a violated mode condition, never as a silent answer; a mode whose accelerations are not
unique is refused (:class:`NotShootable`). An impact law's redundant velocity rows likewise
(:func:`~lcp.ocp.phase_dynamics.impact_rows`): the impulses' split is free within the cones.

The solution is then exact up to the integrator's tolerance: its replay repeats it (misses of
1e-9 and below where the transcription missed by 1e-1 to 1e-4). It is a local optimum for that
phase sequence: a phase the optimum does not have can only shrink to zero length.

Impacts: the replay's impacts start segments; there the velocity jumps by M^-1 H' P with the
impulses P as unknowns under the event method's impact law in the replay's mode (the gap closed,
an approach, Newton's u_N+ = -e u_N-, Coulomb's law on P_T: stick or slide), so the impact time
moves with the segment durations. Not modelled (:class:`NotShootable` says which): a contact that
closes without an impact, the Painleve fallback's impulses and accumulations, spatial contacts, the user's complementarity pairs, contacts or constraints
that move with t, kinematic maps.

The plans (phase sequences) are made in :mod:`lcp.ocp.plans`; where IPOPT cannot solve an NLP
whose iterate shrinks segments to zero, the NLP is solved again on the plan without them
(:func:`~lcp.ocp.plans.pruned_plan`).

Imports CasADi, NumPy, the contact modes, the phase dynamics, the plans and the theta
transcription (whose NLP bookkeeping it reuses); it must not import the solve or the problem (they call it).
"""
from __future__ import annotations

import time

import casadi as ca
import numpy as np

from lcp.contact.modes import OPEN, SLIDE_NEG, SLIDE_POS, STICK
from lcp.ocp.phase_dynamics import (
    CHECK_TOL,
    GRID,
    INTEGRATOR_TOL,
    POINT_WEIGHTS,
    NotShootable,
    impulse_dv,
    mode_dynamics,
    segment_integrator,
)
from lcp.ocp.plans import phase_plan, plan_keys, plan_of_modes, pruned_start
from lcp.ocp.transcription import Transcription, grid_variables, step_terms

__all__ = ["CHECK_TOL", "INTEGRATOR_TOL", "NotShootable", "PhaseShooting", "impact_law", "initial_point", "phase_plan", "plan_keys", "plan_of_modes",
           "refuse", "solve_shooting"]

def refuse(problem) -> None:
    """NotShootable when the problem has what the shooting does not model."""
    sys = problem.system
    if sys.is_spatial:
        raise NotShootable("spatial contacts are not modelled")
    t = sys.t_sym
    if ca.depends_on(ca.vertcat(sys.gap_expr, ca.vec(sys.H_expr), sys.constraints_expr), t):
        raise NotShootable("contacts or constraints that move with t are not modelled")


class PhaseShooting(Transcription):
    """The NLP of an :class:`~lcp.ocp.OptimalControlProblem` on a fixed phase sequence (module
    docstring). Same interface as :class:`~lcp.ocp.transcription.Transcription` (``nlp``, ``ix``,
    bounds, :meth:`unpack`); ``plan`` as :func:`phase_plan` returns it; ``keys`` as
    :func:`plan_keys` returns it (None: every row a mode or an impact law holds, for plans without
    redundant rows).
    With ``check`` the mode conditions of the rows dropped as redundant are constraints too (the
    check of a solution, never solved: they are implied wherever the dropping was right).
    ``like``: another PhaseShooting of the same problem, plan, keys, pairs and band whose symbolic
    NLP this one shares where the two NLPs differ only in their integrators (no rows dropped, so
    ``check`` adds nothing): only the integrator calls are built again (:meth:`shares_with`)."""

    def __init__(self, pb, plan, substeps: int = 0, check: bool = False, zeros=None, pair_tol: float = 0.0,
                 keys=None, like=None):
        refuse(pb)
        #: the user pairs' zero members: zeros[i][k] is True where a_i is zero at step k
        self.zeros, self.pair_tol = zeros, pair_tol
        if pb.complementarity and zeros is None:
            raise ValueError("zeros (pair_zeros of a result) is needed for the user's complementarity pairs")
        #: Runge-Kutta steps per grid interval of a segment (0: CVODES)
        self.substeps = int(substeps)
        #: CVODES at the check's tolerance (CHECK_TOL) rather than the NLP's (INTEGRATOR_TOL)
        self.tol = CHECK_TOL if check else INTEGRATOR_TOL
        if len(plan) != pb.N:
            raise ValueError(f"plan has {len(plan)} intervals, the problem {pb.N}")
        self.plan = [[(tuple(int(c) for c in sg[0]), float(sg[1]), tuple(sg[2]) if len(sg) > 2 else ())
                      for sg in segs] for segs in plan]
        #: per segment, the kept rows of its modes and of its impacts' law (None: all)
        self.keys = keys if keys is not None else [[(None, None)] * len(segs) for segs in self.plan]
        if [len(a) for a in self.keys] != [len(segs) for segs in self.plan]:
            raise ValueError("keys must have one entry per segment of plan")
        self.check = bool(check)
        self._modes_fns, self._integrators, self._ng = {}, {}, 0
        self._like = like if like is not None and like.shares_with(pb, self.plan, self.keys, zeros, pair_tol) else None
        super().__init__(pb)
        del self._like

    def shares_with(self, pb, plan, keys, zeros, pair_tol) -> bool:
        """Whether a PhaseShooting of these arguments has this one's symbolic NLP (constraints,
        costs, bounds), whatever its integrators: the same problem, plan, kept rows (every row kept:
        the check's extra constraints are those of dropped rows), pairs and band."""
        return (pb is self.pb and plan == self.plan and keys == self.keys and zeros is self.zeros
                and pair_tol == self.pair_tol and all(k == (None, None) for row in keys for k in row))

    # ------------------------------------------------------------------ the modes' dynamics
    def mode_function(self, modes, keep=None) -> ca.Function:
        """:func:`~lcp.ocp.phase_dynamics.mode_dynamics` of the given modes and kept rows, built once."""
        if (modes, keep) not in self._modes_fns:
            self._modes_fns[modes, keep] = mode_dynamics(self.pb, modes, keep)
        return self._modes_fns[modes, keep]

    def integrator(self, modes, keep=None) -> ca.Function:
        """:func:`~lcp.ocp.phase_dynamics.segment_integrator` in the given modes (CVODES at this
        NLP's tolerance, or its Runge-Kutta steps), built once."""
        if (modes, keep) not in self._integrators:
            name = f"seg_{''.join(map(str, modes))}" + ("" if keep is None else "_r" + "_".join(map(str, keep)))
            self._integrators[modes, keep] = segment_integrator(self.pb, self.mode_function(modes, keep), name,
                                                                self.tol, self.substeps)
        return self._integrators[modes, keep]

    # ------------------------------------------------------------------ build
    _SHARED = ("ix", "lbx", "ubx", "lbg", "ubg", "n_constraints", "defect_rows", "n_corrections", "_sx")

    def _build(self):
        like = self._like
        if like is not None:  # the symbolic NLP of ``like`` (and its modes' functions): only the calls anew
            for name in self._SHARED:
                setattr(self, name, getattr(like, name))
            self._modes_fns = like._modes_fns
            self._wrap()
            return
        pb = self.pb
        sys, N, n = pb.system, pb.N, pb.system.n
        m = sys.n_contacts
        mu = np.asarray(sys.mu, dtype=float)
        sigma, q0p, v0p, Tv, z, hs, us, qs, vs, tk = grid_variables(self, step_floor=STEP_FLOOR)
        gap = ca.Function("gap", [sys.q_sym], [sys.gap_expr]) if m else None
        Hfn = ca.Function("H", [sys.q_sym], [sys.H_expr]) if m else None
        J, pair_sizes = ca.SX(0), {}
        prev_modes = None
        self._calls, self._defect_rows = [], []
        for k in range(N):
            h = hs[k]
            ua, ub = self.control_pair(us, k)
            segs = self.plan[k]
            S = len(segs)
            if S > 1:
                ds = [self._var(f"d{k}_{j}", 1, 0.0, np.inf, key="d") for j in range(S)]
                self._constrain(ca.sum1(ca.vertcat(*ds)) - h, 0.0, 0.0)
            else:
                ds = [h]
            x = ca.vertcat(qs[k], vs[k])
            t_seg = tk[k]
            impN, impT = ca.SX.zeros(m, 1), ca.SX.zeros(m, 1)
            for j, (modes, _, impacts) in enumerate(segs):
                if impacts:  # the impacts at the segment's start: x is the state before them
                    x = impact_law(self, x, impacts, k, j)
                if j < S - 1:
                    xe = ca.vertcat(self._var(f"Qs{k}_{j}", n, -np.inf, np.inf, key="Qs"),
                                    self._var(f"Vs{k}_{j}", n, -np.inf, np.inf, key="Vs"))
                else:
                    xe = ca.vertcat(qs[k + 1], vs[k + 1])
                keep = self.keys[k][j][0]
                xg, qg = self._call(modes, keep, x, ca.vertcat(t_seg, ds[j], tk[k], h, ua, ub))
                self._defect(xg[:, -1] - xe)
                if m:
                    impN, impT = impN + qg[:m, -1], impT + qg[m:, -1]
                t_end = t_seg + ds[j]
                if m:
                    times = [t_seg + c * ds[j] for c in (0.0, *GRID)]
                    states = [x] + [xg[:, i] for i in range(len(GRID) - 1)] + [xe]
                    points = [(tt, xx, ua + (tt - tk[k]) / h * (ub - ua)) for tt, xx in zip(times, states)]
                    free = self._admissible(modes, keep, prev_modes, points, mu, gap, Hfn, f"{k}_{j}")
                    if free is not None:  # the mean forces: an admissible distribution's
                        impN, impT = impN + ds[j] * free[:m], impT + ds[j] * free[m:]
                prev_modes, x, t_seg = modes, xe, t_end
            pN = self._var(f"pN{k}", m, -np.inf, np.inf, key="pN")  # mean forces over the interval
            fT = self._var(f"fT{k}", m, -np.inf, np.inf, key="fT")
            if m:  # (integrals of the integrator: with the defects, what the integrator's error moves)
                self._defect(ca.vertcat(impN - h * pN, impT - h * fT))
            st = pb.make_step(k, tk[k], h, qs[k], qs[k + 1], vs[k], vs[k + 1], ua, ub, h * pN, h * fT)
            J = step_terms(self, J, st, us, k, h, ua, ub, z, sigma, pair_sizes, pairs=False)
            if pb.complementarity:  # the user's pairs with the zero member of each row fixed
                fixed_pairs(self, k, st)
        J = self._terminal_terms(J, Tv, qs, vs, z)
        g = ca.vertcat(*self._g) if self._g else ca.SX.zeros(0, 1)
        X, P = ca.vertcat(*self._x), ca.vertcat(sigma, q0p, v0p)
        # the integrators can only be called on MX: the NLP is built in SX with their outputs as
        # symbols, then evaluated in MX with the integrator calls in place of those symbols
        outs = ca.vertcat(*[ca.vertcat(ca.vec(c[3]), ca.vec(c[4])) for c in self._calls])
        #: one correction per integrator output (every state and integral at the check points)
        self.n_corrections = int(outs.shape[0])
        ins = ca.Function("shooting_inputs", [X, P], [ca.vertcat(*[ca.vertcat(c[2], c[5]) for c in self._calls])])
        jg = ca.Function("shooting_nlp", [X, P, outs], [J, g])
        #: the symbolic NLP without its integrators: sizes of x and p, the calls' inputs, the costs and
        #: constraints of (x, p, the calls' outputs), and per call (modes, kept rows, input sizes)
        self._sx = (X.shape[0], P.shape[0], ins, jg,
                    [(modes, keep, x_in.shape[0], p_in.shape[0]) for modes, keep, x_in, _, _, p_in in self._calls])
        del self._calls
        self._wrap()
        self.defect_rows = np.concatenate(self._defect_rows) if self._defect_rows else np.zeros(0, dtype=int)
        self.ix = {key: np.array(val) for key, val in self.ix.items()}
        self.lbx, self.ubx = np.concatenate(self._lbx), np.concatenate(self._ubx)
        self.lbg = np.concatenate(self._lbg) if self._lbg else np.zeros(0)
        self.ubg = np.concatenate(self._ubg) if self._ubg else np.zeros(0)
        self.n_constraints = int(self.lbg.size)
        del self._x, self._g, self._lbx, self._ubx, self._lbg, self._ubg, self._nx

    def _wrap(self):
        """The MX NLP: the symbolic NLP (``_sx``) with this NLP's integrators in place of the calls'
        output symbols (the integrators can only be called on MX)."""
        nx, npar, ins, jg, calls = self._sx
        Xm, Pm = ca.MX.sym("x", nx), ca.MX.sym("p", npar + self.n_corrections)
        args = ins(Xm, Pm[:npar])
        results, row = [], 0
        for modes, keep, n_x, n_p in calls:
            a, b = row, row + n_x
            c = b + n_p
            out = self.integrator(modes, keep)(x0=args[a:b], p=args[b:c])
            results += [ca.vec(out["xf"]), ca.vec(out["qf"])]
            row = c
        outs = ca.vertcat(*results)
        # the integrators' outputs plus the correction parameters (solve_shooting's deferred correction)
        Jm, gm = jg(Xm, Pm[:npar], outs + Pm[npar:])
        self.nlp = {"x": Xm, "f": Jm, "g": gm, "p": Pm}
        self.g_fn = ca.Function("shooting_g", [Xm, Pm], [gm])
        self.outputs_fn = ca.Function("shooting_outputs", [Xm, Pm], [outs])

    def _admissible(self, modes, keep, prev, points, mu, gap, Hfn, tag):
        """The segment's mode kept admissible at its points (t, x, u) (start, the integrator's grid,
        end), and its switch from the previous mode at its start. With rows dropped as redundant
        (``keep``) the forces at each point are lambda + Z z, z free variables (``ix["zf"]``): some
        distribution admissible. Returns the integral of Z z over the segment per unit duration
        (Newton-Cotes on the points: exact for the polynomial through them), or None."""
        n, m = self.pb.system.n, self.pb.system.n_contacts
        fn = self.mode_function(modes, keep)
        free = None
        first = prev is None
        if first:  # the start state's tangential velocities and gaps (numbers)
            sys = self.pb.system
            q_start, v_start = np.asarray(self.pb.q0, dtype=float), np.asarray(self.pb.v0, dtype=float)
            uT_start, gap_start = sys.contact_jacobian(q_start)[m:] @ v_start, sys.gaps(q_start)
        for i, (t, x, u) in enumerate(points):
            _, lamN, lamT, acc, Z, res = fn(t, x[:n], x[n:], u)
            if Z.shape[1]:  # redundant rows: the forces' free part
                lam = ca.mtimes(Z, self._var(f"zf{tag}_{i}", Z.shape[1], -np.inf, np.inf, key="zf"))
                lamN, lamT = lamN + lam[:m], lamT + lam[m:]
                free = (0.0 if free is None else free) + POINT_WEIGHTS[i] * lam
                if self.check:  # what the dropping assumed: the dropped rows' conditions hold
                    self._constrain(res, 0.0, 0.0)
            uT = ca.mtimes(Hfn(x[:n])[m:, :], x[n:])
            for j in range(m):
                md = modes[j]
                pm = md if first else prev[j]
                if md != OPEN:
                    self._constrain(lamN[j], 0.0, np.inf)
                if md == STICK:
                    self._constrain(ca.vertcat(mu[j] * lamN[j] - lamT[j], mu[j] * lamN[j] + lamT[j]), 0.0, np.inf)
                    if i == 0 and pm in (SLIDE_POS, SLIDE_NEG):  # a stop
                        self._constrain(uT[j], 0.0, 0.0)
                elif md in (SLIDE_POS, SLIDE_NEG) and mu[j] > 0.0:  # (frictionless: any direction)
                    s = 1.0 if md == SLIDE_POS else -1.0
                    self._constrain(s * uT[j], 0.0, np.inf)
                    if i == 0:
                        at_rest = pm == STICK or (first and abs(float(uT_start[j])) <= 1e-12)
                        if pm in (SLIDE_POS, SLIDE_NEG) and pm != md:  # a reversal passes through rest
                            self._constrain(uT[j], 0.0, 0.0)
                            at_rest = True
                        if at_rest:  # slipping from rest: the tangential acceleration along the slide
                            self._constrain(s * acc[m + j], 0.0, np.inf)
                elif i > 0:  # open: the gap stays open
                    self._constrain(gap(x[:n])[j], 0.0, np.inf)
                elif pm != OPEN or (first and float(gap_start[j]) <= 1e-12):
                    self._constrain(acc[j], 0.0, np.inf)  # a lift-off accelerates away from the surface
        return free

    def _defect(self, expr):
        """A continuity (or impulse) equality: the integrator's value minus the variable."""
        self._defect_rows.append(np.arange(self._ng, self._ng + expr.shape[0]))
        self._constrain(expr, 0.0, 0.0)

    def constraints(self, x, outputs=None) -> np.ndarray:
        """The constraint values at x, corrections zero (one pass of the integrators, or none
        where their ``outputs`` at x are given)."""
        if outputs is None:
            return np.array(self.g_fn(x, self.params())).ravel()
        nx, npar, ins, jg, calls = self._sx
        return np.array(jg(x, self.params()[:npar], outputs)[1]).ravel()

    def outputs(self, x) -> np.ndarray:
        """The integrators' outputs at x (the calls' states and integrals at the check points)."""
        return np.array(self.outputs_fn(x, self.params())).ravel()

    def params(self, corrections=None) -> np.ndarray:
        """The NLP's parameter vector: (sigma = 0, q0, v0, the output corrections or zeros)."""
        c = np.zeros(self.n_corrections) if corrections is None else corrections
        return np.concatenate([[0.0], self.pb.q0, self.pb.v0, c])

    def _constrain(self, expr, lo, hi):
        super()._constrain(expr, lo, hi)
        self._ng += self._g[-1].shape[0]

    def _call(self, modes, keep, x, p):
        """Symbols standing for the segment integrator's (xf, qf) at (x, p) (see ``_build``)."""
        n, m, i = self.pb.system.n, self.pb.system.n_contacts, len(self._calls)
        xf, qf = ca.SX.sym(f"xf{i}", 2 * n, len(GRID)), ca.SX.sym(f"qf{i}", 2 * m, len(GRID))
        self._calls.append((modes, keep, x, xf, qf, p))
        return xf, qf

    def step_impulses(self, x, steps):
        N, m = self.pb.N, self.pb.system.n_contacts
        return steps[:, None] * x[self.ix["pN"]].reshape(N, m), steps[:, None] * x[self.ix["fT"]].reshape(N, m)

    def impulses(self, x):
        """No impulses at the nodes: zeros of shape (N, 0)."""
        return np.zeros((self.pb.N, 0)), np.zeros((self.pb.N, 0))

    def modes(self):
        """(N, m) int8: each interval's mode at its start."""
        return np.array([segs[0][0] for segs in self.plan], dtype=np.int8).reshape(self.pb.N, -1)

    def diagnose(self, x, g=None) -> dict:
        """``dynamics``: the largest continuity defect between segments; ``residual``: the
        largest violation of the other constraints (the modes' admissibility and switches, the
        user's constraints); ``modes``: each interval's modes at its start. ``g``: the constraint
        values at x, when already evaluated (:meth:`constraints`)."""
        g = self.constraints(x) if g is None else g
        viol = np.maximum(np.maximum(self.lbg - g, g - self.ubg), 0.0)
        other = np.ones(g.size, dtype=bool)
        other[self.defect_rows] = False
        return {"dynamics": float(np.max(viol[self.defect_rows], initial=0.0)),
                "residual": float(np.max(viol[other], initial=0.0)), "modes": self.modes(),
                "lcp": float("nan"), "conflicts": 0, "max_product": 0.0, "cross": 0.0}


def impact_law(tr, x, impacts, k, j):
    """The state after the impacts at a segment's start of ``tr``'s NLP, with the impact law as constraints:
    the gap closed, an approach, Newton's restitution on the normal velocity, and Coulomb's law
    on the tangential impulse in the replay's mode (stick: no tangential velocity after it;
    slide: at the cone's bound against the velocity after it). The velocity rows that
    ``tr.keys[k][j][1]`` drops as implied by the others (with the gap of a dropped normal row) are
    left out but in the check (``tr.check``): the impulses' split along them is free, bounded by
    the cones."""
    sys = tr.pb.system
    kept = tr.keys[k][j][1]
    held = iter(range(2 * len(impacts)))  # the velocity rows' indices, in impact_rows' order
    n, m = sys.n, sys.n_contacts
    q, v = x[:n], x[n:]
    H = ca.Function("H", [sys.q_sym], [sys.H_expr])(q)
    Mq = ca.Function("M", [sys.t_sym, sys.q_sym], [sys.mass_expr])(0.0, q)
    gap = ca.Function("gap", [sys.q_sym], [sys.gap_expr])(q)
    mu, e = np.asarray(sys.mu, dtype=float), np.asarray(sys.e, dtype=float)
    rhs = ca.SX.zeros(n, 1)
    pairs = []
    for c, tmode, _, _ in impacts:
        PN = tr._var(f"PN{k}_{j}_{c}", 1, 0.0, np.inf, key="PN")
        PT = tr._var(f"PT{k}_{j}_{c}", 1, -np.inf, np.inf, key="PT")
        rhs = rhs + H[c, :].T * PN + H[m + c, :].T * PT
        pairs.append((c, tmode, PN, PT))
    vp = v + ca.solve(Mq, rhs)
    for c, tmode, PN, PT in pairs:
        uN_pre = ca.mtimes(H[c, :], v)
        normal = kept is None or next(held) in kept or tr.check
        if normal:
            tr._constrain(gap[c], 0.0, 0.0)
        tr._constrain(uN_pre, -np.inf, 0.0)
        if normal:
            tr._constrain(ca.mtimes(H[c, :], vp) + e[c] * uN_pre, 0.0, 0.0)
        uT = ca.mtimes(H[m + c, :], vp)
        if tmode == OPEN:  # frictionless
            tr._constrain(PT, 0.0, 0.0)
        elif tmode == STICK:
            if kept is None or next(held) in kept or tr.check:
                tr._constrain(uT, 0.0, 0.0)
            tr._constrain(ca.vertcat(mu[c] * PN - PT, mu[c] * PN + PT), 0.0, np.inf)
        else:
            s = 1.0 if tmode == SLIDE_POS else -1.0
            tr._constrain(PT + s * mu[c] * PN, 0.0, 0.0)
            tr._constrain(s * uT, 0.0, np.inf)
    return ca.vertcat(q, vp)


def pair_zeros(pb, result) -> list:
    """Which member of each user complementarity pair is zero, per pair, step and row, in
    ``result`` (the smaller one): the phase sequence of the pairs, kept by the shooting."""
    from lcp.ocp.pairs import pair_values

    u = np.asarray(result.u, dtype=float)
    out = [[] for _ in pb.complementarity]
    for k in range(len(result.t) - 1):
        j = 2 * k if pb.hold == "affine" else k
        ua, ub = u[j], u[j] if pb.hold == "constant" else u[j + 1]
        st = pb.make_step(k, result.t[k], result.steps[k], result.q[k], result.q[k + 1], result.v[k],
                          result.v[k + 1], ua, ub, result.p_N[k], result.p_T[k])
        for i, (a, b) in enumerate(pair_values(pb.complementarity, st)):
            out[i].append(a <= b)
    return out


#: a user pair's zero member is an equality; where IPOPT then finds too few degrees of freedom
#: (the member is implied by the modes: a block's height while it presses on its floor) it is held
#: within this of zero instead (on the hopper the equalities converge, the band does not)
PAIR_TOL = 1e-10


def fixed_pairs(tr, k, st) -> None:
    """The user pairs at step k of ``tr``'s NLP with the zero member of each row held at zero
    (``tr.zeros``; within ``tr.pair_tol``) and the other nonnegative."""
    for i, (fa, fb) in enumerate(tr.pb.complementarity):
        a, b = ca.vec(ca.SX(fa(st))), ca.vec(ca.SX(fb(st)))
        za = np.asarray(tr.zeros[i][k], dtype=bool)
        for r in range(a.shape[0]):
            zero, other = (a[r], b[r]) if za[r] else (b[r], a[r])
            tr._constrain(zero, -tr.pair_tol, tr.pair_tol)
            tr._constrain(other, 0.0, np.inf)


def _free_forces(tr, modes, keep, points):
    """Least-norm z of the free force directions at the points (t, x, u) of a segment in ``tr``
    (numbers), and the Newton-Cotes integral of Z z per unit duration: the initial point's."""
    n = tr.pb.system.n
    fn = tr.mode_function(modes, keep)
    zs, free = [], 0.0
    for i, (tt, x, uu) in enumerate(points):
        _, lamN, lamT, _, Z, _ = (np.array(o, dtype=float) for o in fn(tt, x[:n], x[n:], uu))
        z = -np.linalg.lstsq(Z, np.concatenate([lamN, lamT]).ravel(), rcond=None)[0]
        zs.append(z)
        free = free + POINT_WEIGHTS[i] * (Z @ z)
    return zs, free


def initial_point(tr, result, states: str = "integrated") -> np.ndarray:
    """The variables of ``tr``'s NLP (:class:`PhaseShooting`) at ``result``'s control and steps, the states integrated segment by
    segment through the plan (single shooting: feasible but for the terminal conditions), or
    with ``states="result"`` the result's own node states (multiple shooting: defects where
    the result's steps were inexact, the terminal conditions met)."""
    pb, ix = tr.pb, tr.ix
    n, m = pb.system.n, pb.system.n_contacts
    x = np.zeros(tr.lbx.size)
    t = np.asarray(result.t, dtype=float)
    if pb.free_time:
        x[ix["T"]] = result.T
    if pb.steps == "free":
        x[ix["h"].ravel()] = np.diff(t)
    u = np.asarray(result.u, dtype=float)
    for i, idx in enumerate(ix["u"]):
        x[idx] = u[i]
    if pb.max_cost is not None:
        x[ix["z"]] = result.peak if np.isfinite(result.peak) else 0.0
    xs = np.concatenate([pb.q0, pb.v0])
    d_i, s_i, p_i, z_i = 0, 0, 0, 0
    for k, segs in enumerate(tr.plan):
        h = t[k + 1] - t[k]
        ua, ub = tr.control_pair(list(u), k)
        t_seg = t[k]
        iN, iT = np.zeros(m), np.zeros(m)
        for j, (modes, dur, impacts) in enumerate(segs):
            if impacts:
                xs = xs.copy()
                xs[n:] = xs[n:] + impulse_dv(pb.system, xs[:n], impacts)
                for j_c, _, pn, pt in impacts:
                    x[ix["PN"][p_i]], x[ix["PT"][p_i]] = pn, pt
                    p_i += 1
            if len(segs) > 1:
                x[ix["d"][d_i]] = dur
                d_i += 1
            start = xs if states == "integrated" or j else np.concatenate([result.q[k], result.v[k]])
            keep = tr.keys[k][j][0]
            out = tr.integrator(modes, keep)(x0=start, p=np.concatenate([[t_seg, dur, t[k], h], ua, ub]))
            xf = np.array(out["xf"])
            xs = xf[:, -1]
            if m:
                qf = np.array(out["qf"])[:, -1]
                iN, iT = iN + qf[:m], iT + qf[m:]
            if keep is not None:  # redundant rows: the least-norm distribution at each point
                times = [t_seg + c * dur for c in (0.0, *GRID)]
                points = [(tt, xx, ua + (tt - t[k]) / h * (ub - ua))
                          for tt, xx in zip(times, [start] + [xf[:, i] for i in range(len(GRID))])]
                zs, free = _free_forces(tr, modes, keep, points)
                for z in zs:
                    x[ix["zf"][z_i]] = z
                    z_i += 1
                iN, iT = iN + dur * free[:m], iT + dur * free[m:]
            if j < len(segs) - 1:
                x[ix["Qs"][s_i]], x[ix["Vs"][s_i]] = xs[:n], xs[n:]
                s_i += 1
            t_seg += dur
        if states == "integrated":
            x[ix["q"][k]], x[ix["v"][k]] = xs[:n], xs[n:]
            x[ix["pN"][k]], x[ix["fT"][k]] = iN / h, iT / h
        else:
            x[ix["q"][k]], x[ix["v"][k]] = result.q[k + 1], result.v[k + 1]
            x[ix["pN"][k]], x[ix["fT"][k]] = result.p_N[k] / h, result.p_T[k] / h
    return x


#: the shortest free step, relative to T / N as ``step_bounds``. The transcriptions keep the
#: problem's floor (0.05: their short steps carried large forces that the replay refused); here a
#: step is integrated exactly, so a step the optimum does not need shrinks to almost nothing, as a
#: phase does. Jean-Pratt minimum time at R = 1.0 (N = 40): the last two steps sat on the floor,
#: braking past the stop and sliding back, 4.1e-5 above the optimum; with this floor, 1.3e-9
STEP_FLOOR = 1e-6

#: Runge-Kutta steps per grid interval of the shooting NLP, and the most tried. The deferred
#: correction, not the step count, sets the accuracy; the count sets the cost of an iteration and
#: of the NLP's build: 4 instead of 8 took 20-25 % off the motor, the two-block chain and the seven
#: blocks at the same optima; 2 left the box and the hopper (N = 20) failing their replays
RK_SUBSTEPS, RK_SUBSTEPS_MAX = 4, 128
#: the steps of a second try where the first NLP's solve fails (before any solution of its own)
RK_SUBSTEPS_SAFE = 8
#: the mode conditions' tolerance of a shooting solution (the admissibility of every segment's
#: modes, its switches, the user's constraints): a solution above it is not taken
MODE_TOL = 1e-8
#: defect corrections tried on one Runge-Kutta NLP before its steps are refined
CORRECTIONS = 6
#: most IPOPT iterations of a warm-started correction before it is solved again cold (from the
#: same point). Warm starts near the previous solution (a barrier of 1e-8) usually finish in a few
#: iterations; where the correction moves an active bound they can stall: the two discs (N = 30),
#: warm corrections of 500, 344 and 500 iterations (70 s of the round's 83 s) where the cold solves
#: of the same NLPs took 11 to 35
WARM_MAX_ITER = 40
#: most IPOPT iterations of a cold solve that starts from a solution of the same NLP (a stalled
#: warm correction's retry) or of a coarser one (the refined steps' NLP). Such solves took 11 to 35
#: iterations where they converged (the two discs, N = 30); where they did not, they ran to the
#: iteration limit: the cart-pole at N = 40, a retry of 500 iterations (54 s) and a refined NLP of
#: 500 (139 s), both failed. With the cap the cart-pole took 157 s instead of 254 s (side by side,
#: both loaded) for the same result; the two discs, the box, the hopper and the seven blocks ended
#: at the same costs in the same iterations
NEAR_MAX_ITER = 150
#: the barrier parameter a warm-started correction starts from, decreased monotonically. Measured on
#: the two discs at N = 30 against the adaptive barrier (mu_init 1e-8, inert): the first round's
#: correction took 11 IPOPT iterations instead of 40 stalled ones and a cold solve; the second
#: round's solves 42, 40 (stalled) and 12 instead of 117 (failed), 70, 40 (stalled) and 175; the
#: whole solve 9.8 s instead of 28 s, at 204.268179 (replay 2.0e-11) instead of 204.268489. From
#: 1e-5 the rounds went as under the adaptive barrier; from 1e-7 9.5 s, 204.268214. The motor,
#: the chains, the box, the hopper, the cart-pole and the seven blocks ended at the same costs
WARM_MU = 1e-6


def solve_shooting(pb, result, start: str = "replay", defect_tol: float = 1e-9, options: dict | None = None,
                   plan=None):
    """The shooting polish of ``result`` (module docstring): (x, cost, diag, IPOPT's stats, time,
    the NLP whose ``diagnose`` gave ``diag``).

    The NLP integrates each phase by the classical Runge-Kutta method on fixed steps (an SX
    function: exact first and second derivatives, IPOPT converges in tens of iterations). Its
    solution is checked by CVODES at rtol 1e-12 (``diag["dynamics"]``: the largest defect), and
    the difference between the two integrators' outputs at that solution (the states at every
    check point, the force integrals) is added to the Runge-Kutta outputs as a parameter (deferred
    correction): the next solve, warm-started, lands where the accurate integrator's phases join
    and its states meet the mode conditions at the check points inside the segments. While the
    defect exceeds ``defect_tol`` or the mode conditions :data:`MODE_TOL`: up to
    :data:`CORRECTIONS` corrections while each halves them; then, for the defect, finer steps
    (order 4: by (defect / tol)^(1/4)), up to
    :data:`RK_SUBSTEPS_MAX` per grid interval. ``start="replay"``: the phases and states of the
    event replay of ``result``'s control (a feasible start); ``"result"``: ``result``'s own modes
    and states (on ``plan`` where given, as :func:`~lcp.ocp.plans.hybrid_plan` makes it, else on
    its modes). Where IPOPT fails on an NLP (before any solution of it) whose last iterate shrinks
    segments below :data:`~lcp.ocp.plans.PRUNE_TOL` of their interval, the NLP is solved again on
    the plan without them (:func:`~lcp.ocp.plans.pruned_plan`; ``stats["pruned"]`` counts the
    segments removed). Raises :class:`NotShootable` where the shooting does not apply."""
    refuse(pb)
    if plan is not None and start != "result":
        raise ValueError("a plan is solved from the result's own states: start='result'")
    plan = phase_plan(result) if start == "replay" else plan if plan is not None else plan_of_modes(result)
    t0 = time.perf_counter()
    zeros = pair_zeros(pb, result) if pb.complementarity else None
    states = "integrated" if start == "replay" else "result"
    keys = plan_keys(pb, plan, result, states)  # redundant rows dropped (at the walk's states)
    # CVODES: the initial point, the check of every solution
    check = PhaseShooting(pb, plan, check=True, zeros=zeros, keys=keys)
    x = initial_point(check, result, states)
    ip = {"print_level": 0, "sb": "yes", "tol": 1e-10, "constr_viol_tol": 1e-10, "max_iter": 500,
          "mu_strategy": "adaptive", "bound_relax_factor": 0.0, **(options or {})}
    # a monotone barrier from WARM_MU for the warm starts: under the adaptive strategy the start's
    # own complementarity sets the first barrier (mu_init is inert), and the corrections stalled
    warm_ip = {**ip, "warm_start_init_point": "yes", "mu_strategy": "monotone", "mu_init": WARM_MU,
               "warm_start_bound_push": 1e-9, "warm_start_mult_bound_push": 1e-9,
               "max_iter": min(int(ip["max_iter"]), WARM_MAX_ITER)}
    # a cold solve from a solution (a stalled correction's retry, the refined steps' NLP) is capped
    near_ip = {**ip, "max_iter": min(int(ip["max_iter"]), NEAR_MAX_ITER)}
    M, iters, warm, diag, ok, stats, pair_tol = RK_SUBSTEPS, 0, {}, None, False, {}, 0.0
    cost, solved, pruned = float("nan"), False, 0
    while True:
        tr = PhaseShooting(pb, plan, substeps=M, zeros=zeros, pair_tol=pair_tol, keys=keys, like=check)
        solvers = {}
        C = np.zeros(tr.n_corrections)
        last, last_err, good = np.inf, np.inf, None
        for _ in range(CORRECTIONS + 1):
            for key in (("warm", "near") if warm else ("near" if solved else "cold",)):
                if key not in solvers:
                    solvers[key] = ca.nlpsol("shooting", "ipopt", tr.nlp,
                                             {"print_time": False, "show_eval_warnings": False,
                                              "ipopt": {"warm": warm_ip, "near": near_ip, "cold": ip}[key]})
                solver = solvers[key]
                sol = solver(x0=np.clip(x, tr.lbx, tr.ubx), lbx=tr.lbx, ubx=tr.ubx, lbg=tr.lbg, ubg=tr.ubg,
                             p=tr.params(C), **(warm if key == "warm" else {}))
                stats = solver.stats()
                iters += int(stats["iter_count"])
                ok = stats["return_status"] in ("Solve_Succeeded", "Solved_To_Acceptable_Level")
                if ok:
                    break
                # a warm-started correction that stalls is solved again from the same point with
                # IPOPT's own barrier start (WARM_MAX_ITER)
            if not ok and good is not None:
                # a correction's solve failed: keep the last solution (then finer steps), as when a
                # correction no longer halves the defect (the two discs, N = 30: the first solve's
                # defect 3.7e-8, the correction's warm solve ended in IPOPT's Error_In_Step_Computation)
                stats, ok = good, True
                break
            if not ok:
                break
            good, solved = stats, True
            x, cost = np.array(sol["x"]).ravel(), float(sol["f"])
            warm = {"lam_x0": sol["lam_x"], "lam_g0": sol["lam_g"]}
            out = check.outputs(x)  # (one CVODES pass: the check's constraints and the correction)
            g = check.constraints(x, out)
            diag = check.diagnose(x, g)
            # the joins to defect_tol and the mode conditions at the check points to MODE_TOL
            err = max(diag["dynamics"] / defect_tol, diag["residual"] / MODE_TOL)
            if err <= 1.0 or err > 0.5 * last_err:
                break  # (met, or no longer halved by a correction)
            last, last_err = diag["dynamics"], err
            C = out - tr.outputs(x)
        if not ok and stats["return_status"] == "Not_Enough_Degrees_Of_Freedom" and zeros and not pair_tol:
            pair_tol, warm = PAIR_TOL, {}  # pair members implied by the modes: held in a band
            check = PhaseShooting(pb, plan, check=True, zeros=zeros, pair_tol=pair_tol, keys=keys)
            continue
        cut = pruned_start(pb, tr, np.array(sol["x"]).ravel()) if not ok and good is None else None
        if cut is not None:
            # segments that shrank to zero: their conditions at coinciding points repeat each
            # other, and IPOPT's multipliers grew without bound (the two discs, N = 60: 4e8 at the
            # iteration limit; without those three segments solved in 15 iterations). Each such
            # solve removes at least one segment: this ends
            plan, keys, removed, it = cut
            pruned += removed
            check = PhaseShooting(pb, plan, check=True, zeros=zeros, pair_tol=pair_tol, keys=keys)
            x, warm = initial_point(check, it), {}
            continue
        if not ok and good is None and M < RK_SUBSTEPS_SAFE:
            # the coarser steps' NLP did not converge from this start: once more on finer steps
            # (the convex obstacle, N = 40: at 4 steps IPOPT's iteration limit, at 8 solved)
            M, warm = RK_SUBSTEPS_SAFE, {}
            continue
        if not ok or diag["dynamics"] <= defect_tol or M >= RK_SUBSTEPS_MAX:
            # (not refined for the mode conditions at the interior check points: the correction
            # reaches them. Doubling the steps there, tried before the correction did, solved the
            # hopper's first round at N = 40 (1.8e-8 -> 3.9e-10; its replay then missed by 2.6e-6),
            # but took the cart-pole at N = 20 through three rounds to worse optima, 10 s -> 220 s)
            break
        M = min(RK_SUBSTEPS_MAX, int(np.ceil(1.2 * M * (diag["dynamics"] / max(last, defect_tol)) ** 0.25 + M)))
        warm = {}
    stats = {**stats, "iter_count": iters, "pruned": pruned}
    return x, cost, diag if diag is not None else check.diagnose(x), stats, time.perf_counter() - t0, check
