"""The dynamics of one smooth phase of a contact-mode sequence, for the exact-phase shooting.

:func:`mode_dynamics` gives the accelerations and contact forces of a system in fixed contact
modes (index reduction at the acceleration level), :func:`rk4_segment` integrates one phase on a
fixed grid in SX (the shooting's NLP), :func:`impulse_dv` applies impact impulses (numbers).
Imports CasADi, NumPy and the contact mode codes; it must not import the shooting, the solve or
the problem (they call it).
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from lcp.contact.modes import OPEN, SLIDE_NEG, SLIDE_POS, STICK

__all__ = ["GRID", "impulse_dv", "mode_dynamics", "rk4_segment"]

#: the integrator's output times within a segment (fractions of it): the modes are kept
#: admissible there and at the segment's start (a slide whose velocity changed sign between its
#: two ends kept the cart-pole's ends admissible while its replay stuck: a miss of 1.9)
GRID = (0.25, 0.5, 0.75, 1.0)


def mode_dynamics(pb, modes) -> ca.Function:
    """(t, q, v, u) -> (a, lambda_N (m), lambda_T (m), normal and tangential accelerations
    H a + dH/dt v (2 m)) of problem ``pb``'s system in the given modes (codes, one per contact):
    the closed contacts' normal accelerations zero, the sticking ones' tangential too, the sliding
    ones' friction at the cone's bound against the slide, the bilateral constraints held."""
    sys = pb.system
    n, m, nb = sys.n, sys.n_contacts, sys.n_bilateral
    t, q, v = sys.t_sym, sys.q_sym, sys.v_sym
    u = ca.SX.sym("u", pb.nu)
    H = sys.H_expr if m else ca.SX.zeros(0, n)
    Hdot_v = ca.mtimes(ca.jacobian(ca.mtimes(H, v), q), v) if m else ca.SX.zeros(0, 1)
    cols, rows, rhs = [], [], []
    closed = [j for j in range(m) if modes[j] != OPEN]
    stick = [j for j in range(m) if modes[j] == STICK]
    mu = np.asarray(sys.mu, dtype=float)
    for j in closed:
        col = H[j, :].T
        if modes[j] in (SLIDE_POS, SLIDE_NEG):  # friction -s mu lambda_N along the tangent
            s = 1.0 if modes[j] == SLIDE_POS else -1.0
            col = col - s * mu[j] * H[m + j, :].T
        cols.append(col)
        rows.append(H[j, :])
        rhs.append(-Hdot_v[j])
    for j in stick:
        cols.append(H[m + j, :].T)
        rows.append(H[m + j, :])
        rhs.append(-Hdot_v[m + j])
    if nb:
        G = ca.jacobian(sys.constraints_expr, q)
        Gdot_v = ca.mtimes(ca.jacobian(ca.mtimes(G, v), q), v)
        for i in range(nb):
            cols.append(G[i, :].T)
            rows.append(G[i, :])
            rhs.append(-Gdot_v[i])
    F = sys.force_expr + ca.mtimes(sys.control_matrix_expr, u)
    r = len(cols)
    if r:
        K = ca.vertcat(ca.horzcat(sys.mass_expr, -ca.horzcat(*cols)), ca.horzcat(ca.vertcat(*rows),
                                                                                  ca.SX.zeros(r, r)))
        y = ca.solve(K, ca.vertcat(F, *rhs))
    else:
        y = ca.solve(sys.mass_expr, F)
    a = y[:n]
    lamN, lamT = [ca.SX(0)] * m, [ca.SX(0)] * m
    for i, j in enumerate(closed):
        lamN[j] = y[n + i]
        if modes[j] in (SLIDE_POS, SLIDE_NEG):
            lamT[j] = -(1.0 if modes[j] == SLIDE_POS else -1.0) * mu[j] * y[n + i]
    for i, j in enumerate(stick):
        lamT[j] = y[n + len(closed) + i]
    acc = ca.mtimes(H, a) + Hdot_v if m else ca.SX.zeros(0, 1)
    return ca.Function(f"mode_{''.join(map(str, modes))}", [t, q, v, u],
                       [a, ca.vertcat(*lamN) if m else ca.SX.zeros(0, 1),
                        ca.vertcat(*lamT) if m else ca.SX.zeros(0, 1), acc])


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
    return ca.Function(name, [x0, p0], [ca.horzcat(*outs_x), ca.horzcat(*outs_q)], ["x0", "p"], ["xf", "qf"])


def impulse_dv(system, q, impacts):
    """The velocity change of the given impulses (numbers: the initial point)."""
    sys = system
    m = sys.n_contacts
    H = sys.contact_jacobian(q)
    rhs = sum(H[c] * pn + H[m + c] * pt for c, _, pn, pt in impacts)
    return np.linalg.solve(sys.mass(q), rhs)
