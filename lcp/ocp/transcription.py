"""Direct transcription of an optimal control problem with Moreau-Jean steps (an MPCC).

The unknowns are, at the nodes k = 0..N, the state (q_k, v_k); the control, one value per step
(piecewise-constant hold) or per node (linear hold), or a start and an end value (affine hold: the
default with free steps, ``hold="auto"``); over each step k the contact
impulses, lifted into the complementarity pairs of the discrete Coulomb law; and, with
``steps="free"``, the step lengths h_k (summing to T). Each step is one step of
:mod:`lcp.timestepping` with the control's impulse integrated exactly over the step::

    W_h (v_{k+1} - v_k) = r_k + H' p_k + G' lambda_k,     G v_{k+1} + phi_t = 0,
    q_{k+1} = q_k + h_k ((1 - theta) v_k + theta v_{k+1}),
    r_k = h_k ((1 - theta) F0(t_k, q_k, v_k) + theta F0(t_k + h_k, q_k, v_k)) + B(t_k, q_k) int u dt
          - h_k^2 theta K v_k,

where F = F0 + B u is the system's force (affine in u), int u dt over the step is h_k u_k for the
constant hold and h_k (u_k + u_{k+1}) / 2 for the linear hold, W_h = A + h theta C + (h theta)^2 K
with K = -dF/dq, C = -dF/dv at the step's start. :class:`lcp.timestepping.assembly.StepAssembly` integrates a
:class:`lcp.model.control.ControlSchedule` the same way, so a replay at the same steps repeats the
optimizer's trajectory to round-off.

The discrete Coulomb law of each contact is the LCP of
:meth:`lcp.contact.problem.ContactProblem.to_lcp`, with p_T = h (beta+ - beta-)::

    0 <= N      perp  wN = u_N + e min(u_N-, 0)    >= 0,
    0 <= beta+  perp  wp = lambda + u_T            >= 0,
    0 <= beta-  perp  wm = lambda - u_T            >= 0,
    0 <= lambda perp  wl = mu N - beta+ - beta-    >= 0,      u = H(q_k) v_{k+1}, u_N- = H_N(q_k) v_k,

with forces (N = p_N / h) as unknowns, so that a product a w is a power whatever the step. A
frictionless contact (mu = 0) has no friction pairs: with them, mu N - beta+ - beta- >= 0 forced
beta+- = 0, a feasible set without interior that degraded IPOPT's conditioning (measured on a ball
bounced to a target height, N = 12: the first start failed, the event start ended at cost 4.061; without
them the first start reaches 0.2935). Its friction blocks stay in x at a fixed zero
(:func:`contact_blocks`), so that every block keeps its shape and its friction impulses read zero.

The gap law: contacts that open and close (``contact_law="gap"``)
------------------------------------------------------------------
The law above holds every contact closed at every step. Under the gap law the normal pair is on
the gap at the step's end, 0 <= N_k perp g(q_{k+1}) / (theta T / N) >= 0, with two more conditions
on a force: the gap closed at the step's start too (N_k perp g(q_k)) and the normal velocity zero
there (|N_k u_N(v_k+)| <= sigma, a signed pair). A contact that closes with approach velocity gets
an impulse at the node: v_k+ = v_k + M^-1 H' P_k, with P_N perp g(q_k), Newton's law
P_N (u_N(v_k+) + e min(u_N(v_k), 0)) = 0 and Coulomb's law on P_T (the event method's impact
law), and step k starts from v_k+. A curved frictionless contact (see below) closed at a node does
not approach after it, u_N(v_k+) >= -g(q_k) / (theta T / N): without this row a node could touch a
curved gap with an approaching velocity and no impulse, the chord to the next node passing through
the other body (the two discs, N = 30, from a start that sends disc 1 around disc 2: the homotopy
ended with a Coulomb residual 0.51, with the row at 2e-15). An open contact then approaches at most
so fast that it would close within theta T / N. Not yet on other contacts: on flat gaps the row
made the fixed-phase solves degenerate (a resting contact's u_N+ and gap both fixed at zero; eight
OCP tests failed, the Jean-Pratt block's among them), and on the tipped box's corners (curved,
mu = 0.8) it changed how the default starts fail at N = 10 (not measured further). Friction vanishes with N (mu N - beta+ - beta- >= 0). Between
nodes a contact is then either closed with a force or open, so the theta = 1/2 step is exact for
constant forces in flight as in contact, and the event replay repeats it, provided the touchdowns,
lift-offs and stick-slip switches fall on nodes (free steps, or a control that puts them there).
The node velocities v_k stay those before the impulse. Not yet: the friction cross pairs of free
steps after a flight compare with the flying step's slacks (a landing that sticks at once needs
zero tangential velocity before it).

Curved gaps: the stabilised step
--------------------------------
Where a contact's normal H_N = dg/dq depends on q (a curved gap: a point on a bowl or a circle, a
tipping box's corner, a leg's foot), the conditions above over-determine a loaded step: the chord
q_{k+1} - q_k = h (v_k + v_{k+1}) / 2 between two points of the curve, with velocities along the
curve at both ends, leaves one scalar pN for two conditions, and the homotopy stopped on the
Coulomb residual (a bowl y = x^2 / 2, N = 20: residual 0.11). For those contacts (and those whose
tangent turns with q) the step is stabilised as Gear, Gupta and Leimkuhler's index reduction: the
position update gets a correction along the end's normal, q_{k+1} = q_k + h (v_k + v_{k+1}) / 2 +
M(q_{k+1})^-1 H_N(q_{k+1})' eta_k, with eta_k (an impulse times a time) a free multiplier held to
|eta_k| <= h^2 N_k (none without a force), and a force also needs the normal velocity zero at the
step's end with the end's normal (the signed pair N_k H_N(q_{k+1}) v_{k+1}), so that a contact held
closed needs no impulse at its nodes. The Coulomb law of the step sees the end's tangential
velocity H_T(q_{k+1}) v_{k+1}: with H_T(q_k) a corner pivoting by 0.27 rad in a step (the tipped
box, N = 20) read 0.02 m/s where it moved at 0.41 m/s, and the homotopy stalled on the Coulomb
residual 0.87. The forces act along the mean of the contact Jacobians at the step's ends (with
H(q_k) alone the step is first order: replay misses 0.17, 0.083, 0.040 at N = 10, 20, 40 on the
bowl; with the mean 1.4e-2, 3.5e-3, 8.7e-4). The step is second order on curved gaps, not exact: a
replay misses by O(h^2). Flat gaps (H constant) keep the step above unchanged.

Free steps: switches off the grid
---------------------------------
With ``steps="free"`` the step lengths are unknowns and the *cross complementarity* of FESD
(Nurkanovic et al. 2024) forbids a mode switch inside a step: the pairs of step k are also
complementary to the slacks of step k - 1 at their shared node,

    beta+_k wp_{k-1} = 0,  beta-_k wm_{k-1} = 0,  wl_k lambda_{k-1} = 0,  N_k wN_{k-1} = 0,

i.e. a block still sliding at node k keeps its friction at the bound, in the same direction, over
step k: it can stop only at a node. Within a step the forces are then those of one mode, and for
forces constant over the step the theta = 1/2 step is exact, so switches (stick/slip/stop and the
control's own switches) become decision variables and the transcription exact between them.

The affine hold: smooth controls within a phase
-----------------------------------------------
A piecewise-constant control approximates a control that is smooth within a contact phase (the
minimum-effort ramp during a slide) by a staircase; over n equal steps its cost exceeds the ramp's
by J / (4 n^2), so the objective converges only as N^-2 however exactly the steps are integrated.
``hold="affine"`` gives each step a start and an end value u_k+, u_{k+1}- (affine in between, free
to jump at the nodes: at a switch the optimal control often does). Within a step of one mode the
forces are then affine in t, the velocity quadratic, and the trapezoid misses the position by
h^2 (a_0 - a_1) / 12. The step keeps the exact impulse (h times the mean force) and corrects the
position exactly,

    q_{k+1} = q_k + h_k (v_k + v_{k+1}) / 2 - h_k^2 da_k / 12,
    M da_k = dF_k + H' dlambda_k,   dF_k = F0(t_k + h_k) - F0(t_k) + B (u_{k+1}- - u_k+),

with the change dlambda = (dN, dbeta+ - dbeta-) of the contact forces over the step as unknowns.
The mode fixes it: the forces at both ends of the step stay admissible (N, beta+, beta-,
mu N - beta+ - beta- >= 0 at t_k and t_{k+1}, so a multiplier that is zero on average, or a friction
at its bound, keeps its rate zero), and the rate complementarity

    N perp (H_N da) = 0,      (mu N - beta+ - beta-) perp (H_T da) = 0

keeps a closed contact closed and a sticking contact stuck over the whole step (pairs of a
multiplier >= 0 and a signed rate, relaxed as |a s| <= sigma with the other pairs). Exact for a
constant mass matrix and contact Jacobian and forces affine in t (the Jean-Pratt block);
otherwise second order like the theta = 1/2 step. theta = 1/2 only, no bilateral constraints.

This theta step stays the default integrator: Radau IIA collocation (``integrator="radau"``,
:mod:`lcp.ocp.collocation`) has order 2s - 1 on smooth dynamics and cuts the replay misses of
nosnoc's friction examples (motor, N = 30: 0.50 -> 4.6e-4) but meets their 1e-6 on none of
them, and supports only the velocity law, while this step is exact on the constant systems.
"""
from __future__ import annotations

import functools
import time

import casadi as ca
import numpy as np

from lcp.ocp.pairs import add_pairs

__all__ = ["FRICTION_BLOCKS", "PAIRS", "Transcription", "contact_blocks", "friction_rows", "grid_variables", "pair_rows",
           "step_terms", "terminal_terms"]

#: complementarity pairs (multiplier, slack) of one contact in one step, in the order of the module
#: docstring; ``wN`` is the gap at the step's end (scaled to a velocity), not a velocity
PAIRS = (("pN", "wN"), ("bp", "wp"), ("bm", "wm"), ("lam", "wl"))
#: the pairs of the impulse at a step's start node: ``gS`` (the gap at that node: ``g0`` at node 0,
#: the previous step's ``wN`` after it) gates the normal impulse, the rest is the Coulomb law at impact
IMPULSE_PAIRS = (("PN", "gS"), ("Pbp", "Pwp"), ("Pbm", "Pwm"), ("Plam", "Pwl"))
#: pairs of a multiplier >= 0 and a signed velocity (relaxed as |a s| <= sigma): a contact carrying a
#: force over a step starts it at rest in the normal direction; an impulse gives Newton's restitution
SIGNED_PAIRS = (("pN", "sU"), ("PN", "sI"))
#: the friction blocks of a contact (the step's Coulomb pairs, the impulse's, the affine hold's force
#: rates): those of a frictionless contact (mu = 0) are fixed at zero and enter no constraint
FRICTION_BLOCKS = frozenset(("bp", "wp", "bm", "wm", "lam", "wl", "Pbp", "Pwp", "Pbm", "Pwm", "Plam", "Pwl",
                             "dbp", "dbm"))


def _scalar(expr, name):
    x = ca.SX(expr)
    if x.numel() != 1:
        raise ValueError(f"{name} must return a scalar, got shape {x.shape}")
    return x


class Transcription:
    """The NLP of an :class:`~lcp.ocp.OptimalControlProblem` (variables, bounds, constraints).

    Attributes
    ----------
    nlp : dict
        ``x``, ``f``, ``g`` and ``p`` (sigma, q0, v0) for :func:`casadi.nlpsol`.
    ix : dict
        Indices of each block of variables in ``x``.
    lbx, ubx, lbg, ubg : ndarray
    step : casadi.Function
        ``(t, h, q, v, u_start, u_mean, u_end - u_start) -> (W_h, r, H, G, phi_t(t + h), gap, M, dF)``,
        dF the change of the contact-free force over the step (affine hold).
    cross : bool
        Whether the cross complementarity (free steps) is imposed.
    """

    def __init__(self, pb):
        t_start = time.perf_counter()
        self.pb = pb
        self.step = self._step_function()
        sys = pb.system
        self.kin = ca.Function("kin", [sys.t_sym, sys.q_sym], [sys.mass_expr, sys.H_expr,
                                                               ca.jacobian(sys.constraints_expr, sys.q_sym)])
        #: gaps are scaled to velocities by the nominal step theta T / N (the products a w of the
        #: normal pairs are then powers, and a resting contact's wN equals its normal velocity)
        self.gap_scale = pb.theta * pb.T / pb.N
        #: the gap law (impulses at the nodes, contacts that open and close) or the velocity law
        #: (every contact closed at every step)
        self.gap_law = pb.contact_law == "gap" and sys.n_contacts > 0
        self.restitution = self.gap_law and bool(np.any(sys.e > 0))
        self.cross = pb.steps == "free" and pb.system.n_contacts > 0
        self.curved = _curved(sys) if self.gap_law else np.zeros(0, dtype=int)  # stabilised steps (Curved gaps)
        #: the contacts with friction (mu > 0); see :func:`contact_blocks`
        self.frictional = np.flatnonzero(np.asarray(sys.mu, dtype=float) > 0)
        self._x, self._lbx, self._ubx, self._nx = [], [], [], 0
        self._g, self._lbg, self._ubg = [], [], []
        self.ix = {}
        self._build()
        self.build_time = time.perf_counter() - t_start

    def _step_function(self) -> ca.Function:
        pb = self.pb
        sys, th = pb.system, pb.theta
        t, q, v = sys.t_sym, sys.q_sym, sys.v_sym
        h = ca.SX.sym("h")
        us, ubar, du = ca.SX.sym("us", pb.nu), ca.SX.sym("ubar", pb.nu), ca.SX.sym("du", pb.nu)
        B = sys.control_matrix_expr
        F0 = sys.force_expr
        Fs = F0 + ca.mtimes(B, us)
        K, C = -ca.jacobian(Fs, q), -ca.jacobian(Fs, v)
        Wh = sys.mass_expr + h * th * C + (h * th) ** 2 * K
        F1 = ca.substitute(F0, t, t + h)
        r = h * ((1 - th) * F0 + th * F1) + h * ca.mtimes(B, ubar) - h * h * th * ca.mtimes(K, v)
        G = ca.jacobian(sys.constraints_expr, q)
        phi_t1 = ca.substitute(ca.jacobian(sys.constraints_expr, t), t, t + h)
        dF = F1 - F0 + ca.mtimes(B, du)
        return ca.Function("mj_step", [t, h, q, v, us, ubar, du],
                           [Wh, r, sys.H_expr, G, phi_t1, sys.gap_expr, sys.mass_expr, dF])

    # ------------------------------------------------------------------ NLP bookkeeping
    def _var(self, name, size, lb, ub, key=None):
        s = ca.SX.sym(name, size)
        start = self._nx  # a running count: summing the shapes each time made the build quadratic in N
        self._nx += size
        self._x.append(s)
        self._lbx.append(np.broadcast_to(lb, (size,)).astype(float))
        self._ubx.append(np.broadcast_to(ub, (size,)).astype(float))
        idx = np.arange(start, start + size)
        if key is not None:
            self.ix.setdefault(key, []).append(idx)
        return s

    def _constrain(self, expr, lo, hi):
        expr = ca.vec(ca.SX(expr))
        self._g.append(expr)
        self._lbg.append(np.broadcast_to(lo, (expr.shape[0],)).astype(float))
        self._ubg.append(np.broadcast_to(hi, (expr.shape[0],)).astype(float))

    # ------------------------------------------------------------------ build
    def _build(self):
        pb = self.pb
        sys, N, th = pb.system, pb.N, pb.theta
        m, nb = sys.n_contacts, sys.n_bilateral
        mu, e = ca.DM(sys.mu), ca.DM(sys.e)
        sigma, q0p, v0p, Tv, z, hs, us, qs, vs, tk = grid_variables(self)
        affine = pb.hold == "affine"
        J = ca.SX(0)
        pair_sizes = {}
        prev = None  # the previous step's (a, w) blocks, for the cross complementarity
        if self.cross:
            HN0, HT0 = sys.H_expr[:m, :], sys.H_expr[m:, :]
            sub = ca.Function("H0", [sys.q_sym], [HN0, HT0])(q0p)
            uN0, uT0 = ca.mtimes(sub[0], v0p), ca.mtimes(sub[1], v0p)
            lam0 = ca.fabs(uT0)
            prev = {"wN": uN0, "wp": lam0 + uT0, "wm": lam0 - uT0, "lam": lam0}
        self.vplus, gS = [], None
        if self.gap_law:  # node 0's gap: a number (q0 is given), not a variable that the mode could fix
            gS = sys.gap_fn(q0p) / self.gap_scale
        for k in range(N):
            h = hs[k]
            ua, ub = self.control_pair(us, k)
            qa, qb, va, vb = qs[k], qs[k + 1], vs[k], vs[k + 1]
            if self.gap_law:  # the impulse at the step's start node, then the step from the velocity after it
                va, imp_pairs, signed = self._impulse(k, tk[k], qa, va, gS, sigma)
            self.vplus.append(va)
            blk = contact_blocks(self, [nm for a_w in PAIRS for nm in a_w], str(k))
            lamb = self._var(f"lb{k}", nb, -np.inf, np.inf, key="lb")
            Wh, r, H, G, phi_t1, _, Mq, dF = self.step(tk[k], h, qa, va, ua, 0.5 * (ua + ub), ub - ua)
            pN, pT = h * blk["pN"], h * (blk["bp"] - blk["bm"])
            dyn = ca.mtimes(Wh, vb - va) - r
            HL, HF = _end_jacobians(self, H, tk[k] + h, qb)  # curved contacts: the law's, the forces'
            if m:
                dyn = dyn - ca.mtimes(HF.T, ca.vertcat(pN, pT))
            if nb:
                dyn = dyn - ca.mtimes(G.T, lamb)
                self._constrain(ca.mtimes(G, vb) + phi_t1, 0.0, 0.0)
            self._constrain(dyn, 0.0, 0.0)
            # the affine hold: the trapezoid plus its exact correction for forces affine in t over the step
            dq = (qb - qa - 0.5 * h * (va + vb) + h * h / 12 * self._rates(k, blk, H, Mq, dF, m, mu, sigma) if affine
                  else qb - qa - h * ((1 - th) * va + th * vb))
            self._constrain(_stabilised(self, dq, k, tk[k] + h, qb, vb, h, blk["pN"], sigma), 0.0, 0.0)
            if m:
                uN, uT = ca.mtimes(H[:m, :], vb), ca.mtimes(HL[m:, :], vb)
                lam = blk["lam"]
                if self.gap_law:
                    # the gap at the step's end (position level); the force only where the gap is
                    # closed at both ends of the step (pN against gS: the start gap) and the normal
                    # velocity at the start is zero (the signed pair pN sU)
                    self._constrain(blk["wN"] - sys.gap_fn(qb) / self.gap_scale, 0.0, 0.0)
                else:
                    self._constrain(blk["wN"] - (uN + e * ca.fmin(ca.mtimes(H[:m, :], va), 0)), 0.0, 0.0)
                self._constrain(friction_rows(self, blk["wp"] - (lam + uT)), 0.0, 0.0)
                self._constrain(friction_rows(self, blk["wm"] - (lam - uT)), 0.0, 0.0)
                self._constrain(friction_rows(self, blk["wl"] - (mu * blk["pN"] - blk["bp"] - blk["bm"])), 0.0, 0.0)
                a = [pair_rows(self, x, blk[x]) for x, _ in PAIRS]
                w = [pair_rows(self, x, blk[y]) for x, y in PAIRS]
                if self.gap_law:
                    a += [blk["pN"]] + imp_pairs[0]
                    w += [gS] + imp_pairs[1]
                if self.cross:  # step k's multipliers against step k - 1's slacks at node k (the
                    # normal one only under the velocity law: the gap law has pN against gS)
                    names = (("bp", "wp"), ("bm", "wm"), ("wl", "lam"))
                    if not self.gap_law:
                        names = (("pN", "wN"),) + names
                    a += [pair_rows(self, x, blk[x]) for x, _ in names]
                    w += [pair_rows(self, x, prev[y]) for x, y in names]
                    prev = blk
                self._constrain(ca.vertcat(*a) * ca.vertcat(*w) - sigma, -np.inf, 0.0)  # Scholtes
                if self.gap_law:
                    prod = ca.vertcat(blk["pN"] * signed[0], signed[1])
                    self._constrain(prod - sigma, -np.inf, 0.0)
                    self._constrain(prod + sigma, 0.0, np.inf)
                    gS = blk["wN"]
            st = pb.make_step(k, tk[k], h, qa, qb, va, vb, ua, ub, pN, pT)
            J = self._step_terms(J, st, us, k, h, ua, ub, z, sigma, pair_sizes)
        J = self._terminal_terms(J, Tv, qs, vs, z)
        g = ca.vertcat(*self._g) if self._g else ca.SX.zeros(0, 1)
        self.nlp = {"x": ca.vertcat(*self._x), "f": J, "g": g, "p": ca.vertcat(sigma, q0p, v0p)}
        #: (x, p) -> the velocity after each node's impulse (n, N): the start of each step
        self.aux = ca.Function("aux", [self.nlp["x"], self.nlp["p"]], [ca.horzcat(*self.vplus)])
        del self.vplus
        self.ix = {key: np.array(val) for key, val in self.ix.items()}
        if self.gap_law and not self.restitution:
            self.ix["sI"] = self.ix["sU"]
        self.lbx, self.ubx = np.concatenate(self._lbx), np.concatenate(self._ubx)
        self.lbg = np.concatenate(self._lbg) if self._lbg else np.zeros(0)
        self.ubg = np.concatenate(self._ubg) if self._ubg else np.zeros(0)
        del self._x, self._g, self._lbx, self._ubx, self._lbg, self._ubg, self._nx

    def _step_terms(self, J, st, us, k, h, ua, ub, z, sigma, pair_sizes):
        return step_terms(self, J, st, us, k, h, ua, ub, z, sigma, pair_sizes)

    def _terminal_terms(self, J, Tv, qs, vs, z):
        return terminal_terms(self, J, Tv, qs, vs, z)

    def control_pair(self, us, k):
        """The control at the start and at the end of step k (lists of per-row symbols or arrays)."""
        hold = self.pb.hold
        if hold == "constant":
            return us[k], us[k]
        if hold == "linear":
            return us[k], us[k + 1]
        return us[2 * k], us[2 * k + 1]

    def _impulse(self, k, t, q, v, gS, sigma):
        """The impulse at node k (at the start of step k) and the velocity after it.

        Newton's restitution and Coulomb's law at the velocity level, as the event method's impact
        law (:mod:`lcp.events.impacts`): the normal impulse PN only where the gap gS is closed, and
        then such that u_N+ + e min(u_N-, 0) = 0 (the signed pair PN sI); the friction impulse
        within mu PN, opposing the tangential velocity after the impulse. Returns (v+, the
        nonnegative pairs as two lists, (sU, PN sI)).
        """
        sys = self.pb.system
        m, nb = sys.n_contacts, sys.n_bilateral
        imp = contact_blocks(self, [nm for a_w in IMPULSE_PAIRS[1:] for nm in a_w], str(k))
        imp["PN"] = self._var(f"PN{k}", m, 0.0, np.inf, key="PN")
        sU = self._var(f"sU{k}", m, -np.inf, np.inf, key="sU")
        Mq, H, G = self.kin(t, q)
        rhs = ca.mtimes(H.T, ca.vertcat(imp["PN"], imp["Pbp"] - imp["Pbm"]))
        if nb:  # the impulse keeps the bilateral constraints' velocities
            K = ca.vertcat(ca.horzcat(Mq, G.T), ca.horzcat(G, ca.SX.zeros(nb, nb)))
            dv = ca.solve(K, ca.vertcat(rhs, ca.SX.zeros(nb, 1)))[: sys.n]
        else:
            dv = ca.solve(Mq, rhs)
        vp = v + dv
        HN, HT = H[:m, :], H[m:, :]
        uN, uT = ca.mtimes(HN, vp), ca.mtimes(HT, vp)
        self._constrain(sU - uN, 0.0, 0.0)
        if self.restitution:
            sI = self._var(f"sI{k}", m, -np.inf, np.inf, key="sI")
            self._constrain(sI - (uN + ca.DM(sys.e) * ca.fmin(ca.mtimes(HN, v), 0)), 0.0, 0.0)
        else:
            sI = sU
        self._constrain(friction_rows(self, imp["Pwp"] - (imp["Plam"] + uT)), 0.0, 0.0)
        self._constrain(friction_rows(self, imp["Pwm"] - (imp["Plam"] - uT)), 0.0, 0.0)
        self._constrain(friction_rows(self, imp["Pwl"] - (ca.DM(sys.mu) * imp["PN"] - imp["Pbp"] - imp["Pbm"])),
                        0.0, 0.0)
        a = [imp["PN"]] + [friction_rows(self, imp[nm]) for nm in ("Pbp", "Pbm", "Plam")]
        w = [gS] + [friction_rows(self, imp[nm]) for nm in ("Pwp", "Pwm", "Pwl")]
        rows = [int(i) for i in self.curved if sys.mu[i] == 0.0]
        if rows:
            # a curved frictionless contact closed at the node does not approach after it (gS = 0:
            # u_N+ >= 0, Moreau's condition, which the pairs above leave out where P_N = 0); an open
            # one not so fast that it would close within theta T / N (gS is the gap over that time)
            self._constrain(ca.vertcat(*[sU[i] + gS[i] for i in rows]), 0.0, np.inf)
        return vp, (a, w), (sU, imp["PN"] * sI)

    def _rates(self, k, blk, H, Mq, dF, m, mu, sigma):
        """Acceleration change da over step k under the affine hold (module docstring), with its
        contact-force changes as unknowns, their endpoint bounds and rate complementarity."""
        if not m:
            return ca.solve(Mq, dF)
        d = contact_blocks(self, ("dN", "dbp", "dbm"), str(k), -np.inf)
        s = {nm: self._var(f"{nm}{k}", m, -np.inf, np.inf, key=nm) for nm in ("sN", "sT")}
        da = ca.solve(Mq, dF + ca.mtimes(H.T, ca.vertcat(d["dN"], d["dbp"] - d["dbm"])))
        self._constrain(ca.vertcat(s["sN"], s["sT"]) - ca.mtimes(H, da), 0.0, 0.0)
        dwl = mu * d["dN"] - d["dbp"] - d["dbm"]
        fr = functools.partial(friction_rows, self)
        for mean, rate in ((blk["pN"], d["dN"]), (fr(blk["bp"]), fr(d["dbp"])), (fr(blk["bm"]), fr(d["dbm"])),
                           (fr(blk["wl"]), fr(dwl))):
            self._constrain(ca.vertcat(mean - 0.5 * rate, mean + 0.5 * rate), 0.0, np.inf)  # >= 0 at both ends
        prod = ca.vertcat(blk["pN"] * s["sN"], fr(blk["wl"] * s["sT"]))
        self._constrain(prod - sigma, -np.inf, 0.0)
        self._constrain(prod + sigma, 0.0, np.inf)
        return da

    # ------------------------------------------------------------------ numbers out of x
    def squeezed_phases_law(self, x):
        return squeezed_phases(self, x)

    def unpack(self, x):
        """(T, steps, q, v, u, p_N, p_T) of a vector of NLP variables."""
        pb, ix = self.pb, self.ix
        N, n, m = pb.N, pb.system.n, pb.system.n_contacts
        T = float(x[ix["T"]].ravel()[0]) if pb.free_time else pb.T
        if pb.steps == "free":
            steps = x[ix["h"]].ravel()
        else:
            steps = np.full(N, T / N) if pb.step_fractions is None else T * np.asarray(pb.step_fractions)
        q = np.vstack([pb.q0] + [x[i] for i in ix["q"]]).reshape(N + 1, n)
        v = np.vstack([pb.v0] + [x[i] for i in ix["v"]]).reshape(N + 1, n)
        u = np.vstack([x[i] for i in ix["u"]]).reshape(-1, pb.nu)
        if m:
            pN, pT = self.step_impulses(x, steps)
        else:
            pN = pT = np.zeros((N, 0))
        return T, steps, q, v, u, pN, pT

    def step_impulses(self, x, steps):
        """(p_N, p_T), shape (N, m): each step's contact impulses (its length times its mean forces)."""
        N, m = self.pb.N, self.pb.system.n_contacts
        return (steps[:, None] * x[self.ix["pN"]].reshape(N, m),
                steps[:, None] * (x[self.ix["bp"]] - x[self.ix["bm"]]).reshape(N, m))

    def impulses(self, x):
        """The impulses (P_N, P_T) at the start node of each step, shape (N, m) each."""
        N, m = self.pb.N, self.pb.system.n_contacts
        if not self.gap_law:
            return np.zeros((N, 0)), np.zeros((N, 0))
        ix = self.ix
        return x[ix["PN"]].reshape(N, m), (x[ix["Pbp"]] - x[ix["Pbm"]]).reshape(N, m)


#: a step's own contact blocks (one value per step and contact): its mode, copied whole by
#: :func:`squeezed_phases`
STEP_BLOCKS = ("pN", "wN", "bp", "wp", "bm", "wm", "lam", "wl", "dN", "dbp", "dbm", "sN", "sT")


def squeezed_phases(tr, x):
    """A start for another fixed-phase solve, or None: every free step at its lower length bound
    whose mode (which member of each contact pair is the larger) differs from a neighbour's takes
    that neighbour's contact blocks (the following step's first). The first pass's modes come from
    uniform steps: a switch inside one of them can leave a step of a phase the optimum lacks, which
    the fixed-phase solve can only shrink to the lower bound. Measured on the Jean-Pratt
    move-and-hold at N = 40 on [0.45, 0.7] s, T = 1.2 s: a stick step of minimum length after the
    hold delayed the return, 3.6e-3 above the optimum."""
    pb, m, N = tr.pb, tr.pb.system.n_contacts, tr.pb.N
    if pb.steps != "free" or not m or N < 2:
        return None
    ih = tr.ix["h"].reshape(-1)
    at_lo = x[ih] <= tr.lbx[ih] * (1.0 + 1e-6)
    sig = np.stack([x[tr.ix[a]] > x[tr.ix[w]] for a, w in (("pN", "wN"), ("bp", "wp"), ("bm", "wm"), ("lam", "wl"))],
                   axis=-1)
    blocks = [tr.ix[key] for key in STEP_BLOCKS if key in tr.ix and tr.ix[key].shape == (N, m)]
    x_new, changed = x.copy(), False
    for k in np.flatnonzero(at_lo):
        for nb in (k + 1, k - 1):
            diff = np.any(sig[k] != sig[nb], axis=-1) if 0 <= nb < N else np.zeros(m, dtype=bool)
            if np.any(diff):
                for idx in blocks:
                    x_new[idx[k][diff]] = x[idx[nb][diff]]
                changed = True
                break
    return x_new if changed else None


def contact_blocks(tr, names, tag: str, lb: float = 0.0, ub: float = np.inf) -> dict:
    """One step's (or stage's) contact blocks ``names`` (m each, keys of ``tr.ix``), within [lb, ub];
    the :data:`FRICTION_BLOCKS` of a frictionless contact fixed at zero (lb = ub = 0).

    A contact with mu = 0 still had its friction pairs, whose feasible set has no interior
    (mu N - beta+ - beta- >= 0 forces beta+- = 0) and which degraded IPOPT's conditioning. Its
    friction blocks stay in x, so that every block keeps its (N, m) shape and the reported friction
    impulses are zeros, but fixed at zero and in no constraint (:func:`friction_rows`): IPOPT
    treats fixed variables as parameters (its default ``fixed_variable_treatment``), so the
    problem it solves has no friction variables for such a contact.
    """
    m = tr.pb.system.n_contacts
    fric = np.zeros(m, dtype=bool)
    fric[tr.frictional] = True
    out = {}
    for nm in names:
        if nm in FRICTION_BLOCKS and not fric.all():
            sym = tr._var(f"{nm}{tag}", m, np.where(fric, lb, 0.0), np.where(fric, ub, 0.0), key=nm)
            # the expressions see zeros: the fixed variables appear in no constraint and no cost
            out[nm] = ca.vertcat(*[sym[i] if fric[i] else ca.SX(0.0) for i in range(m)])
        else:
            out[nm] = tr._var(f"{nm}{tag}", m, lb, ub, key=nm)
    return out


def pair_rows(tr, a_name, expr):
    """The rows of a contact pair (named by its multiplier ``a_name``) that enter the complementarity
    constraint: every contact's for a normal pair (``pN``), the frictional contacts' for a friction
    pair (:func:`friction_rows`)."""
    return expr if a_name == "pN" else friction_rows(tr, expr)


def friction_rows(tr, expr):
    """The rows of the frictional contacts (``tr.frictional``) of an m-vector: ``expr`` itself when
    every contact has friction."""
    if tr.frictional.size == tr.pb.system.n_contacts:
        return expr
    # (row by row: CasADi reads an index list on a 1 x 1 expression as the whole expression)
    return ca.vertcat(ca.SX.zeros(0, 1), *[expr[int(i)] for i in tr.frictional])


def _end_jacobians(tr, H, t1, q1):
    """(HL, HF) of step k: the contact Jacobian H(q_k) with the rows of the curved contacts replaced
    by H(q_{k+1}) (HL: the velocity v_{k+1} that the Coulomb law sees is measured with the end's
    normal and tangent, where the stabilised step holds it) and by the mean of H(q_k) and H(q_{k+1})
    (HF: the force turns with the contact over the step). Both are H without curved contacts."""
    if not tr.curved.size:
        return H, H
    m, c = tr.pb.system.n_contacts, tr.curved
    sel = np.zeros(2 * m)
    sel[np.concatenate([c, m + c])] = 1.0
    S = ca.DM(np.diag(sel))
    dH = ca.mtimes(S, tr.kin(t1, q1)[1] - H)
    return H + dH, H + 0.5 * dH


def _stabilised(tr, dq, k, t1, q1, v1, h, pN, sigma):
    """Step k's position residual dq less the correction M(q_{k+1})^-1 H_N(q_{k+1})' eta_k of its
    curved contacts (module docstring, "Curved gaps"; dq itself without them): eta_k (an impulse
    times a time, so that the correction is one in any coordinates) free within |eta_k| <= h^2 N_k
    (none without a force), and the end's normal velocity H_N(q_{k+1}) v_{k+1} zero under a force
    (the signed pair N_k u_N1, relaxed as |a s| <= sigma)."""
    c = tr.curved
    if not c.size:
        return dq
    eta = tr._var(f"eta{k}", c.size, -np.inf, np.inf, key="eta")
    M1, H1 = tr.kin(t1, q1)[:2]
    HN1 = H1[c.tolist(), :]
    pc = pN[c.tolist()]
    tr._constrain(ca.vertcat(h * h * pc - eta, h * h * pc + eta), 0.0, np.inf)
    prod = pc * ca.mtimes(HN1, v1)
    tr._constrain(prod - sigma, -np.inf, 0.0)
    tr._constrain(prod + sigma, 0.0, np.inf)
    return dq - ca.solve(M1, ca.mtimes(HN1.T, eta))


def _curved(sys):
    """Indices of the contacts whose normal or tangent row of the contact Jacobian depends on q."""
    m = sys.n_contacts
    return np.flatnonzero([ca.depends_on(sys.H_expr[i, :], sys.q_sym) or ca.depends_on(sys.H_expr[m + i, :], sys.q_sym)
                           for i in range(m)])


def grid_variables(tr, step_floor: float | None = None):
    """The variables and grid every transcription shares, added to ``tr``: (sigma, q0, v0, T, z,
    steps h_k, controls, node positions, node velocities, node times). T is a variable with
    ``free_time``, z the epigraph variable of ``max_cost``; free steps are variables summing to T
    within ``step_bounds`` T / N (the lower bound replaced by ``step_floor`` where given), else uniform or the fixed piecewise-uniform grid of a phase guess
    (``step_fractions``); the nodes pinned by ``node_times`` are constraints where the grid moves."""
    pb = tr.pb
    N, n, nu = pb.N, pb.system.n, pb.nu
    sigma, q0p, v0p = ca.SX.sym("sigma"), ca.SX.sym("q0", n), ca.SX.sym("v0", n)
    Tv = tr._var("T", 1, *pb.T_bounds, key="T") if pb.free_time else ca.SX(pb.T)
    z = tr._var("z", 1, -np.inf, np.inf, key="z") if pb.max_cost is not None else None
    if pb.steps == "free":
        lo, hi = pb.step_bounds
        lo = lo if step_floor is None else step_floor
        Tlo, Thi = (pb.T_bounds if pb.free_time else (pb.T, pb.T))
        hs = [tr._var(f"h{k}", 1, lo * Tlo / N, hi * Thi / N, key="h") for k in range(N)]
        tr._constrain(ca.sum1(ca.vertcat(*hs)) - Tv, 0.0, 0.0)
    else:
        fr = pb.step_fractions
        hs = [Tv / N] * N if fr is None else [Tv * float(f) for f in fr]
    n_u = {"constant": N, "linear": N + 1, "affine": 2 * N}[pb.hold]
    us = [tr._var(f"u{k}", nu, pb.u_min, pb.u_max, key="u") for k in range(n_u)]
    qs, vs = [q0p], [v0p]
    for k in range(1, N + 1):
        qs.append(tr._var(f"q{k}", n, -np.inf, np.inf, key="q"))
        vs.append(tr._var(f"v{k}", n, -np.inf, np.inf, key="v"))
    tk = [ca.SX(0)]
    for k in range(N):
        tk.append(tk[-1] + hs[k])
    if pb.steps == "free" or pb.free_time:  # a fixed grid holds its pinned nodes by construction
        # (a constant row of zeros would leave IPOPT a rank-deficient Jacobian)
        for k, tval in pb.node_times.items():
            tr._constrain(tk[k] - tval, 0.0, 0.0)
    return sigma, q0p, v0p, Tv, z, hs, us, qs, vs, tk


def step_terms(tr, J, st, us, k, h, ua, ub, z, sigma, pair_sizes, pairs: bool = True):
    """The step's cost terms and the user's path constraints and pairs, added to a transcription
    ``tr`` (every transcription's: theta, Radau, shooting)."""
    pb = tr.pb
    if pb.stage_cost is not None:
        J = J + h * _scalar(pb.stage_cost(st), "stage_cost")
    if pb.control_rate_weight and pb.hold == "affine":
        J = J + pb.control_rate_weight * ca.sumsqr(ub - ua) / h
    elif pb.control_rate_weight and k + 1 < len(us):
        J = J + pb.control_rate_weight * ca.sumsqr(us[k + 1] - us[k]) / h
    if pb.path_constraints is not None:
        tr._constrain(ca.vec(ca.SX(pb.path_constraints(st))), -np.inf, 0.0)
    if pb.path_equalities is not None:
        tr._constrain(ca.vec(ca.SX(pb.path_equalities(st))), 0.0, 0.0)
    if pb.complementarity and pairs:  # the user's pairs, relaxed with the contacts' (lcp.ocp.pairs)
        add_pairs(pb.complementarity, k, st, sigma, tr._var, tr._constrain, pair_sizes)
    if pb.max_cost is not None:
        tr._constrain(_scalar(pb.max_cost(st), "max_cost") - z, -np.inf, 0.0)
    return J


def terminal_terms(tr, J, Tv, qs, vs, z):
    """The terminal cost and constraints, and the epigraph variable of max_cost."""
    pb = tr.pb
    if pb.terminal_cost is not None:
        J = J + _scalar(pb.terminal_cost(Tv, qs[-1], vs[-1]), "terminal_cost")
    if pb.terminal_constraints is not None:
        tr._constrain(ca.vec(ca.SX(pb.terminal_constraints(qs[-1], vs[-1]))), 0.0, 0.0)
    return J if z is None else J + z
