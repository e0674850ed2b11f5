"""The dynamics of one smooth phase of a contact-mode sequence, for the exact-phase shooting.

:func:`mode_dynamics` gives the accelerations and contact forces of a system in fixed contact
modes (index reduction at the acceleration level), :func:`rk4_segment` integrates one phase on a
fixed grid in SX (the shooting's NLP), :func:`impulse_dv` applies impact impulses (numbers).

Redundant rows (a box resting on two stuck corners: two tangential rows on one line, four rows on
three velocities): the KKT matrix [M, -C; R, 0] of all the rows a mode holds is singular.
:func:`independent_rows` picks a maximal independent subset at a reference state (the phase's
start), :func:`mode_dynamics` solves with it (the accelerations are unique, the dropped rows
implied) and returns the null space of the force columns, along which the forces are free: the
shooting keeps the modes admissible for SOME distribution of the forces. Where the accelerations
are not unique, :class:`NotShootable` says so.

Imports CasADi, NumPy and the contact mode codes; it must not import the shooting, the solve or
the problem (they call it).
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from lcp.contact.modes import OPEN, SLIDE_NEG, SLIDE_POS, STICK

__all__ = [
    "CHECK_TOL",
    "GRID",
    "INTEGRATOR_TOL",
    "POINT_WEIGHTS",
    "RANK_TOL",
    "SINGULAR_TOL",
    "NotShootable",
    "impact_rows",
    "impulse_dv",
    "independent_rows",
    "mode_dynamics",
    "mode_rows",
    "rk4_segment",
    "segment_integrator",
]

#: CVODES's options: Adams (the phases are smooth; 2.2x faster than BDF on the motor at the same
#: tolerance) at rtol 1e-10, four orders below the replay tolerance 1e-6 (the event replay
#: integrates with DOP853 at rtol 1e-12); the motor at rtol 1e-12 took 3.8x longer for a cost
#: that differs by 1e-11
INTEGRATOR_TOL = {"reltol": 1e-10, "abstol": 1e-12, "linear_multistep_method": "adams"}
#: CVODES's options for the check of a solution (one pass: tight)
CHECK_TOL = {"reltol": 1e-12, "abstol": 1e-14, "linear_multistep_method": "adams"}
#: the integrator's output times within a segment (fractions of it): the modes are kept
#: admissible there and at the segment's start (a slide whose velocity changed sign between its
#: two ends kept the cart-pole's ends admissible while its replay stuck: a miss of 1.9)
GRID = (0.25, 0.5, 0.75, 1.0)
#: Newton-Cotes weights on the segment's points (0 and GRID): the integral over [0, 1] of the
#: polynomial through values there (Boole's rule)
POINT_WEIGHTS = tuple(np.linalg.solve(np.vander((0.0, *GRID), increasing=True).T,
                                      1.0 / np.arange(1, len(GRID) + 2)))


class NotShootable(ValueError):
    """The problem or its phase sequence has something the shooting does not model."""


#: a segment function's derivatives in more forward directions than this fraction of its inputs are
#: taken from its Jacobian (:func:`rk4_segment`)
JAC_PENALTY = 0.5
#: relative tolerance of the rank decisions on a mode's rows (each scaled to unit norm): a row whose
#: distance from the span of the rows kept before it is below this is implied by them
RANK_TOL = 1e-9
#: a mode whose reduced Delassus matrix R_S M^-1 C_S has a singular value below this (relative to
#: its largest) has no unique accelerations (Painleve's indeterminacy): refused
SINGULAR_TOL = 1e-12


def mode_rows(pb, modes):
    """The rows of problem ``pb``'s system that the given modes hold, symbolic in (q, v):
    (R, C, rhs, P, labels) with R (r x n) the rows whose accelerations are held (R a = rhs), C
    (n x r) their force columns (a row's own H' or, on a sliding contact's normal row,
    H_N' - s mu H_T'), P (2m x r, numbers) mapping the row forces y to (lambda_N, lambda_T), and
    labels (kind, index) with kind "N", "T" (a contact's normal or tangential row) or "G" (a
    bilateral constraint), in the order closed normals, sticking tangentials, bilaterals."""
    sys = pb.system
    n, m, nb = sys.n, sys.n_contacts, sys.n_bilateral
    q, v = sys.q_sym, sys.v_sym
    H = sys.H_expr if m else ca.SX.zeros(0, n)
    Hdot_v = ca.mtimes(ca.jacobian(ca.mtimes(H, v), q), v) if m else ca.SX.zeros(0, 1)
    mu = np.asarray(sys.mu, dtype=float)
    cols, rows, rhs, labels = [], [], [], []
    for j in (j for j in range(m) if modes[j] != OPEN):
        col = H[j, :].T
        if modes[j] in (SLIDE_POS, SLIDE_NEG):  # friction -s mu lambda_N along the tangent
            col = col - _sign(modes[j]) * mu[j] * H[m + j, :].T
        cols.append(col)
        rows.append(H[j, :])
        rhs.append(-Hdot_v[j])
        labels.append(("N", j))
    for j in (j for j in range(m) if modes[j] == STICK):
        cols.append(H[m + j, :].T)
        rows.append(H[m + j, :])
        rhs.append(-Hdot_v[m + j])
        labels.append(("T", j))
    if nb:
        G = ca.jacobian(sys.constraints_expr, q)
        Gdot_v = ca.mtimes(ca.jacobian(ca.mtimes(G, v), q), v)
        for i in range(nb):
            cols.append(G[i, :].T)
            rows.append(G[i, :])
            rhs.append(-Gdot_v[i])
            labels.append(("G", i))
    r = len(labels)
    P = np.zeros((2 * m, r))
    for i, (kind, j) in enumerate(labels):
        if kind == "N":
            P[j, i] = 1.0
            if modes[j] in (SLIDE_POS, SLIDE_NEG):
                P[m + j, i] = -_sign(modes[j]) * mu[j]
        elif kind == "T":
            P[m + j, i] = 1.0
    R = ca.vertcat(*rows) if r else ca.SX.zeros(0, n)
    C = ca.horzcat(*cols) if r else ca.SX.zeros(n, 0)
    return R, C, (ca.vertcat(*rhs) if r else ca.SX.zeros(0, 1)), P, labels


def _sign(mode) -> float:
    return 1.0 if mode == SLIDE_POS else -1.0


def independent_rows(pb, modes, t, q):
    """A maximal independent subset of the rows the modes hold (:func:`mode_rows`) at (t, q), as
    sorted row indices, or None where all are independent: the rows taken greedily, closed normals
    first, then bilaterals, then sticking tangentials, each kept when its distance from the span
    of those kept (rows scaled to unit norm) exceeds :data:`RANK_TOL` (two stuck corners of a box
    on a floor: their tangential rows coincide, the second is implied).

    Raises :class:`NotShootable` where the accelerations of the modes are not unique at (t, q): a
    dropped row whose force column is not in the span of the kept ones (a sliding contact's), or
    a singular reduced Delassus matrix R_S M^-1 C_S."""
    sys = pb.system
    R, C, _, _, labels = mode_rows(pb, modes)
    if not labels:
        return None
    Rn, Cn, Mn = (np.array(a, dtype=float) for a in
                  ca.Function("rows", [sys.t_sym, sys.q_sym], [R, C, sys.mass_expr])(t, q))
    rank = {"N": 0, "G": 1, "T": 2}
    order = sorted(range(len(labels)), key=lambda i: (rank[labels[i][0]], i))
    keep = _greedy_rows(Rn, order)
    where = f"mode {''.join(str(int(c)) for c in modes)} at t = {float(t):.6g}"
    Cs = Cn[:, keep]
    for d in (i for i in range(len(labels)) if i not in keep):
        c = Cn[:, d]
        res = c - Cs @ np.linalg.lstsq(Cs, c, rcond=None)[0] if keep else c
        if np.linalg.norm(res) > RANK_TOL * max(np.linalg.norm(c), 1e-300):
            raise NotShootable(f"{where}: row {labels[d]} is implied by the others but its force is not: "
                               "the accelerations are not unique")
    if keep:
        s = np.linalg.svd(Rn[keep] @ np.linalg.solve(Mn, Cs), compute_uv=False)
        if s[-1] <= SINGULAR_TOL * s[0]:
            raise NotShootable(f"{where}: the reduced Delassus matrix is singular (smallest singular value "
                               f"{s[-1]:.2e} of {s[0]:.2e}): the accelerations are not unique")
    return None if len(keep) == len(labels) else tuple(keep)


def _greedy_rows(Rn, order) -> list:
    """Sorted indices of the rows of Rn (numbers) taken in ``order``, each kept when its distance
    from the span of those kept before it exceeds RANK_TOL (rows scaled to unit norm)."""
    keep = []
    for i in order:
        norm = np.linalg.norm(Rn[i])
        if norm == 0.0:
            continue
        row = Rn[i] / norm
        if keep:
            A = Rn[keep] / np.linalg.norm(Rn[keep], axis=1)[:, None]
            row = row - A.T @ np.linalg.lstsq(A.T, row, rcond=None)[0]
        if np.linalg.norm(row) > RANK_TOL:
            keep.append(i)
    return sorted(keep)


def impact_rows(system, impacts, q):
    """The velocity rows that an impact law holds after the impacts at q (numbers), in the order
    of :func:`~lcp.ocp.shooting.impact_law`: per impact (contact c, tangential mode, ...) its normal
    row, and its tangential row where the impulse sticks; and a maximal independent subset of
    them (normals first), as sorted indices, or None where all are independent (two stuck corners
    of a box landing flat: four rows on three velocities, the impulses' split not unique)."""
    m = system.n_contacts
    H = system.contact_jacobian(np.asarray(q, dtype=float))
    rows, kinds = [], []
    for c, tmode, *_ in impacts:
        rows.append(H[c])
        kinds.append(0)
        if tmode == STICK:
            rows.append(H[m + c])
            kinds.append(1)
    if not rows:
        return None
    keep = _greedy_rows(np.array(rows), sorted(range(len(rows)), key=lambda i: (kinds[i], i)))
    return None if len(keep) == len(rows) else tuple(keep)


def mode_dynamics(pb, modes, keep=None) -> ca.Function:
    """(t, q, v, u) -> (a, lambda_N (m), lambda_T (m), normal and tangential accelerations
    H a + dH/dt v (2 m), Z (2m x d), residual) of problem ``pb``'s system in the given modes
    (codes, one per contact): the closed contacts' normal accelerations zero, the sticking ones'
    tangential too, the sliding ones' friction at the cone's bound against the slide, the
    bilateral constraints held.

    ``keep``: the rows held (:func:`independent_rows`; None: all of :func:`mode_rows`). The other
    d rows are implied by them and carry no force of their own in (lambda_N, lambda_T): those are
    one admissible-or-not distribution of the forces, and every distribution that gives the same
    motion is lambda + Z z (z in R^d; Z's columns: for each dropped row, its force unit minus the
    kept forces that make the same generalized force, C_S (C_S' C_S)^-1 C_S' c_d, symbolic in q,
    so exact wherever the dependency holds). ``residual`` (empty when d = 0) is what must vanish
    for that: the dropped rows' velocities and acceleration conditions, and C Z (the generalized
    force of the null-space directions)."""
    sys = pb.system
    n, m = sys.n, sys.n_contacts
    t, q, v = sys.t_sym, sys.q_sym, sys.v_sym
    u = ca.SX.sym("u", pb.nu)
    R, C, rhs, P, labels = mode_rows(pb, modes)
    r = len(labels)
    S = list(range(r)) if keep is None else sorted(int(i) for i in keep)
    D = [i for i in range(r) if i not in S]
    H = sys.H_expr if m else ca.SX.zeros(0, n)
    Hdot_v = ca.mtimes(ca.jacobian(ca.mtimes(H, v), q), v) if m else ca.SX.zeros(0, 1)
    F = sys.force_expr + ca.mtimes(sys.control_matrix_expr, u)
    if S:  # the KKT system [M, -C_S; R_S, 0] by its Schur complement, the Delassus matrix R_S M^-1 C_S:
        # two small symbolic solves instead of one of size n + r (the box resting on two corners: its
        # Runge-Kutta segment's Hessian 3.2e6 -> 1.0e6 instructions, the shooting's NLP 0.4 -> 0.1 s
        # per iteration; the motor's and the chain's shootings end at the same costs to 3e-14)
        Minv_F = ca.solve(sys.mass_expr, F)
        Minv_C = ca.solve(sys.mass_expr, C[:, S])
        lam = ca.solve(ca.mtimes(R[S, :], Minv_C), rhs[S] - ca.mtimes(R[S, :], Minv_F))
        y = ca.vertcat(Minv_F + ca.mtimes(Minv_C, lam), lam)
    else:
        y = ca.solve(sys.mass_expr, F)
    a = y[:n]
    Y = [ca.SX(0)] * r
    for i, row in enumerate(S):
        Y[row] = y[n + i]
    lamN, lamT = _contact_forces(Y, labels, P, m)
    if D:  # the null space of the force columns: one direction per dropped row
        Cs = C[:, S]
        T = ca.solve(ca.mtimes(Cs.T, Cs), ca.mtimes(Cs.T, C[:, D]))
        Nb = ca.SX.zeros(r, len(D))
        for i, d in enumerate(D):
            Nb[d, i] = 1.0
        for i, row in enumerate(S):
            Nb[row, :] = -T[i, :]
        Z = ca.mtimes(ca.DM(P), Nb)
        residual = ca.vertcat(ca.mtimes(R[D, :], v), ca.mtimes(R[D, :], a) - rhs[D], ca.vec(ca.mtimes(C, Nb)))
    else:
        Z, residual = ca.SX.zeros(2 * m, 0), ca.SX.zeros(0, 1)
    acc = ca.mtimes(H, a) + Hdot_v if m else ca.SX.zeros(0, 1)
    return ca.Function(f"mode_{''.join(map(str, modes))}", [t, q, v, u],
                       [a, ca.vertcat(*lamN) if m else ca.SX.zeros(0, 1),
                        ca.vertcat(*lamT) if m else ca.SX.zeros(0, 1), acc, Z, residual])


def _contact_forces(Y, labels, P, m):
    """(lambda_N, lambda_T) as lists of m SX from the row forces Y (a list; labels, P as mode_rows')."""
    lamN, lamT = [ca.SX(0)] * m, [ca.SX(0)] * m
    for i, (kind, j) in enumerate(labels):
        if kind == "N":
            lamN[j] = Y[i]
            if P[m + j, i] != 0.0:  # a slide: friction at the cone's bound
                lamT[j] = float(P[m + j, i]) * Y[i]
        elif kind == "T":
            lamT[j] = Y[i]
    return lamN, lamT


def segment_integrator(pb, fn, name, tol, substeps: int = 0) -> ca.Function:
    """One segment in the modes of ``fn`` (:func:`mode_dynamics`): x0 = (q, v), p = (t_seg, d, t_k,
    h_k, u_a, u_b) -> xf, qf = the integrals of lambda_N and lambda_T over the segment (the
    distribution ``fn`` gives: for redundant rows, the kept rows' forces) at the fractions GRID of
    it, by CVODES with the options ``tol``, or with ``substeps`` > 0 by :func:`rk4_segment`. The
    control is u_a + (t - t_k) / h_k (u_b - u_a) (the hold's value on interval k)."""
    sys, nu = pb.system, pb.nu
    n = sys.n
    x = ca.SX.sym("x", 2 * n)
    p = ca.SX.sym("p", 4 + 2 * nu)
    tau = ca.SX.sym("tau")
    t_seg, d, t_k, h_k = p[0], p[1], p[2], p[3]
    ua, ub = p[4:4 + nu], p[4 + nu:]
    t = t_seg + tau * d
    u = ua + (t - t_k) / h_k * (ub - ua)
    a, lamN, lamT = fn(t, x[:n], x[n:], u)[:3]
    if substeps:  # classical Runge-Kutta, fixed steps, in SX (exact derivatives of any order)
        return rk4_segment(name, x, p, tau, ca.vertcat(x[n:], a) * d, ca.vertcat(lamN, lamT) * d, substeps)
    dae = {"x": x, "p": p, "t": tau, "ode": d * ca.vertcat(x[n:], a), "quad": d * ca.vertcat(lamN, lamT)}
    return ca.integrator(name, "cvodes", dae, 0.0, list(GRID), {**tol, "max_num_steps": 100000})


def rk4_segment(name, x, p, tau, ode, quad, substeps):
    """(x0, p) -> (xf, qf) at the fractions GRID of [0, 1], by the classical Runge-Kutta method with
    ``substeps`` steps per grid interval, quadratures integrated alongside (one SX function per
    mode: evaluated by CasADi's SX virtual machine, 5-6x faster than the same steps repeated by
    ``mapaccum`` in MX on the motor)."""
    f = ca.Function("f", [tau, x, p], [ode, quad])
    x0, p0 = ca.SX.sym("x0", x.shape[0]), ca.SX.sym("p", p.shape[0])
    xs, qs = x0, ca.SX.zeros(quad.shape[0], 1)
    outs_x, outs_q, t0 = [], [], 0.0
    for g in GRID:
        dt = (g - t0) / substeps
        for i in range(substeps):
            t = t0 + i * dt
            k1, l1 = f(t, xs, p0)
            k2, l2 = f(t + dt / 2, xs + dt / 2 * k1, p0)
            k3, l3 = f(t + dt / 2, xs + dt / 2 * k2, p0)
            k4, l4 = f(t + dt, xs + dt * k3, p0)
            xs = xs + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            qs = qs + dt / 6 * (l1 + 2 * l2 + 2 * l3 + l4)
        outs_x.append(xs)
        outs_q.append(qs)
        t0 = g
    # JAC_PENALTY: where the NLP's derivatives ask a segment for more forward directions than half
    # its inputs, CasADi builds the segment's Jacobian once rather than that many directional
    # derivatives (the seven blocks at N = 50: 21 segment functions, each forward(64) 7.3e5
    # instructions against 7.1e4 for the Jacobian; the shooting NLP's build 5.4 -> 2.9 s, its
    # solve 1.9 -> 1.1 s at the same optimum; the same derivatives rounded differently sent IPOPT
    # another way through the cart-pole's failing swing-up round at N = 40, 63 -> 126 s)
    return ca.Function(name, [x0, p0], [ca.horzcat(*outs_x), ca.horzcat(*outs_q)], ["x0", "p"], ["xf", "qf"],
                       {"jac_penalty": JAC_PENALTY})


def impulse_dv(system, q, impacts):
    """The velocity change of the given impulses (numbers: the initial point)."""
    sys = system
    m = sys.n_contacts
    H = sys.contact_jacobian(q)
    rhs = sum(H[c] * pn + H[m + c] * pt for c, _, pn, pt in impacts)
    return np.linalg.solve(sys.mass(q), rhs)
