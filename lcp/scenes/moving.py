"""Scenes with moving contacts: time-dependent gaps and tangents (Moreau-Jean only).

Holds :func:`moving_table` (a ball bouncing on a table that moves up and down, with its reference
written with the table as a coordinate pinned by a rheonomous bilateral constraint, which the event
method integrates) and :func:`conveyor` (a block put on a moving belt, with its closed form,
:class:`ConveyorExact`). Imports the model and :mod:`lcp.scenes.scene` only; never the simulation,
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

__all__ = ["moving_table", "conveyor", "ConveyorExact"]


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
