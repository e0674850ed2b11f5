"""Scenes with moving contacts: time-dependent gaps and tangents (both methods).

Holds :func:`moving_table` (a ball bouncing on a table that moves up and down, with its reference
written with the table as a coordinate pinned by a rheonomous bilateral constraint, which the event
method integrates) and :func:`conveyor` (a block put on a moving belt, with its closed form,
:class:`ConveyorExact`), :func:`cam_follower` (a spring-loaded follower on a moving cam surface, with
its pinned form) and :func:`table_impacts` (the moving table's impacts, semi-analytic). Imports the model and :mod:`lcp.scenes.scene` only; never the simulation,
the time stepping or the event method.

A moving contact's local velocity is u = H(t, q) v + b(t, q), b = (dg/dt, ds/dt)
(:attr:`lcp.model.system.System.contact_rate_fn`): the relative velocity of the ball and the table,
of the block and the belt.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from lcp.model.system import Contact, System
from lcp.scenes.scene import Scene, check_params

__all__ = ["moving_table", "conveyor", "ConveyorExact", "cam_follower", "table_impacts"]


def moving_table(amplitude: float = 0.05, omega: float = 6.0, e: float = 0.7, height: float = 0.3,
                 g: float = 9.81, t_end: float = 1.5, pinned: bool = False) -> Scene:
    """A ball (point mass 1, q = (x, y)) dropped from ``height`` at rest onto a table at height
    s(t) = amplitude sin(omega t), frictionless, Newton restitution ``e``: the gap y - s(t)
    depends on time.

    With ``pinned`` the same physics in the form the event method integrates: q = (x, y, z), the
    table z (mass 1) pinned by the rheonomous bilateral constraint z - s(t) = 0 and the gap
    y - z depends on q only. Its y is the reference of the time-dependent form.

    Examples
    --------
    >>> from lcp.scenes.moving import moving_table
    >>> sc = moving_table()
    >>> sc.system.contacts_depend_on_t, moving_table(pinned=True).system.contacts_depend_on_t
    (True, False)
    """
    check_params(amplitude=amplitude, omega=omega, height=height, g=g, t_end=t_end)
    if not 0 <= e <= 1:
        raise ValueError(f"e must lie in [0, 1], got {e!r}")
    t = ca.SX.sym("t")
    s = amplitude * ca.sin(omega * t)
    params = dict(amplitude=amplitude, omega=omega, e=e, height=height, g=g, pinned=pinned)
    if not pinned:
        q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
        system = System(q, v, ca.SX.eye(2), ca.vertcat(0, -g), t=t, names=("x", "y"),
                        contacts=[Contact(gap=q[1] - s, tangent=q[0], mu=0.0, e=e, name="table")])
        return Scene(system, np.array([0.0, height]), np.zeros(2), float(t_end), "moving_table", params,
                     no_exact_reason="the reference is moving_table(pinned=True) by the event method")
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    system = System(q, v, ca.SX.eye(3), ca.vertcat(0, -g, 0), t=t, names=("x", "y", "z"),
                    constraints=[q[2] - s],
                    contacts=[Contact(gap=q[1] - q[2], tangent=q[0], mu=0.0, e=e, name="table")])
    return Scene(system, np.array([0.0, height, 0.0]), np.array([0.0, 0.0, amplitude * omega]), float(t_end),
                 "moving_table_pinned", params, no_exact_reason="no closed form (the reference itself)")


class ConveyorExact:
    """The block on the belt: x' = v0 + mu g t until it moves with the belt (t_stick = (V - v0) /
    (mu g) for v0 < V), then x' = V; y = 0, N = m g, friction force m mu g then 0."""

    def __init__(self, V, mu, g, m, v0):
        self.V, self.mu, self.g, self.m, self.v0 = V, mu, g, m, v0
        a = mu * g * float(np.sign(V - v0))
        self.accel = a
        self.t_stick = float((V - v0) / a) if a else 0.0
        self.switch_times = np.array([self.t_stick])

    def __call__(self, t) -> dict:
        t = np.asarray(t, dtype=float)
        ts, a, v0 = self.t_stick, self.accel, self.v0
        tt = np.minimum(t, ts)
        x = v0 * tt + 0.5 * a * tt * tt + self.V * np.maximum(t - ts, 0.0)
        xdot = np.where(t < ts, v0 + a * t, self.V)
        f = np.where(t < ts, self.m * a, 0.0)
        return dict(x=x, xdot=xdot, y=np.zeros_like(t), N=np.full_like(t, self.m * self.g), f=f)


def conveyor(V: float = 1.0, mu: float = 0.4, g: float = 9.81, m: float = 1.0, v0: float = 0.0,
             t_end: float | None = None) -> Scene:
    """A block (q = (x, y), mass ``m``) put with velocity ``v0`` on a belt moving at ``V``: the
    tangent s(t, q) = x - V t measures the sliding on the belt, whose friction ``mu`` drags the
    block until it moves with the belt (:class:`ConveyorExact`). Default horizon: 2 t_stick.

    Examples
    --------
    >>> from lcp.scenes.moving import conveyor
    >>> sc = conveyor(V=1.0, mu=0.5, g=10.0)
    >>> sc.solution.t_stick, float(sc.exact(1.0)["x"])
    (0.2, 0.9)
    """
    check_params(V=abs(V) if V else 1.0, mu=mu, g=g, m=m)
    t = ca.SX.sym("t")
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    system = System(q, v, m * ca.SX.eye(2), ca.vertcat(0, -m * g), t=t, names=("x", "y"),
                    contacts=[Contact(gap=q[1], tangent=q[0] - V * t, mu=mu, name="belt")])
    sol = ConveyorExact(float(V), float(mu), float(g), float(m), float(v0))
    if t_end is None:
        t_end = 2 * sol.t_stick if sol.t_stick > 0 else 1.0
    return Scene(system, np.zeros(2), np.array([float(v0), 0.0]), float(t_end), "conveyor",
                 dict(V=V, mu=mu, g=g, m=m, v0=v0), sol)


def cam_follower(k: float = 50.0, rest: float = 1.0, radius: float = 1.0, amplitude: float = 0.1,
                 omega: float = 10.0, e: float = 0.8, height: float = 1.3, m: float = 1.0, g: float = 9.81,
                 t_end: float = 1.0, pinned: bool = False) -> Scene:
    """A follower (q = (x, y), mass ``m``) held by a spring of stiffness ``k`` towards the height
    ``rest`` and by gravity above a cam whose surface moves as c(t) = radius + amplitude sin(omega t):
    the gap y - c(t) depends on time, frictionless, Newton restitution ``e``; released at rest at
    ``height``. With the defaults the spring and gravity pull the follower onto the cam: three
    impacts by t = 1, then it rides and bounces on the moving surface.

    With ``pinned`` the same physics with the cam surface a coordinate z (mass 1) pinned by the
    rheonomous bilateral constraint z - c(t) = 0 and the gap y - z of q only: the form both
    methods integrated before the event method took time-dependent gaps, its reference.

    Examples
    --------
    >>> from lcp.scenes.moving import cam_follower
    >>> sc = cam_follower()
    >>> sc.system.contacts_depend_on_t, cam_follower(pinned=True).system.n_bilateral
    (True, 1)
    """
    check_params(k=k, rest=rest, radius=radius, amplitude=amplitude, omega=omega, height=height, m=m, g=g,
                 t_end=t_end)
    if not 0 <= e <= 1:
        raise ValueError(f"e must lie in [0, 1], got {e!r}")
    t = ca.SX.sym("t")
    c = radius + amplitude * ca.sin(omega * t)
    params = dict(k=k, rest=rest, radius=radius, amplitude=amplitude, omega=omega, e=e, height=height, m=m, g=g,
                  pinned=pinned)
    if not pinned:
        q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
        system = System(q, v, m * ca.SX.eye(2), ca.vertcat(0, -k * (q[1] - rest) - m * g), t=t, names=("x", "y"),
                        contacts=[Contact(gap=q[1] - c, tangent=q[0], mu=0.0, e=e, name="cam")])
        return Scene(system, np.array([0.0, height]), np.zeros(2), float(t_end), "cam_follower", params,
                     no_exact_reason="the reference is cam_follower(pinned=True)")
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    system = System(q, v, ca.diag(ca.vertcat(m, m, 1.0)), ca.vertcat(0, -k * (q[1] - rest) - m * g, 0), t=t,
                    names=("x", "y", "z"), constraints=[q[2] - c],
                    contacts=[Contact(gap=q[1] - q[2], tangent=q[0], mu=0.0, e=e, name="cam")])
    return Scene(system, np.array([0.0, height, radius]), np.array([0.0, 0.0, amplitude * omega]), float(t_end),
                 "cam_follower_pinned", params, no_exact_reason="no closed form (the reference itself)")


def table_impacts(amplitude: float, omega: float, e: float, height: float, g: float = 9.81, n_impacts: int = 3,
                  t0: float = 0.0, y0: float | None = None, ydot0: float = 0.0) -> np.ndarray:
    """Semi-analytic impacts of the ball of :func:`moving_table`: rows (t_i, u_i-, u_i+) of the first
    ``n_impacts`` impacts, u the relative normal velocity ydot - s'(t) before and after (u+ = -e u-).

    Each free flight is the parabola y(t) = y_k + ydot_k (t - t_k) - g (t - t_k)^2 / 2; its landing
    is the first zero of y(t) - amplitude sin(omega t) after t_k, bracketed by sampling at 1/400 of
    the table's period and refined by Brent's method to the last bits of t (a landing that only
    grazes the table between two samples is not seen: the reference is for clear bounces).

    Examples
    --------
    >>> import math
    >>> t1 = table_impacts(0.0, 6.0, 0.5, 0.3, n_impacts=1)[0, 0]  # a table at rest: sqrt(2 h / g)
    >>> bool(abs(t1 - math.sqrt(0.6 / 9.81)) < 1e-15)
    True
    """
    from scipy.optimize import brentq  # only for the reference (keeps `import lcp` cheap)

    a, w = float(amplitude), float(omega)
    tk, yk = float(t0), float(height if y0 is None else y0)
    vk = float(ydot0)
    dt = 2 * np.pi / w / 400

    def gap(t):
        s = t - tk
        return yk + vk * s - 0.5 * g * s * s - a * np.sin(w * t)

    out = []
    for _ in range(n_impacts):
        lo = tk
        hi = tk + dt
        while gap(hi) > 0.0:
            lo, hi = hi, hi + dt
            if hi - tk > 1e3 * dt * 400:
                raise ValueError("no landing found within 1000 table periods")
        ti = brentq(gap, lo, hi, xtol=1e-16, rtol=4 * np.finfo(float).eps, maxiter=200)
        ydot = vk - g * (ti - tk)
        sdot = a * w * np.cos(w * ti)
        u_minus = ydot - sdot
        u_plus = -e * u_minus
        out.append((ti, u_minus, u_plus))
        tk, yk, vk = ti, a * np.sin(w * ti), sdot + u_plus
    return np.array(out)
