"""Free rigid bodies in 3D: Newton-Euler coordinates with a unit quaternion.

Holds :class:`RigidBody` (one body: its symbols, mass matrix, gyroscopic force, kinematics T(q),
rotation and material points), :func:`free_body` (builds one) and :func:`bodies_system` (a
:class:`~lcp.model.system.System` of several bodies and their contacts). Imports CasADi, NumPy and
:mod:`lcp.model.system`; never the contact problem, time stepping or events.

Coordinates and velocities of one body (Siconos's NewtonEulerDS):

- q = (x, y, z, p0, p1, p2, p3): the centre of mass in the world frame and the unit quaternion p
  (scalar first) that turns body-frame vectors into world-frame ones, r_world = R(p) r_body;
- v = (vx, vy, vz, wx, wy, wz): the centre's velocity in the world frame and the angular velocity
  omega in the body frame;
- qdot = T(q) v with T = blockdiag(I, Xi(p)/2), Xi(p) omega = p (x) (0, omega);
- M = blockdiag(m I, J) (J: the inertia tensor about the centre, body frame), and the forces
  F = (f, tau - omega x J omega): the gyroscopic torque is part of the body's force.

Examples
--------
A cube of side 1 and mass 1 (J = I/6) spinning about its body z axis at 2 rad/s, dropped with no
contact: after 0.5 s by Moreau-Jean its quaternion has turned by exactly 2 * 0.5 rad about z (the
exponential map), and it has fallen g t^2/2:

>>> import numpy as np, lcp
>>> from lcp.model.rigid_body import free_body, bodies_system
>>> cube = free_body(1.0, np.eye(3) / 6, name="cube")
>>> s = bodies_system([cube], gravity=9.81)
>>> s.n_q, s.n, s.unit_quaternions
(7, 6, (3,))
>>> r = lcp.simulate(s, 0.5, h=0.01, q0=[0, 0, 0, 1, 0, 0, 0], v0=[0, 0, 0, 0, 0, 2.0])
>>> bool(abs(r.q[-1, 2] + 9.81 * 0.5**2 / 2) < 1e-13), bool(np.allclose(r.q[-1, 3:], [np.cos(0.5), 0, 0, np.sin(0.5)], atol=1e-14))
(True, True)
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from lcp.model.system import System

__all__ = ["RigidBody", "bodies_system", "free_body", "quaternion_matrix", "rotation_matrix"]


def quaternion_matrix(p) -> ca.SX:
    """Xi(p), 4 x 3, with Xi(p) omega = p (x) (0, omega) (scalar first)."""
    p0, p1, p2, p3 = p[0], p[1], p[2], p[3]
    return ca.vertcat(ca.horzcat(-p1, -p2, -p3), ca.horzcat(p0, -p3, p2), ca.horzcat(p3, p0, -p1),
                      ca.horzcat(-p2, p1, p0))


def rotation_matrix(p) -> ca.SX:
    """R(p), 3 x 3, of a unit quaternion p (scalar first): body-frame vectors to world-frame ones."""
    w, x, y, z = p[0], p[1], p[2], p[3]
    return ca.vertcat(
        ca.horzcat(1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
        ca.horzcat(2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
        ca.horzcat(2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)))


def _inertia(inertia) -> np.ndarray:
    J = np.asarray(inertia, dtype=float)
    if J.shape == (3,):
        J = np.diag(J)
    if J.shape != (3, 3) or not np.all(np.isfinite(J)):
        raise ValueError(f"inertia must be a finite 3 x 3 tensor (or its 3 principal moments), got {inertia!r}")
    if np.max(np.abs(J - J.T)) > 1e-12 * max(1.0, float(np.max(np.abs(J)))):
        raise ValueError("inertia must be symmetric")
    lam = np.linalg.eigvalsh(J)
    if lam[0] <= 0:
        raise ValueError(f"inertia must be positive definite, its principal moments are {lam.tolist()}")
    if lam[0] + lam[1] < lam[2] * (1 - 1e-12):
        raise ValueError(f"inertia violates the triangle inequality of principal moments {lam.tolist()}")
    return J


@dataclass(frozen=True)
class RigidBody:
    """One free rigid body (module docstring): symbols, mass matrix, force and kinematics.

    Attributes
    ----------
    name : str
    mass : float
    inertia : ndarray (3, 3)
        Inertia tensor about the centre of mass, body frame.
    q, v : casadi.SX
        The 7 coordinate and 6 velocity symbols.
    """

    name: str
    mass: float
    inertia: np.ndarray
    q: ca.SX
    v: ca.SX

    @property
    def position(self) -> ca.SX:
        return self.q[0:3]

    @property
    def quaternion(self) -> ca.SX:
        return self.q[3:7]

    @property
    def omega(self) -> ca.SX:
        """Angular velocity in the body frame."""
        return self.v[3:6]

    @property
    def rotation(self) -> ca.SX:
        return rotation_matrix(self.quaternion)

    @property
    def mass_matrix(self) -> ca.SX:
        """blockdiag(m I, J), 6 x 6."""
        return ca.diagcat(self.mass * ca.SX.eye(3), ca.SX(self.inertia))

    @property
    def gyroscopic(self) -> ca.SX:
        """(0, -omega x J omega): the body's force with no load."""
        w = self.omega
        return ca.vertcat(ca.SX.zeros(3, 1), -ca.cross(w, ca.mtimes(ca.SX(self.inertia), w)))

    @property
    def kinematics(self) -> ca.SX:
        """T(q) = blockdiag(I, Xi(p)/2), 7 x 6."""
        return ca.diagcat(ca.SX.eye(3), 0.5 * quaternion_matrix(self.quaternion))

    def point(self, r_body) -> ca.SX:
        """World position x + R(p) r of the material point r (body frame, 3 numbers)."""
        r = ca.SX(np.asarray(r_body, dtype=float).reshape(3, 1))
        return self.position + ca.mtimes(self.rotation, r)

    def point_velocity(self, r_body) -> ca.SX:
        """World velocity of the material point r: v + R (omega x r)."""
        r = ca.SX(np.asarray(r_body, dtype=float).reshape(3, 1))
        return self.v[0:3] + ca.mtimes(self.rotation, ca.cross(self.omega, r))

    def weight(self, g: float) -> ca.SX:
        """The generalized force of gravity g along -z: (0, 0, -m g, 0, 0, 0)."""
        return ca.vertcat(0, 0, -self.mass * g, 0, 0, 0)

    def angular_momentum(self, q, v) -> np.ndarray:
        """World-frame angular momentum about the origin: x m v + R(p) J omega (numbers)."""
        q, v = np.asarray(q, dtype=float), np.asarray(v, dtype=float)
        R = np.array(ca.evalf(ca.substitute(self.rotation, self.quaternion, ca.DM(q[3:7]))), dtype=float)
        return self.mass * np.cross(q[:3], v[:3]) + R @ (self.inertia @ v[3:6])

    def names(self) -> tuple:
        b = self.name
        return tuple(f"{b}.{c}" for c in ("x", "y", "z", "p0", "p1", "p2", "p3"))

    def velocity_names(self) -> tuple:
        b = self.name
        return tuple(f"{b}.{c}" for c in ("vx", "vy", "vz", "wx", "wy", "wz"))


def free_body(mass: float, inertia, name: str = "body") -> RigidBody:
    """A free rigid body of ``mass`` and ``inertia`` (3 x 3 tensor about the centre, body frame, or
    its three principal moments), with fresh symbols (module docstring).

    Raises
    ------
    ValueError
        A mass that is not finite and > 0, an inertia that is not a symmetric positive-definite
        3 x 3 tensor obeying the triangle inequality.
    """
    if isinstance(mass, (bool, str)) or not np.isscalar(mass) or not np.isfinite(mass) or mass <= 0:
        raise ValueError(f"mass of {name} must be finite and > 0, got {mass!r}")
    J = _inertia(inertia)
    return RigidBody(str(name), float(mass), J, ca.SX.sym(f"{name}_q", 7), ca.SX.sym(f"{name}_v", 6))


def bodies_system(bodies, contacts=(), gravity: float = 0.0, force=None, **system_options) -> System:
    """The :class:`~lcp.model.system.System` of free ``bodies`` (stacked in order) and ``contacts``.

    Parameters
    ----------
    bodies : sequence of RigidBody
    contacts : sequence of Contact
        Gaps and tangents written with the bodies' symbols (``body.point(r)``): their Jacobians are
        taken in v-space by the System (H = dg/dq T).
    gravity : float
        g along -z (0: none).
    force : casadi.SX, optional
        An extra generalized force (6 per body, v-space: world force, body-frame torque).
    **system_options
        Passed to :class:`~lcp.model.system.System` (``t``, ``breakpoints``, ...).
    """
    bodies = list(bodies)
    if not bodies or not all(isinstance(b, RigidBody) for b in bodies):
        raise ValueError("bodies must be a non-empty sequence of RigidBody (lcp.model.rigid_body.free_body)")
    if len({b.name for b in bodies}) != len(bodies):
        raise ValueError("bodies must have distinct names")
    F = ca.vertcat(*(b.gyroscopic + (b.weight(gravity) if gravity else 0) for b in bodies))
    if force is not None:
        F = F + force
    return System(ca.vertcat(*(b.q for b in bodies)), ca.vertcat(*(b.v for b in bodies)),
                  mass=ca.diagcat(*(b.mass_matrix for b in bodies)), force=F, contacts=contacts,
                  kinematics=ca.diagcat(*(b.kinematics for b in bodies)),
                  unit_quaternions=tuple(7 * i + 3 for i in range(len(bodies))),
                  names=sum((b.names() for b in bodies), ()),
                  velocity_names=sum((b.velocity_names() for b in bodies), ()), **system_options)
