"""Radau IIA collocation inside each step of the optimal-control transcription (``integrator="radau"``).

The theta = 1/2 step of :mod:`lcp.ocp.transcription` is exact for forces constant over a step (the
Jean-Pratt block) but only second order on smooth nonlinear or stiff dynamics. Here each step k
(length h_k, from node k to node k + 1) carries s collocation stages at t_k + c_j h_k, the nodes
c_1 < ... < c_s = 1 of Radau IIA (computed from the Legendre polynomials, with the Butcher matrix
A_jl = int_0^{c_j} l_l, l_l the Lagrange basis on the nodes), and the stage states (Q_kj, V_kj)
satisfy, for j = 1..s,

    sum_l Ainv_jl (Q_kl - q_k) = h_k V_kj,
    M(t_kj, Q_kj) sum_l Ainv_jl (V_kl - v_k) = h_k (F(t_kj, Q_kj, V_kj, u(t_kj)) + H(Q_kj)' f_kj),

where Ainv = A^-1 and the last stage is the node k + 1 (stiffly accurate: Q_ks = q_{k+1},
V_ks = v_{k+1}); u(t_kj) is the hold's control at the stage time (constant: u_k; linear and
affine: the step's start and end values mixed by c_j). Order 2s - 1 at the nodes for smooth
dynamics (s = 1: implicit Euler; s = 2: order 3; s = 3: order 5), stiffly stable (the motor's
electrical time constant).

Contacts: the velocity law at every stage. Each stage has the step's complementarity pairs
(:data:`lcp.ocp.transcription.PAIRS`) with forces as unknowns (f = (N, beta+ - beta-)) against the
stage's contact velocities u = H(Q_kj) V_kj::

    0 <= N perp u_N >= 0,  0 <= beta+ perp lambda + u_T >= 0,  0 <= beta- perp lambda - u_T >= 0,
    0 <= lambda perp mu N - beta+ - beta- >= 0,

so a closed contact has u_N = 0 at every stage (the velocity level: index 2, order 2s - 1 in q
and v). With ``steps="free"`` the FESD cross complementarity (Nurkanovic et al. 2024) holds
between all stages of a step (a multiplier of stage j against the slack of every other stage l of
the same step), so a step is one mode, and between every stage of step k and the last stage of
step k - 1 (as the theta transcription's cross pairs), so that the switches fall on nodes and the
step lengths place them; the fixed-phase solve (:func:`fixed_mode_bounds`) then fixes one member
of each pair for all stages of a step at once. At a stick-to-slide switch it replaces the stick-to-slide
pair of :data:`STEP_CROSS` (which wants the stick force at the cone at the end of the stick step) by
the stick force at the node under the sliding step's own control (``wsp``, ``wsm``): the control may
jump at a node. A slide in step 0 that cannot start at t = 0 is preceded by a stick step, and a phase
left on minimum-length steps is merged into its neighbour (:func:`squeezed_phases`). Uniform steps keep each stage's own pairs only (a
switch may fall inside a step, between stages, as in plain collocation).

The impulse of a step handed to the costs and the replay is h_k sum_j b_j f_kj (b the last row of
A). Not modelled (refused by name in :class:`~lcp.ocp.problem.OptimalControlProblem`): the gap law
(contacts that start open, impulses at nodes), restitution, bilateral constraints and spatial
contacts.

Imports CasADi, NumPy, :mod:`lcp.contact.problem` and the theta transcription (whose NLP
bookkeeping it reuses); it must not import the solve, the problem or the complementarity module
(they call it).
"""
from __future__ import annotations

import time

import casadi as ca
import numpy as np

from lcp.contact.problem import ContactProblem
from lcp.ocp.transcription import PAIRS, Transcription, contact_blocks, friction_rows, grid_variables, pair_rows

__all__ = ["RADAU_STAGES", "RadauTranscription", "fixed_mode_bounds", "radau_tableau"]

#: the numbers of stages offered (s = 1 is implicit Euler)
RADAU_STAGES = (1, 2, 3, 4)
#: cross pairs between steps (step k's member, step k - 1's last stage's member): the theta
#: transcription's, and (lam, wl): a contact that slides in step k after sticking in step k - 1
#: starts sliding only where its stick force has reached the cone (wl = 0 at the node; the last
#: stage is the node, whereas the theta step's wl is a mean over its step); for k >= 1 its slack is
#: multiplied by a variable ``gate`` held at 1, which the fixed-phase bounds set to 0 where they
#: bound the stick margin at the node instead
STEP_CROSS = (("pN", "wN"), ("bp", "wp"), ("bm", "wm"), ("wl", "lam"), ("lam", "wl"))


def radau_tableau(s: int):
    """(c, A, b) of the s-stage Radau IIA method.

    Examples
    --------
    >>> from lcp.ocp.collocation import radau_tableau
    >>> c, A, b = radau_tableau(2)
    >>> [round(float(x), 12) for x in c], [round(float(x), 12) for x in A[0]]
    ([0.333333333333, 1.0], [0.416666666667, -0.083333333333])
    """
    if s not in RADAU_STAGES:
        raise ValueError(f"stages must be one of {RADAU_STAGES}, got {s!r}")
    # the right Radau nodes: zeros of P_s(2x - 1) - P_{s-1}(2x - 1)
    coef = np.zeros(s + 1)
    coef[s], coef[s - 1] = 1.0, -1.0
    c = np.sort((np.real(np.polynomial.legendre.legroots(coef)) + 1.0) / 2.0)
    c[-1] = 1.0
    A = np.zeros((s, s))
    P = np.polynomial.Polynomial
    for l_ in range(s):
        basis = P([1.0])
        for m_ in range(s):
            if m_ != l_:
                basis = basis * P([-c[m_], 1.0]) / (c[l_] - c[m_])
        integral = basis.integ()
        A[:, l_] = integral(c) - integral(0.0)
    return c, A, A[-1].copy()


class RadauTranscription(Transcription):
    """The NLP of an :class:`~lcp.ocp.OptimalControlProblem` with Radau IIA collocation in each step.

    Same interface as :class:`~lcp.ocp.transcription.Transcription` (``nlp``, ``ix``, bounds,
    :meth:`unpack`, :meth:`impulses`); the contact blocks of ``ix`` have one row per stage
    (N s rows, step-major), and the stage states ``Qs``, ``Vs`` one per interior stage.
    """

    def __init__(self, pb):
        self.stages = int(pb.stages)
        self.c, self.A, self.b = radau_tableau(self.stages)
        super().__init__(pb)

    def _build(self):  # noqa: C901 (one pass over the steps, as the theta transcription's)
        t_start = time.perf_counter()
        pb = self.pb
        sys, N, n, nu, s = pb.system, pb.N, pb.system.n, pb.nu, self.stages
        m = sys.n_contacts
        mu = ca.DM(sys.mu)
        c, Ainv = self.c, np.linalg.inv(self.A)
        sigma, q0p, v0p, Tv, z, hs, us, qs, vs, tk = grid_variables(self)
        t, q, v, u = sys.t_sym, sys.q_sym, sys.v_sym, ca.SX.sym("u", nu)
        stage_fn = ca.Function("radau_stage", [t, q, v, u],
                               [sys.mass_expr, sys.force_expr + ca.mtimes(sys.control_matrix_expr, u), sys.H_expr])
        J, pair_sizes, dyn, stage_out = ca.SX(0), {}, [], []
        prev = None
        if self.cross:  # the start state's slacks stand for the "previous step" of step 0
            H0 = ca.Function("H0", [q], [sys.H_expr])(q0p)
            uN0, uT0 = ca.mtimes(H0[:m, :], v0p), ca.mtimes(H0[m:, :], v0p)
            prev = {"wN": uN0, "wp": ca.fabs(uT0) + uT0, "wm": ca.fabs(uT0) - uT0, "lam": ca.fabs(uT0),
                    "wl": self._start_margin(stage_fn, q0p, v0p, self.control_pair(us, 0)[0])}
        for k in range(N):
            h = hs[k]
            ua, ub = self.control_pair(us, k)
            qa, va = qs[k], vs[k]
            Q = [self._var(f"Q{k}_{j}", n, -np.inf, np.inf, key="Qs") for j in range(s - 1)] + [qs[k + 1]]
            V = [self._var(f"V{k}_{j}", n, -np.inf, np.inf, key="Vs") for j in range(s - 1)] + [vs[k + 1]]
            blks = []
            for j in range(s):
                tj, uj = tk[k] + c[j] * h, ua + c[j] * (ub - ua)
                Mj, Fj, Hj = stage_fn(tj, Q[j], V[j], uj)
                dq = sum(Ainv[j, l_] * (Q[l_] - qa) for l_ in range(s))
                dv = sum(Ainv[j, l_] * (V[l_] - va) for l_ in range(s))
                force = Fj
                if m:
                    blk = contact_blocks(self, [nm for a_w in PAIRS for nm in a_w], f"{k}_{j}")
                    force = force + ca.mtimes(Hj.T, ca.vertcat(blk["pN"], blk["bp"] - blk["bm"]))
                    uN, uT = ca.mtimes(Hj[:m, :], V[j]), ca.mtimes(Hj[m:, :], V[j])
                    self._constrain(blk["wN"] - uN, 0.0, 0.0)
                    # (a frictionless contact's friction blocks are fixed at zero, in no constraint)
                    self._constrain(friction_rows(self, blk["wp"] - (blk["lam"] + uT)), 0.0, 0.0)
                    self._constrain(friction_rows(self, blk["wm"] - (blk["lam"] - uT)), 0.0, 0.0)
                    self._constrain(friction_rows(self, blk["wl"] - (mu * blk["pN"] - blk["bp"] - blk["bm"])), 0.0, 0.0)
                    blks.append(blk)
                res = ca.vertcat(dq - h * V[j], ca.mtimes(Mj, dv) - h * force)
                self._constrain(res, 0.0, 0.0)
                dyn.append(res)
                stage_out.append(ca.vertcat(tj, h, Q[j], V[j]))
            pN = pT = ca.SX.zeros(0, 1)
            if m:
                a, w = [], []
                if self.cross and k:  # the stick-to-slide pair's gate (see fixed_mode_bounds)
                    prev = {**prev, "wl": self._var(f"gate{k}", m, 1.0, 1.0, key="gate") * prev["wl"]}
                for j in range(s):  # each stage's own pairs; with free steps every other stage's slacks
                    # too (one mode per step: uniform steps keep a switch inside a step possible)
                    for l_ in (range(s) if self.cross else (j,)):
                        a += [pair_rows(self, x, blks[j][x]) for x, _ in PAIRS]
                        w += [pair_rows(self, x, blks[l_][y]) for x, y in PAIRS]
                    if self.cross:
                        a += [pair_rows(self, x, blks[j][x]) for x, _ in STEP_CROSS]
                        w += [pair_rows(self, x, prev[y]) for x, y in STEP_CROSS]
                if self.cross:
                    prev = blks[-1]
                self._constrain(ca.vertcat(*a) * ca.vertcat(*w) - sigma, -np.inf, 0.0)  # Scholtes
                pN = h * sum(self.b[j] * blks[j]["pN"] for j in range(s))
                pT = h * sum(self.b[j] * (blks[j]["bp"] - blks[j]["bm"]) for j in range(s))
            st = pb.make_step(k, tk[k], h, qa, qs[k + 1], va, vs[k + 1], ua, ub, pN, pT)
            J = self._step_terms(J, st, us, k, h, ua, ub, z, sigma, pair_sizes)
        if self.cross and m:
            for k in range(1, N):  # the stick margins at node k under step k's control (fixed-phase bounds)
                fs = self._stick_forces(stage_fn, tk[k], qs[k], vs[k], self.control_pair(us, k)[0])
                for key, sign in (("wsp", -1.0), ("wsm", 1.0)):
                    var = self._var(f"{key}{k}", m, -np.inf, np.inf, key=key)
                    self._constrain(var - (mu * fs[:m] + sign * fs[m:]), 0.0, 0.0)
        J = self._terminal_terms(J, Tv, qs, vs, z)
        g = ca.vertcat(*self._g) if self._g else ca.SX.zeros(0, 1)
        self.nlp = {"x": ca.vertcat(*self._x), "f": J, "g": g, "p": ca.vertcat(sigma, q0p, v0p)}
        #: (x, p) -> (the collocation residuals, the stages' (t, h, Q, V) as columns)
        self.stage_eval = ca.Function("radau_eval", [self.nlp["x"], self.nlp["p"]],
                                      [ca.vertcat(*dyn), ca.horzcat(*stage_out)])
        self.aux = ca.Function("aux", [self.nlp["x"], self.nlp["p"]], [ca.horzcat(*vs[:-1])])
        if self.cross and m:  #: (x, p) -> wl0 (the start's stick margin; see fixed_mode_bounds)
            self.margin0 = ca.Function("margin0", [self.nlp["x"], self.nlp["p"]], [self._margin0])
            del self._margin0
        self.ix = {key: np.array(val) for key, val in self.ix.items()}
        self.lbx, self.ubx = np.concatenate(self._lbx), np.concatenate(self._ubx)
        self.lbg = np.concatenate(self._lbg) if self._lbg else np.zeros(0)
        self.ubg = np.concatenate(self._ubg) if self._ubg else np.zeros(0)
        del self._x, self._g, self._lbx, self._ubx, self._lbg, self._ubg, self._nx
        self.build_time = time.perf_counter() - t_start

    def _start_margin(self, stage_fn, q0p, v0p, u0):
        """The variable ``wl0`` = mu f_N - |f_T| of the forces that hold every contact closed and stuck at
        t = 0 (the acceleration-level law), for the contacts that start at rest tangentially (0 for
        the others): a contact that slides in step 0 must start sliding there, wl0 <= 0, through the
        pair (lam, wl) of :data:`STEP_CROSS` (relaxed as lam wl0 <= sigma: wl0 may be negative)."""
        sys, m = self.pb.system, self.pb.system.n_contacts
        f = self._stick_forces(stage_fn, 0.0, q0p, v0p, u0)
        at_rest = np.abs(sys.contact_jacobian(self.pb.q0)[m:] @ self.pb.v0) == 0.0
        wl0 = self._var("wl0", m, -np.inf, np.inf, key="wl0")
        self._margin0 = ca.DM(at_rest.astype(float)) * (ca.DM(sys.mu) * f[:m] - ca.fabs(f[m:]))
        self._constrain(wl0 - self._margin0, 0.0, 0.0)
        return wl0

    def _stick_forces(self, stage_fn, t, q, v, u):
        """The contact forces (normal, tangential) that keep every contact closed and stuck at (t, q, v)
        under the control value u (the acceleration-level law, every contact stuck)."""
        sys, m = self.pb.system, self.pb.system.n_contacts
        Mq, F, H = stage_fn(t, q, v, u)
        Hv = ca.mtimes(sys.H_expr, sys.v_sym)
        drift = ca.Function("Hdot_v", [sys.q_sym, sys.v_sym], [ca.jtimes(Hv, sys.q_sym, sys.v_sym)])(q, v)
        W = ca.mtimes(H, ca.solve(Mq, H.T))
        # (a tiny Tikhonov term: redundant contacts, a box's corners on a floor, leave W singular;
        # the stick forces are then not unique and this picks the smallest)
        W = W + 1e-12 * ca.trace(W) * ca.DM.eye(2 * m)
        return -ca.solve(W, ca.mtimes(H, ca.solve(Mq, F)) + drift)

    # ------------------------------------------------------------------ numbers out of x
    def _stage_forces(self, x):
        """(N, s, m) normal and tangential stage forces."""
        N, m, s, ix = self.pb.N, self.pb.system.n_contacts, self.stages, self.ix
        fN = x[ix["pN"]].reshape(N, s, m)
        fT = (x[ix["bp"]] - x[ix["bm"]]).reshape(N, s, m)
        return fN, fT

    def step_impulses(self, x, steps):
        """(p_N, p_T), shape (N, m): h_k sum_j b_j f_kj of the stage forces."""
        fN, fT = self._stage_forces(x)
        return (steps[:, None] * np.einsum("j,kjc->kc", self.b, fN),
                steps[:, None] * np.einsum("j,kjc->kc", self.b, fT))

    def impulses(self, x):
        """No impulses at the nodes (the velocity law): zeros of shape (N, 0)."""
        N = self.pb.N
        return np.zeros((N, 0)), np.zeros((N, 0))

    def x0_law(self, x0, gs, steps) -> None:
        """Fill the stage states (interpolated between the guess's nodes) and the stage contact
        variables (the guess's mean forces, the slacks from the interpolated velocities)."""
        fill_x0(self, x0, gs, steps)

    def fixed_mode_bounds_law(self, x):
        return fixed_mode_bounds(self, x)

    def squeezed_phases_law(self, x):
        return squeezed_phases(self, x)

    def diagnose_law(self, x) -> dict:
        return diagnose(self, x)


def fill_x0(tr, x0, gs, steps) -> None:
    """:meth:`RadauTranscription.x0_law` (see there)."""
    pb, ix, s = tr.pb, tr.ix, tr.stages
    sys, N, m = pb.system, pb.N, pb.system.n_contacts
    mu = sys.mu
    for k in range(N):
        for j in range(s):
            qj = (1 - tr.c[j]) * gs.q[k] + tr.c[j] * gs.q[k + 1]
            vj = (1 - tr.c[j]) * gs.v[k] + tr.c[j] * gs.v[k + 1]
            if j < s - 1:
                x0[ix["Qs"][k * (s - 1) + j]] = qj
                x0[ix["Vs"][k * (s - 1) + j]] = vj
            if not m:
                continue
            H = sys.contact_jacobian(qj)
            uN, uT = H[:m] @ vj, H[m:] @ vj
            fN, fT = np.maximum(gs.p_N[k], 0.0) / steps[k], gs.p_T[k] / steps[k]
            bp, bm, lam = np.maximum(fT, 0.0), np.maximum(-fT, 0.0), np.abs(uT)
            vals = {"pN": fN, "bp": bp, "bm": bm, "lam": lam, "wN": np.maximum(uN, 0.0),
                    "wp": np.maximum(lam + uT, 0.0), "wm": np.maximum(lam - uT, 0.0),
                    "wl": np.maximum(mu * fN - bp - bm, 0.0)}
            for nm, val in vals.items():
                x0[ix[nm][k * s + j]] = val


def _blocks(tr, x, name):
    """Variable indices and values of a stage-shaped block: (N, s, m) each."""
    N, m, s = tr.pb.N, tr.pb.system.n_contacts, tr.stages
    idx = tr.ix[name].reshape(N, s, m)
    return idx, x[idx]


def fixed_mode_bounds(tr, x):
    """Variable bounds with the mode of every step frozen as at ``x``: for each pair and contact of a
    step, the member that is smaller over the step's stages (its largest value) is fixed at zero at
    every stage (the within-step cross complementarity makes a step one mode); with free steps also
    the smaller of step k's multiplier and step k - 1's last-stage slack, and at a stick-to-slide
    switch the stick margin at the node under the sliding step's control (see the comments)."""
    lbx, ubx = tr.lbx.copy(), tr.ubx.copy()
    if not tr.pb.system.n_contacts:
        return lbx, ubx
    for a, w in PAIRS:
        ia, xa = _blocks(tr, x, a)
        iw, xw = _blocks(tr, x, w)
        if not tr.cross:  # uniform steps: stage by stage
            a_small = xa <= xw
            ubx[ia[a_small]] = 0.0
            ubx[iw[~a_small]] = 0.0
            continue
        a_small = np.max(xa, axis=1) <= np.max(xw, axis=1)  # (N, m)
        ubx[ia.transpose(0, 2, 1)[a_small]] = 0.0
        ubx[iw.transpose(0, 2, 1)[~a_small]] = 0.0
        if a == "lam":
            slides = ~a_small  # (N, m): the steps whose contact slides (lam free, wl fixed at zero)
    if not tr.cross:
        return lbx, ubx
    # a step that slides after a stick starts at the cone: its stick-to-slide pair fixes the slack
    # (wl0 at t = 0, the previous step's last wl after it) by the step's mode, not by comparing a
    # speed with a force (a slide that starts slowly would otherwise be frozen at rest)
    # a slide in step 0 from a rest whose stick margin at t = 0 is positive under the guess's control
    # cannot start at t = 0 (the theta first pass's modes are means over its steps: its step 0
    # slides when the force reaches the cone within it, the motor's current building up): step 0
    # sticks instead, and the slide starts at node 1, placed by the step lengths
    P = np.concatenate([[0.0], tr.pb.q0, tr.pb.v0])
    late = slides[0] & (np.array(tr.margin0(x, P), dtype=float).ravel() > 0.0)
    if np.any(late):
        ilam, iwl = _blocks(tr, x, "lam")[0][0], _blocks(tr, x, "wl")[0][0]  # (s, m)
        ubx[ilam[:, late]] = 0.0
        ubx[iwl[:, late]] = tr.ubx[iwl[:, late]]
        slides = slides.copy()
        slides[0] &= ~late
    i0 = tr.ix["wl0"].reshape(-1)
    ubx[i0[slides[0]]] = 0.0
    if tr.pb.N > 1:
        # after a stick, the stick force under the sliding step's own control, at the node, must
        # reach the cone in the slide's direction (wsp, wsm <= 0), and the homotopy's pair (lam of
        # step k against the previous step's last wl, gated by a variable held at 1) is switched
        # off (gate 0): the control may jump at the node, and requiring wl = 0 at the end of the
        # stick step forces that step to ramp its control up to the cone (wasted effort on a
        # minimum-length step per stick-to-slide switch; with a constant hold the whole stick step
        # at the cone)
        loaded = np.max(_blocks(tr, x, "pN")[1], axis=1) > np.max(_blocks(tr, x, "wN")[1], axis=1)
        starts = slides[1:] & ~slides[:-1] & loaded[1:]  # (N - 1, m)
        neg = np.max(_blocks(tr, x, "bm")[1], axis=1) > np.max(_blocks(tr, x, "bp")[1], axis=1)
        isp, ism = tr.ix["wsp"].reshape(-1, tr.pb.system.n_contacts), tr.ix["wsm"].reshape(-1, tr.pb.system.n_contacts)
        ubx[isp[starts & ~neg[1:]]] = 0.0
        ubx[ism[starts & neg[1:]]] = 0.0
        ig = tr.ix["gate"].reshape(-1, tr.pb.system.n_contacts)
        lbx[ig[starts]] = ubx[ig[starts]] = 0.0
        for a, w in STEP_CROSS[:-1]:
            ia, xa = _blocks(tr, x, a)
            iw, xw = _blocks(tr, x, w)
            a_small = np.max(xa[1:], axis=1) <= xw[:-1, -1]  # (N - 1, m)
            ubx[ia[1:].transpose(0, 2, 1)[a_small]] = 0.0
            ubx[iw[:-1, -1][~a_small]] = 0.0
    return lbx, ubx


def _signature(tr, x):
    """(N, m, 4) booleans: which member of each pair of :data:`PAIRS` is the larger over a step's stages."""
    return np.stack([np.max(_blocks(tr, x, a)[1], axis=1) > np.max(_blocks(tr, x, w)[1], axis=1)
                     for a, w in PAIRS], axis=-1)


def squeezed_phases(tr, x):
    """A start for another fixed-phase solve, or None: every step at its lower length bound whose mode
    differs from a neighbour's takes that neighbour's contact variables (the following step's first).

    The first pass's modes are means over its uniform steps: a switch inside one of its steps may
    leave a step of a phase that the optimum does not have, which the fixed-phase solve can only
    shrink to the minimum length (measured: the Jean-Pratt move-and-hold at N = 40 slid back one
    minimum step late, 0.103 above the optimum)."""
    pb, m = tr.pb, tr.pb.system.n_contacts
    if pb.steps != "free" or not m or pb.N < 2:
        return None
    ih = tr.ix["h"].reshape(-1)
    at_lo = x[ih] <= tr.lbx[ih] * (1.0 + 1e-6)
    sig = _signature(tr, x)
    x_new, changed = x.copy(), False
    for k in np.flatnonzero(at_lo):
        for nb in (k + 1, k - 1):
            if not 0 <= nb < pb.N:
                continue
            diff = np.any(sig[k] != sig[nb], axis=-1)  # (m,)
            if np.any(diff):
                for a_w in PAIRS:
                    for nm in a_w:
                        idx = _blocks(tr, x, nm)[0]
                        x_new[idx[k][:, diff]] = x[idx[nb][:, diff]]
                changed = True
                break
    return x_new if changed else None


def diagnose(tr, x) -> dict:
    """Coulomb residual (impulse units: each stage's law as a :class:`ContactProblem` with the
    stage's Delassus operator h H M^-1 H'), collocation residual and modes (the last stage's) per
    step, and the largest complementarity product and min-residual of the own and cross pairs."""
    pb = tr.pb
    N, n, m, s = pb.N, pb.system.n, pb.system.n_contacts, tr.stages
    P = np.concatenate([[0.0], pb.q0, pb.v0])
    dyn, out = tr.stage_eval(x, P)
    dyn_res = float(np.max(np.abs(np.array(dyn, dtype=float)), initial=0.0))
    modes = np.full((N, m), -1, dtype=np.int8)
    empty = {"residual": 0.0, "dynamics": dyn_res, "modes": modes, "conflicts": 0, "max_product": 0.0,
             "lcp": 0.0, "cross": 0.0, "where": ""}
    if not m:
        return empty
    out = np.array(out, dtype=float)  # (2 + 2n, N s)
    mu = pb.system.mu
    fN, fT = _stage_forces_of(tr, x)
    step_res = np.zeros(N)
    for k in range(N):
        for j in range(s):
            col = out[:, k * s + j]
            tj, h, Q, V = col[0], col[1], col[2:2 + n], col[2 + n:]
            Mq, H, _ = (np.array(a, dtype=float) for a in tr.kin(tj, Q))
            W = h * H @ np.linalg.solve(Mq, H.T)
            p = h * np.concatenate([fN[k, j], fT[k, j]])
            cp = ContactProblem(W, H @ V - W @ p, mu)
            step_res[k] = max(step_res[k], cp.residual(p))
            if j == s - 1:
                modes[k] = cp.modes(p, rtol=1e-6)
    own_a, own_w, cr_a, cr_w = [], [], [], []
    for a, w in PAIRS:
        xa, xw = _blocks(tr, x, a)[1], _blocks(tr, x, w)[1]
        own_a.append(xa.ravel())
        own_w.append(xw.ravel())
        if tr.cross:  # every stage against every other stage of its step
            other = ~np.eye(s, dtype=bool).ravel()
            cr_a.append(np.repeat(xa, s, axis=1)[:, other].ravel())
            cr_w.append(np.tile(xw, (1, s, 1))[:, other].ravel())
    if tr.cross:
        cr_a.append(_blocks(tr, x, "lam")[1][0].ravel())
        cr_w.append(np.tile(np.maximum(x[tr.ix["wl0"].reshape(-1)], 0.0), s))
    if tr.cross and N > 1:
        for a, w in STEP_CROSS:
            xa, xw = _blocks(tr, x, a)[1], _blocks(tr, x, w)[1]
            prev = xw[:-1, -1:]
            if (a, w) == ("lam", "wl"):  # or the stick force under step k's control reached the cone
                margin = np.minimum(x[tr.ix["wsp"]], x[tr.ix["wsm"]]).reshape(N - 1, 1, m)
                prev = np.minimum(prev, np.maximum(margin, 0.0))
            cr_a.append(xa[1:].ravel())
            cr_w.append(np.repeat(prev, s, axis=1).ravel())
    own_a, own_w, cr_a, cr_w = (np.concatenate(z) if z else np.zeros(0) for z in (own_a, own_w, cr_a, cr_w))
    k_worst = int(np.argmax(step_res))
    where = "" if not np.any(step_res > 0) else (
        f"largest in step {k_worst} (t = {float(np.sum(tr.unpack(x)[1][:k_worst])):.6g}): {step_res[k_worst]:.3g}")
    return {**empty, "residual": float(np.max(step_res)), "modes": modes,
            "max_product": float(max(np.max(own_a * own_w), np.max(cr_a * cr_w, initial=0.0))),
            "lcp": float(np.max(np.abs(np.minimum(own_a, own_w)))),
            "cross": float(np.max(np.abs(np.minimum(cr_a, cr_w)), initial=0.0)), "where": where}


def _stage_forces_of(tr, x):
    N, m, s, ix = tr.pb.N, tr.pb.system.n_contacts, tr.stages, tr.ix
    return x[ix["pN"]].reshape(N, s, m), (x[ix["bp"]] - x[ix["bm"]]).reshape(N, s, m)
