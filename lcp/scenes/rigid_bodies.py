"""Scenes of free rigid bodies in 3D (Newton-Euler kinematics, unit quaternions).

- :func:`dzhanibekov`: the torque-free asymmetric body spun near its intermediate axis (the
  Dzhanibekov flip), with the exact period of Euler's equations (:func:`euler_period`);
- :func:`tumbling_box`: a cube dropped tilted onto a plane, eight spatial corner contacts.

Built with :mod:`lcp.model.rigid_body`. Imports the model and :mod:`lcp.scenes.scene` only; never
the simulation, sweeps or optimal control.
"""
from __future__ import annotations

import math

import casadi as ca
import numpy as np

from lcp.model.kinematics import quat_exp
from lcp.model.rigid_body import bodies_system, free_body
from lcp.model.system import Contact
from lcp.scenes.scene import Scene

__all__ = ["dzhanibekov", "euler_period", "tumbling_box"]


def euler_period(moments, omega0) -> float:
    """The period of the body angular velocity omega(t) of the torque-free body (Euler's equations).

    With principal moments I1 < I2 < I3 (in any order here: sorted, omega0 permuted along), energy
    2E = sum I_i w_i^2 and M^2 = sum I_i^2 w_i^2, Landau-Lifshitz (Mechanics, section 37) give
    omega in Jacobi's elliptic functions of tau = t sqrt((I3 - I2)(M^2 - 2E I1)/(I1 I2 I3)) with
    modulus k^2 = (I2 - I1)(2E I3 - M^2) / ((I3 - I2)(M^2 - 2E I1)) where M^2 > 2E I2 (for
    M^2 < 2E I2 exchange the roles of I1 and I3); sn and cn have period 4K(k) in tau, so

        T = 4 K(k) sqrt(I1 I2 I3 / ((I3 - I2)(M^2 - 2E I1))).

    The intermediate component w2 ~ sn changes sign twice per period: a flip every T/2.

    Raises
    ------
    ValueError
        Equal moments or M^2 = 2E I2 exactly (the separatrix: infinite period), or a spin about a
        principal axis (no motion of omega).

    Examples
    --------
    Near the stable axis of largest moment the period tends to that of the linearised motion,
    2 pi / (w3 sqrt((I3 - I1)(I3 - I2)/(I1 I2))):

    >>> T = euler_period([1.0, 2.0, 3.0], [1e-6, 1e-6, 1.0])
    >>> round(T / (2 * math.pi / math.sqrt(2.0 * 1.0 / 2.0)), 9)
    1.0
    """
    from scipy.special import ellipk

    order = np.argsort(moments)
    I1, I2, I3 = (float(x) for x in np.asarray(moments, dtype=float)[order])
    w = np.asarray(omega0, dtype=float)[order]
    if not (I1 < I2 < I3):
        raise ValueError(f"euler_period needs three distinct principal moments, got {moments!r}")
    E2 = I1 * w[0] ** 2 + I2 * w[1] ** 2 + I3 * w[2] ** 2
    M2 = I1 ** 2 * w[0] ** 2 + I2 ** 2 * w[1] ** 2 + I3 ** 2 * w[2] ** 2
    if M2 < E2 * I2:  # rotation about the axis of least moment: exchange I1 and I3
        I1, I3 = I3, I1
    denom = (I3 - I2) * (M2 - E2 * I1)
    k2 = (I2 - I1) * (E2 * I3 - M2) / denom if denom != 0 else float("nan")
    if not (0 <= k2 < 1) or denom == 0:
        raise ValueError(f"euler_period: omega0 = {list(omega0)} lies on the separatrix or a principal axis "
                         f"(k^2 = {k2!r})")
    return float(4 * ellipk(k2) * math.sqrt(I1 * I2 * I3 / denom))


def dzhanibekov(moments=(1.0, 2.0, 3.0), spin: float = 6.0, perturbation: float = 0.02,
                t_end: float = 10.0) -> Scene:
    """A torque-free body spun about its intermediate axis with a small perturbation: it flips.

    Body frame = principal axes, moments ``moments`` (the second the intermediate one), omega0 =
    (perturbation, spin, perturbation), at rest at the origin, p0 = (1, 0, 0, 0). The scene carries
    ``body`` (:class:`~lcp.model.rigid_body.RigidBody`), ``flip_period`` (half the period of
    omega, :func:`euler_period`: the time between two sign changes of the intermediate component),
    ``energy(q, v)`` and ``angular_momentum(q, v)`` (world frame).

    Examples
    --------
    >>> sc = dzhanibekov()
    >>> sc.system.n_q, sc.system.n, round(sc.flip_period, 6)
    (7, 6, 3.893327)
    """
    J = np.diag(np.asarray(moments, dtype=float))
    body = free_body(1.0, J, name="body")
    w0 = np.array([perturbation, spin, perturbation], dtype=float)
    sc = Scene(bodies_system([body]), np.array([0, 0, 0, 1.0, 0, 0, 0]), np.concatenate([np.zeros(3), w0]),
               float(t_end), "dzhanibekov", {"moments": tuple(moments), "spin": spin, "perturbation": perturbation})
    sc.body = body
    sc.flip_period = euler_period(np.diag(J), w0) / 2
    sc.energy = lambda q, v: 0.5 * float(v[3:] @ J @ v[3:]) + 0.5 * float(v[:3] @ v[:3])
    sc.angular_momentum = body.angular_momentum
    return sc


def tumbling_box(side: float = 1.0, mass: float = 1.0, mu: float = 0.3, e: float = 0.0, height: float = 1.5,
                 tilt=(1.0, 2.0, 0.5), angle: float = 0.6, v0=(0.5, 0.0, 0.0), omega0=(1.0, -2.0, 0.5),
                 g: float = 9.81, t_end: float = 3.0) -> Scene:
    """A cube dropped tilted onto the plane z = 0: eight spatial corner contacts.

    The cube (side ``side``, uniform: J = m side^2/6 I, isotropic, so omega stays constant in free
    flight) starts with its centre at height ``height``, turned by ``angle`` about the axis
    ``tilt``, with centre velocity ``v0`` (world) and angular velocity ``omega0`` (body). Each
    corner r is a contact with gap e_z . (x + R(p) r) and tangents the corner's x and y (their
    Jacobians in v-space: the corner's velocity), Coulomb ``mu``, restitution ``e``. The scene
    carries ``body``, ``corners`` (body frame, 8 x 3), ``energy(q, v)`` (kinetic + potential) and
    ``gap(q)`` (the eight gaps).

    Examples
    --------
    >>> sc = tumbling_box()
    >>> sc.system.n_contacts, sc.system.is_spatial, round(float(min(sc.gap(sc.q0))), 6)
    (8, True, 0.705211)
    """
    a = 0.5 * side
    body = free_body(mass, mass * side ** 2 / 6 * np.eye(3), name="box")
    corners = np.array([[sx, sy, sz] for sx in (-a, a) for sy in (-a, a) for sz in (-a, a)])
    contacts = []
    for i, r in enumerate(corners):
        P = body.point(r)
        contacts.append(Contact(gap=P[2], tangent=ca.vertcat(P[0], P[1]), mu=mu, e=e, name=f"corner{i}"))
    axis = np.asarray(tilt, dtype=float)
    p0 = quat_exp(0.5 * angle * axis / np.linalg.norm(axis))
    q0 = np.concatenate([[0.0, 0.0, height], p0])
    sc = Scene(bodies_system([body], contacts, gravity=g), q0, np.concatenate([v0, omega0]).astype(float),
               float(t_end), "tumbling_box", {"side": side, "mass": mass, "mu": mu, "e": e, "height": height,
                                              "tilt": tuple(tilt), "angle": angle, "g": g})
    sc.body, sc.corners = body, corners
    Jb = body.inertia
    sc.energy = lambda q, v: (0.5 * mass * float(v[:3] @ v[:3]) + 0.5 * float(v[3:] @ Jb @ v[3:])
                              + mass * g * float(q[2]))
    gap_fn = ca.Function("corner_gaps", [body.q], [ca.vertcat(*(c.gap for c in contacts))])
    sc.gap = lambda q: np.array(gap_fn(np.asarray(q, dtype=float)[:7]), dtype=float).ravel()
    return sc
