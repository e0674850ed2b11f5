"""Locating the events that end a smooth phase.

Events
------
- a sliding velocity reaching zero (``"stop"``);
- a normal force reaching zero (``"lift-off"``);
- a stick force reaching the friction bound (``"slip"``);
- a gap closing (``"impact"``).

In a closed-form phase (constant accelerations) the stop and the landing are roots of linear and
quadratic polynomials, computed without cancellation. In a SciPy phase they are zeros of event
functions with ``.terminal`` and ``.direction``, located by ``solve_ivp`` on its dense output.
"""
from __future__ import annotations

import itertools
import math

import numpy as np

__all__ = ["approach_gap", "event_functions", "first_descent", "first_landing", "first_stop",
           "first_terminal_event", "too_many_events"]


def first_stop(u0: float, a: float, s: float) -> float:
    """Time dt > 0 at which a sliding velocity u0 (sign s) under constant acceleration a stops;
    inf if it does not decelerate. One division: no cancellation."""
    if s * a < 0 and s * u0 > 0:
        return -u0 / a
    return math.inf


def first_landing(g0: float, u: float, a: float) -> float:
    """Smallest dt > 0 with g0 + u dt + a dt^2/2 = 0 and the gap decreasing; inf if none.

    Roots by the cancellation-free pair q/(a/2) and g0/q with q = -(u + sign(u) sqrt(disc))/2.
    """
    h = 0.5 * a
    if h == 0.0:
        return -g0 / u if u < 0 and g0 >= 0 else math.inf
    disc = u * u - 4.0 * h * g0
    if disc < 0:
        return math.inf
    qq = -0.5 * (u + math.copysign(math.sqrt(disc), u))
    roots = [qq / h]
    if qq != 0.0:
        roots.append(g0 / qq)
    good = [r for r in roots if r > 0 and u + a * r <= 0]
    return min(good) if good else math.inf


def _horner(c, x: float) -> float:
    s = 0.0
    for ci in reversed(c):
        s = s * x + ci
    return s


def _quadratic_roots(c0: float, c1: float, c2: float) -> list:
    """Real roots of c0 + c1 x + c2 x^2 (c2 may be 0), without cancellation."""
    if c2 == 0.0:
        return [-c0 / c1] if c1 != 0.0 else []
    disc = c1 * c1 - 4.0 * c2 * c0
    if disc < 0.0:
        return []
    qq = -0.5 * (c1 + math.copysign(math.sqrt(disc), c1))
    if qq == 0.0:
        return [0.0]
    return [qq / c2, c0 / qq]


def first_descent(c, T: float) -> float:
    """Smallest dt in (0, T) at which p(dt) = c[0] + c[1] dt + ... (degree <= 3) falls from
    positive to zero; inf if none.

    [0, T] is cut at the critical points of p (roots of p', without cancellation) into intervals
    where p is monotone; the root is searched in the first decreasing one that brackets it: by
    one division for a linear p, by the cancellation-free quadratic formula for a quadratic
    (the root in the bracket), by bisection to the last bit for a cubic.

    Examples
    --------
    >>> first_descent([1.0, -2.0], 10.0), first_descent([1.0, -2.0], 0.3)
    (0.5, inf)
    >>> round(first_descent([2.0, 0.0, 0.0, -2.0], 10.0), 15)  # 2 - 2 dt^3
    1.0
    """
    c = [float(x) for x in c]
    while len(c) > 1 and c[-1] == 0.0:
        c.pop()
    deg = len(c) - 1
    if deg < 1 or not T > 0.0:
        return math.inf
    if deg == 1:
        if c[0] > 0.0 and c[1] < 0.0:
            dt = -c[0] / c[1]
            return dt if dt < T else math.inf
        return math.inf
    d = [c[1], 2.0 * c[2], 3.0 * c[3] if deg == 3 else 0.0]
    cuts = sorted(x for x in _quadratic_roots(*d) if 0.0 < x < T)
    edges = [0.0, *cuts, T]
    pa = c[0]
    for a, b in itertools.pairwise(edges):
        pb = _horner(c, b)
        if pa > 0.0 >= pb:
            if deg == 2:
                inside = [x for x in _quadratic_roots(*c) if a <= x <= b]
                if inside:
                    dt = min(inside)
                    return dt if 0.0 < dt < T else math.inf
            lo, hi = a, b  # p(lo) > 0 >= p(hi): bisect to adjacent floats
            while True:
                mid = 0.5 * (lo + hi)
                if not lo < mid < hi:
                    break
                if _horner(c, mid) > 0.0:
                    lo = mid
                else:
                    hi = mid
            return hi if hi < T else math.inf
        pa = pb
    return math.inf


def event_functions(phase, t0, y0, force_tol: float = 0.0, vel_tol: float = 0.0):
    """Terminal event functions of a SciPy phase (an :class:`~lcp.events.ode_phase.OdePhase`)
    starting at (t0, y0): (functions, (kind, contact) per function). Each decreases through zero
    at its event.

    A phase of redundant contacts (``phase.indeterminate``) has one force event, its force margin
    (kind ``"force-limit"``), in place of the per-contact lift-off and slip events: its forces are
    not unique, so the phase ends only when no admissible forces remain.

    A force event that starts on its bound (|g(t0)| <= force_tol: a stick force exactly at the
    friction bound, a normal force exactly zero, that the mode decision found consistent) is
    moved to g = -force_tol: rounding-level crossings of a force held on its bound do not end
    the phase, a real departure is located within force_tol.

    A slide that starts from rest (a slip: s u_t(t0) <= 1e-3 ``vel_tol``) starts its stop function
    at zero with a zero derivative when the decided slip acceleration is at rounding level, and a
    first step whose rounding dips the velocity below zero would end the phase where it began, to
    be decided again the same way, without end. Its stop is a fall below -1e-3 ``vel_tol`` (a
    thousandth of the zero test that decided the slip), as for a spatial slide from rest.
    """
    n, m = phase.model.n, phase.model.m
    model, evaluate = phase.model, phase.evaluate
    evs, meta = [], []
    u0 = None  # the local velocities at the start (where a contact slides)

    def make(fun, kind, j, force=False):
        if force and force_tol > 0 and abs(fun(t0, y0)) <= force_tol:
            inner = fun

            def fun(t, y):
                return inner(t, y) + force_tol
        fun.terminal, fun.direction = True, -1
        evs.append(fun)
        meta.append((kind, int(j)))

    for jj, j in enumerate(phase.idx):
        s = phase.slide[jj]
        if s != 0:
            if u0 is None:
                u0 = _local_velocity(model, t0, y0, n)
            off = 0.0 if s * float(u0[m + j]) > 1e-3 * vel_tol else 1e-3 * vel_tol  # (from rest)
            make(lambda t, y, j=j, s=s, off=off: s * float(_local_velocity(model, t, y, n)[m + j]) + off, "stop", j)
        if phase.indeterminate:
            continue
        make(lambda t, y, j=j: float(evaluate(t, y)[1][j]), "lift-off", j, force=True)
        if s == 0:
            mu = phase.mu[j]
            make(lambda t, y, j=j, mu=mu: float(mu * evaluate(t, y)[1][j] - evaluate(t, y)[2][j]), "slip", j,
                 force=True)
            make(lambda t, y, j=j, mu=mu: float(mu * evaluate(t, y)[1][j] + evaluate(t, y)[2][j]), "slip", j,
                 force=True)
    if phase.indeterminate:
        make(lambda t, y: phase.margin_at(t, y)[0], "force-limit", -1, force=True)
    for j in phase.open_idx:
        make(lambda t, y, j=j: approach_gap(model, y, n, j, t), "impact", j)
    return evs, meta


def approach_gap(model, y, n, j, t=None) -> float:
    """The gap of contact j while it closes, and a positive value while it opens: a contact that
    leaves the surface starts at gap 0, and a first step too short to change the gap in floating
    point must not read as an impact. The landing is unchanged (the gap, approached with u_N < 0).
    A gap below -1e-9 (1 + |q|) is a penetration whatever u_N: an ODE step that carries a contact
    through its surface and out again (two discs passing each other within one step) must end
    negative, or the impact inside the step is missed. For a moving contact both are taken at time
    t: g(t, q(t)), u_N = H v + dg/dt."""
    nq = getattr(model, "nq", None) or n  # n_q coordinates first (Newton-Euler kinematics: n_q != n)
    q, v = y[:nq], y[nq:nq + n]
    if t is None or not model.moving:
        gap = float(model.gaps(q)[j])
        if gap > 0 or float(model.jac(q)[j] @ v) < 0:
            return gap
    else:
        gap = float(model.gaps(q, t)[j])
        if gap > 0 or float(model.local_velocity(t, q, v)[j]) < 0:
            return gap
    if gap < -1e-9 * (1.0 + float(np.max(np.abs(q), initial=0.0))):
        return gap
    return 1.0 + abs(gap)


def _local_velocity(model, t, y, n):
    """u = H v (+ b(t, q) for moving contacts) at the ODE state y = (q, v, ...)."""
    nq = getattr(model, "nq", None) or n
    if not model.moving:
        return model.jac(y[:nq]) @ y[nq:nq + n]
    return model.local_velocity(t, y[:nq], y[nq:nq + n])


def first_terminal_event(sol, meta):
    """(t, y, kind, j) of the earliest event of a ``solve_ivp`` solution that stopped on one
    (``sol.status == 1``); ``meta[i]`` is the (kind, contact) of event function i."""
    t, i = min((float(te[0]), i) for i, te in enumerate(sol.t_events) if te.size)
    kind, j = meta[i]
    return t, sol.y_events[i][0], kind, j


def too_many_events(n_events: int, short: int, t: float, max_events: int, status_message: str):
    """The message that ends an event loop (Zeno behaviour, chattering), or None while it may go on.

    ``short`` counts the consecutive phases of zero length; more than 50 of them, or more than
    ``max_events`` events, end the run.
    """
    if n_events > max_events or short > 50:
        return (f"{status_message} {n_events} events by t = {t:.10g}"
                + (f" ({short} consecutive phases of zero length)" if short > 50 else ""))
    return None
