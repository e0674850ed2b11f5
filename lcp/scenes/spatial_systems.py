"""Scenes with spatial contacts: a block sliding in a plane under the Coulomb disk law.

Each scene is a block (point mass) on a plane, with coordinates q = (x, z, y): x and z in the plane
(the contact's two tangent coordinates), y the gap normal to it. While it slides the friction force
is -mu N U/|U| with U = (xdot, zdot), so the direction of friction turns with the motion.

- :func:`plane_slide`: launched obliquely on a horizontal plane: a straight path, stop and stick.
- :func:`incline_slide`: launched across an incline with mu = tan(theta) (by default): a curved path
  whose speed obeys v (1 + cos phi) = const, tending to v0 / 2 for a horizontal launch.
- :func:`lateral_force_slide`: pushed by a constant in-plane force smaller than mu m g: a curved path
  that turns toward the force and ends in stick at a finite time.
- :func:`jean_pratt_spatial`: the Jean-Pratt block free to move in the plane of its line, coupled
  to the guided body through the normal force (the Painleve mechanism); launched along x it is the
  planar scene.

Their exact solutions are in :mod:`lcp.scenes.spatial_exact` (``scene.exact(t)``).
"""
from __future__ import annotations

import math

import casadi as ca
import numpy as np

from lem.jean_pratt import check_parameters, tan_alpha

from lcp.scenes.scene import Scene
from lcp.model.system import Contact, System

__all__ = ["plane_slide", "incline_slide", "lateral_force_slide", "jean_pratt_spatial"]

_NAMES = ("x", "z", "y")


def _finite(**kw):
    for k, val in kw.items():
        if not isinstance(val, (int, float, np.floating, np.integer)) or not math.isfinite(val):
            raise ValueError(f"{k} must be a finite number, got {val!r}")


def _vec2(name, val) -> np.ndarray:
    try:
        a = np.asarray(val, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be two finite numbers, got {val!r}") from None
    if a.shape != (2,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be two finite numbers, got {val!r}")
    return a


def _block(m: float, mu: float, force, name: str = "floor") -> System:
    """A point mass m on the plane y = 0, in-plane coordinates (x, z), one spatial contact."""
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    return System(q, v, mass=m * ca.SX.eye(3), force=ca.vertcat(*force),
                  contacts=[Contact(gap=q[2], tangent=ca.vertcat(q[0], q[1]), mu=mu, name=name)],
                  names=_NAMES)


def _exact(cls_name: str, **kw):
    """The exact solution object of :mod:`lcp.scenes.spatial_exact` (None with the reason if it does not apply)."""
    from lcp.scenes import spatial_exact

    try:
        return _SpatialSolution(getattr(spatial_exact, cls_name)(**kw)), ""
    except ValueError as exc:
        return None, str(exc)


class _SpatialSolution:
    """Adapter: ``scene.exact(t)`` gives the exact state in the scene's coordinates, a dict of arrays:
    ``x, z`` (in the plane), ``xdot, zdot``, ``y = 0`` (gap), ``speed``, ``phi``, ``path``, ``t``."""

    def __init__(self, sol):
        self.sol = sol

    def __call__(self, t):
        st = self.sol.state(t)
        return dict(t=st["t"], x=st["x"], z=st["y"], xdot=st["vx"], zdot=st["vy"], y=np.zeros_like(st["x"]),
                    speed=st["speed"], phi=st["phi"], path=st["path"])

    def __getattr__(self, name):
        return getattr(self.sol, name)


def _check_mu_g_m(m, mu, g):
    _finite(m=m, mu=mu, g=g)
    if m <= 0:
        raise ValueError(f"m must be > 0, got {m!r}")
    if mu < 0:
        raise ValueError(f"mu must be >= 0, got {mu!r}")
    if g < 0:
        raise ValueError(f"g must be >= 0, got {g!r}")


def plane_slide(m: float = 1.0, mu: float = 0.3, g: float = 9.81, v0: float = 1.0, beta: float = 0.6,
                t_end: float | None = None) -> Scene:
    """A block launched obliquely on a horizontal plane: slides straight, stops, sticks.

    Parameters
    ----------
    m, mu, g : float
        Mass (> 0), friction coefficient (>= 0), gravity (>= 0).
    v0 : float
        Launch speed (>= 0).
    beta : float
        Launch direction in the plane, measured from the x axis (radians).
    t_end : float, optional
        Default horizon; 1.5 times the stop time v0 / (mu g) by default (1 s if it never stops).

    Examples
    --------
    >>> from lcp.scenes.spatial_systems import plane_slide
    >>> sc = plane_slide(v0=2.0, mu=0.5, g=10.0)
    >>> sc.system.tangent_dims.tolist(), sc.v0.tolist()[2], round(sc.solution.t_stop, 12)
    ([2], 0.0, 0.4)
    """
    _check_mu_g_m(m, mu, g)
    _finite(v0=v0, beta=beta)
    if v0 < 0:
        raise ValueError(f"v0 must be >= 0, got {v0!r}")
    sol, why = _exact("PlaneSlideExact", m=m, mu=mu, g=g, v0=v0, beta=beta)
    if t_end is None:
        ts = getattr(sol, "t_stop", math.inf) if sol is not None else math.inf
        t_end = 1.5 * ts if math.isfinite(ts) and ts > 0 else 1.0
    _finite(t_end=t_end)
    params = dict(m=m, mu=mu, g=g, v0=v0, beta=beta)
    v = np.array([v0 * math.cos(beta), v0 * math.sin(beta), 0.0])
    return Scene(_block(m, mu, (0.0, 0.0, -m * g)), np.zeros(3), v, float(t_end), "plane_slide", params, sol,
                 no_exact_reason=why)


def incline_slide(theta: float = 0.3, v0: float = 1.0, g: float = 9.81, m: float = 1.0, mu: float | None = None,
                  phi0: float = math.pi / 2, t_end: float = 2.0) -> Scene:
    """A block launched across an incline of angle theta (mu = tan(theta) by default).

    Coordinates in the incline's frame: x down the line of steepest descent, z horizontal across it,
    y the gap normal to the incline. Gravity gives the in-plane force m g sin(theta) along x and the
    normal load m g cos(theta). With mu = tan(theta) friction balances the slope exactly: the speed
    obeys v (1 + cos phi) = v0 (1 + cos phi0), phi the angle of the velocity from the x axis, so a
    horizontal launch (phi0 = pi/2) tends to the speed v0 / 2 along x.

    Parameters
    ----------
    theta : float
        Incline angle in (0, pi/2).
    v0 : float
        Launch speed (> 0).
    g, m : float
        Gravity (> 0) and mass (> 0).
    mu : float, optional
        Friction coefficient; tan(theta) by default.
    phi0 : float
        Launch direction from the line of steepest descent, in (0, pi]; pi/2 is horizontal.
    t_end : float
        Default horizon.

    Examples
    --------
    >>> from lcp.scenes.spatial_systems import incline_slide
    >>> sc = incline_slide(theta=0.3, v0=1.0)
    >>> sc.v0.tolist(), round(float(sc.system.mu[0]) - __import__("math").tan(0.3), 15)
    ([0.0, 1.0, 0.0], 0.0)
    """
    _finite(theta=theta, v0=v0, phi0=phi0)
    if not 0 < theta < math.pi / 2:
        raise ValueError(f"theta must lie in (0, pi/2), got {theta!r}")
    mu = math.tan(theta) if mu is None else mu
    _check_mu_g_m(m, mu, g)
    if v0 <= 0:
        raise ValueError(f"v0 must be > 0, got {v0!r}")
    if not 0 < phi0 <= math.pi:
        raise ValueError(f"phi0 must lie in (0, pi], got {phi0!r}")
    _finite(t_end=t_end)
    sol, why = _exact("InclineSlideExact", theta=theta, v0=v0, g=g, mu=mu, launch_angle=phi0)
    params = dict(theta=theta, v0=v0, g=g, m=m, mu=mu, phi0=phi0)
    force = (m * g * math.sin(theta), 0.0, -m * g * math.cos(theta))
    # phi0 = pi/2 exactly: no rounding residue along x (cos(pi/2) = 6e-17 would be a launch slope)
    c = 0.0 if phi0 == math.pi / 2 else math.cos(phi0)
    v = np.array([v0 * c, v0 * math.sin(phi0), 0.0])
    return Scene(_block(m, mu, force, name="incline"), np.zeros(3), v, float(t_end), "incline_slide", params, sol,
                 no_exact_reason=why)


def lateral_force_slide(m: float = 1.0, mu: float = 0.5, g: float = 9.81, F=(2.0, 0.0), v0=(0.0, 1.5),
                        t_end: float | None = None) -> Scene:
    """A block on a horizontal plane pushed by a constant in-plane force F, launched with velocity v0.

    With |F| < mu m g the velocity turns toward F and the block stops at a finite time, then
    sticks (the force is within the friction disk).

    Parameters
    ----------
    m, mu, g : float
        Mass (> 0), friction coefficient (>= 0), gravity (>= 0).
    F : (float, float)
        Constant in-plane force (x, z components).
    v0 : (float, float)
        Initial in-plane velocity (x, z components).
    t_end : float, optional
        Default horizon; 1.5 times the stop time by default (2 s if the exact solution does not apply).

    Examples
    --------
    >>> from lcp.scenes.spatial_systems import lateral_force_slide
    >>> sc = lateral_force_slide()
    >>> sc.system.force(sc.q0, sc.v0).tolist()
    [2.0, 0.0, -9.81]
    """
    _check_mu_g_m(m, mu, g)
    F, v = _vec2("F", F), _vec2("v0", v0)
    sol, why = _exact("LateralForceSlideExact", m=m, mu=mu, g=g, F=F, v0=v)
    if t_end is None:
        ts = getattr(sol, "t_stop", math.inf) if sol is not None else math.inf
        t_end = 1.5 * ts if math.isfinite(ts) and ts > 0 else 2.0
    _finite(t_end=t_end)
    params = dict(m=m, mu=mu, g=g, F=tuple(F.tolist()), v0=tuple(v.tolist()))
    return Scene(_block(m, mu, (float(F[0]), float(F[1]), -m * g)), np.zeros(3), np.array([v[0], v[1], 0.0]),
                 float(t_end), "lateral_force_slide", params, sol, no_exact_reason=why)


def jean_pratt_spatial(m: float = 1.0, M: float = 1.0, alpha: float = math.pi / 4, R: float = 0.5, v0=(1.0, 0.0),
                       g: float = 9.81, phi: float = 0.0, t_end: float | None = None) -> Scene:
    """The Jean-Pratt system with the block free to move in the plane of its line.

    q = (x, z, y): x along the slide's direction, z across it in the same horizontal plane, y the gap.
    The slide couples only x to the guided body (Y = y - x tan(alpha)), so the constant mass matrix
    is [[m + M t^2, 0, -M t], [0, m, 0], [-M t, 0, m + M]] (t = tan(alpha)), and the force is
    (phi, 0, -(m + M) g). The contact is spatial: friction -R N U/|U|, U = (xdot, zdot), and the
    normal force N = (m + M) g - M t xdd depends on the friction through xdd (the Painleve coupling).
    Launched along x (v0 = (v, 0)) it is the planar scene :func:`lcp.scenes.jean_pratt`.

    Parameters
    ----------
    m, M, alpha, R, g, phi : float
        As in :func:`lcp.scenes.jean_pratt`.
    v0 : (float, float)
        Initial in-plane velocity (xdot, zdot).
    t_end : float, optional
        Default horizon (0.3 s).

    Examples
    --------
    >>> from lcp.scenes.spatial_systems import jean_pratt_spatial
    >>> sc = jean_pratt_spatial()
    >>> sc.system.mass(sc.q0).tolist()
    [[2.0, 0.0, -1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 2.0]]
    """
    check_parameters(m, M, alpha, R, g)
    _finite(phi=phi)
    v = _vec2("v0", v0)
    t = tan_alpha(alpha)
    q, vs = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    mass = ca.SX(np.array([[m + M * t * t, 0.0, -M * t], [0.0, m, 0.0], [-M * t, 0.0, m + M]]))
    system = System(q, vs, mass, ca.vertcat(phi, 0.0, -(m + M) * g),
                    contacts=[Contact(gap=q[2], tangent=ca.vertcat(q[0], q[1]), mu=R, name="P")], names=_NAMES)
    sol, why = None, "no closed form for an oblique launch (the planar scene's exact solution applies when v0 = (v, 0))"
    if v[1] == 0.0:
        from lcp.scenes.jean_pratt_exact import JeanPrattExact

        try:
            sol = _PlanarAlongX(JeanPrattExact(m=m, M=M, alpha=alpha, R=R, v0=float(v[0]), g=g, phi=phi))
        except ValueError as exc:
            sol, why = None, str(exc)
    if t_end is None:
        t_end = 0.3
    _finite(t_end=t_end)
    params = dict(m=m, M=M, alpha=alpha, R=R, v0=tuple(v.tolist()), g=g, phi=phi)
    return Scene(system, np.zeros(3), np.array([v[0], v[1], 0.0]), float(t_end), "jean_pratt_spatial", params, sol,
                 no_exact_reason=why)


class _PlanarAlongX:
    """The planar Jean-Pratt exact solution seen in the spatial coordinates (z = 0 throughout)."""

    def __init__(self, sol):
        self.sol = sol

    def __call__(self, t):
        out = dict(self.sol(t))
        zero = np.zeros_like(np.asarray(out["x"], dtype=float))
        out.update(z=zero, zdot=zero)
        return out

    def __getattr__(self, name):
        return getattr(self.sol, name)
