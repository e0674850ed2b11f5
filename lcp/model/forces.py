"""Generalized forces of forces and torques applied to material points, by virtual work.

A force F acting at a material point whose position is r(q) does the virtual work F' dr = F' J dq,
J = dr/dq, so its generalized force is J(q)' F. A torque tau about an angle coordinate
theta(q) gives (d theta/dq)' tau. F and tau may depend on time, positions and velocities (a
follower load, a damper); the Jacobians are CasADi's, so nothing is derived by hand.

For a system with Newton-Euler kinematics (qdot = T(q) v, ``System(..., kinematics=T)``, a free
rigid body of :mod:`lcp.model.rigid_body`), forces and velocities live in v-space: pass
``kinematics=T`` and the generalized force is T' J' F (the virtual power F' J T v), the point's
velocity J T v.

Time-dependent forces need the System's time symbol: build them from a symbol ``t`` and pass the
same one as ``System(..., t=t)``; without it CasADi refuses to build the System's functions
("variables [t] are free"). The Moreau-Jean step weights such a force as
(1 - theta) F(t_k) + theta F(t_k + h): second order for theta = 1/2.

Examples
--------
A pendulum of length L written in its angle theta, pushed horizontally at its tip by F(t):

>>> import casadi as ca
>>> from lcp.model.forces import point_force
>>> theta, t = ca.SX.sym("theta"), ca.SX.sym("t")
>>> L = 2.0
>>> tip = ca.vertcat(L * ca.sin(theta), -L * ca.cos(theta))
>>> Q = point_force(theta, tip, ca.vertcat(3 * t, 0))
>>> float(ca.substitute(Q, ca.vertcat(theta, t), ca.DM([0.0, 1.0])))  # L cos(theta) F_x
6.0
"""
from __future__ import annotations

import casadi as ca

__all__ = ["applied_forces", "point_force", "point_velocity", "torque"]


def _column(x, name: str) -> ca.SX:
    try:
        x = x if isinstance(x, ca.SX) else ca.SX(x) if not isinstance(x, (list, tuple)) else ca.vertcat(*x)
    except Exception as exc:
        raise ValueError(f"{name} must be a CasADi SX expression or a list of them") from exc
    if x.shape[1] != 1:
        if x.shape[0] == 1:
            x = x.T
        else:
            raise ValueError(f"{name} must be a column, got shape {x.shape}")
    return x


def _coordinates(q) -> ca.SX:
    if not isinstance(q, ca.SX) or not q.is_symbolic() or q.shape[1] != 1:
        raise ValueError("q must be the column of coordinate symbols (casadi.SX.sym('q', n))")
    return q


def _v_space(J, q, kinematics) -> ca.SX:
    """J T for a system with kinematics (T: n_q x n_v), J itself without."""
    if kinematics is None:
        return J
    T = kinematics if isinstance(kinematics, ca.SX) else ca.SX(kinematics)
    if T.shape[0] != q.shape[0]:
        raise ValueError(f"kinematics must have n_q = {q.shape[0]} rows, got shape {T.shape}")
    return ca.mtimes(J, T)


def point_force(q, r, F, kinematics=None) -> ca.SX:
    """Generalized force of a force ``F`` applied at the material point ``r(q)``.

    Parameters
    ----------
    q : casadi.SX
        Coordinate symbols (n x 1), as given to :class:`lcp.model.system.System`.
    r : casadi.SX or list
        Position of the point (d x 1, d = 2 or 3), an expression of q (and possibly t).
    F : casadi.SX or list
        Force (d x 1), an expression of t, q and v.
    kinematics : casadi.SX, optional
        T(q) of a system with Newton-Euler kinematics (n_q x n_v): the force is then in v-space.

    Returns
    -------
    casadi.SX
        J(q)' F, n x 1, with J = dr/dq (with kinematics: (J T)' F, n_v x 1).

    Examples
    --------
    >>> import casadi as ca
    >>> q = ca.SX.sym("q", 3)  # x, y, angle of a body
    >>> x, y, a = q[0], q[1], q[2]
    >>> corner = ca.vertcat(x + ca.cos(a), y + ca.sin(a))
    >>> Q = point_force(q, corner, [0.0, 5.0])
    >>> ca.evalf(ca.substitute(Q, q, ca.DM([0.0, 0.0, 0.0]))).T  # vertical force at arm 1: torque 5
    DM([[0, 5, 5]])
    """
    q = _coordinates(q)
    r, F = _column(r, "r"), _column(F, "F")
    if r.shape != F.shape:
        raise ValueError(f"r and F must have the same shape, got {r.shape} and {F.shape}")
    return ca.mtimes(_v_space(ca.jacobian(r, q), q, kinematics).T, F)


def point_velocity(q, v, r, kinematics=None) -> ca.SX:
    """Velocity J(q) v of the material point ``r(q)`` (time-independent r), e.g. for a damper
    ``F = -c * point_velocity(q, v, r)``; J T v with ``kinematics=T`` (v then has n_v entries)."""
    q = _coordinates(q)
    r = _column(r, "r")
    if not isinstance(v, ca.SX) or (v.shape != q.shape and kinematics is None):
        raise ValueError("v must be the column of velocity symbols, shaped like q")
    J = _v_space(ca.jacobian(r, q), q, kinematics)
    if J.shape[1] != v.shape[0]:
        raise ValueError(f"v must have n_v = {J.shape[1]} entries, got {v.shape[0]}")
    return ca.mtimes(J, v)


def torque(q, angle, tau, kinematics=None) -> ca.SX:
    """Generalized force of a torque ``tau`` about the planar angle ``angle(q)``: (d angle/dq)' tau."""
    q = _coordinates(q)
    angle, tau = _column(angle, "angle"), _column(tau, "tau")
    if angle.numel() != 1 or tau.numel() != 1:
        raise ValueError("angle and tau must be scalar expressions")
    return _v_space(ca.jacobian(angle, q), q, kinematics).T * tau


def applied_forces(q, loads, kinematics=None) -> ca.SX:
    """Sum of the generalized forces of ``loads``, a sequence of (r, F) pairs (see :func:`point_force`;
    in v-space with ``kinematics=T``).

    Examples
    --------
    >>> import casadi as ca
    >>> q = ca.SX.sym("q", 2)
    >>> ca.evalf(applied_forces(q, [(q, [0.0, -9.81]), (2 * q, [1.0, 0.0])])).T
    DM([[2, -9.81]])
    """
    q = _coordinates(q)
    total = ca.SX.zeros(q.shape[0] if kinematics is None else ca.SX(kinematics).shape[1], 1)
    for r, F in loads:
        total = total + point_force(q, r, F, kinematics)
    return total
