"""A slider-crank mechanism with a q-dependent mass matrix and nonlinear loop-closure constraints.

Holds :func:`slider_crank` (the scene, re-exported by :mod:`lcp.scenes.classical`) and
:class:`SliderCrankReference` (its motion from the reduced equation in the crank angle, integrated
by SciPy's DOP853). Imports the model (:mod:`lcp.model`) and :class:`~lcp.scenes.scene.Scene`;
never the simulation, the time stepping or the event method.
"""
from __future__ import annotations

import math

import casadi as ca
import numpy as np

from lcp.model.system import System
from lcp.scenes.scene import Scene

__all__ = ["SliderCrankReference", "slider_crank"]


def _mass(q, l1, l2, m1, m2, m3, J1, J2):
    """The mass matrix in q = (crank angle, rod angle, slider position): the crank turns about the
    origin, the rod's centre sits at l1 e(theta1) + l2/2 e(theta2), so its kinetic energy couples the
    two angles through m2 l1 l2/2 cos(theta1 - theta2)."""
    c12 = m2 * l1 * l2 / 2 * ca.cos(q[0] - q[1])
    return ca.blockcat([[J1 + m1 * l1 ** 2 / 4 + m2 * l1 ** 2, c12, 0],
                        [c12, J2 + m2 * l2 ** 2 / 4, 0],
                        [0, 0, m3]])


def _potential(q, l1, l2, m1, m2, g):
    """Gravity (along -y) on the crank's and the rod's centres."""
    return g * (m1 * l1 / 2 * ca.sin(q[0]) + m2 * (l1 * ca.sin(q[0]) + l2 / 2 * ca.sin(q[1])))


class SliderCrankReference:
    """The motion of :func:`slider_crank` from its reduced (one-coordinate) equation.

    With the crank angle theta as the only coordinate, theta_2 = -arcsin(l1 sin(theta) / l2),
    s = l1 cos(theta) + l2 cos(theta_2), the kinetic energy is 1/2 m(theta) theta'^2 with
    m = J' A(q(theta)) J, J = dq/dtheta, and Lagrange's equation reads

        m(theta) theta'' = -1/2 m'(theta) theta'^2 - V'(theta),

    integrated by ``solve_ivp`` (DOP853, rtol 1e-12, atol 1e-12, dense output) over [0, t_end].
    ``self(t)`` returns ``theta``, ``omega`` and the full ``q`` and ``v`` (len(t), 3).
    """

    def __init__(self, params: dict, t_end: float):
        from scipy.integrate import solve_ivp

        p = params
        th, w = ca.SX.sym("theta"), ca.SX.sym("omega")
        th2 = -ca.asin(p["l1"] * ca.sin(th) / p["l2"])
        qth = ca.vertcat(th, th2, p["l1"] * ca.cos(th) + p["l2"] * ca.cos(th2))
        J = ca.jacobian(qth, th)
        A = _mass(qth, p["l1"], p["l2"], p["m1"], p["m2"], p["m3"], p["J1"], p["J2"])
        mred = ca.mtimes([J.T, A, J])
        V = _potential(qth, p["l1"], p["l2"], p["m1"], p["m2"], p["g"]) - p["torque"] * th
        acc = (-0.5 * ca.gradient(mred, th) * w ** 2 - ca.gradient(V, th)) / mred
        rhs = ca.Function("slider_crank_reduced", [th, w], [acc])
        self.to_qv = ca.Function("slider_crank_full", [th, w], [qth, J * w])

        def f(_t, y):
            return [y[1], float(rhs(y[0], y[1]))]

        self.sol = solve_ivp(f, (0.0, t_end), [p["theta0"], p["omega0"]], method="DOP853", rtol=1e-12,
                             atol=1e-12, dense_output=True)
        if not self.sol.success:
            raise RuntimeError(f"the slider-crank reference failed: {self.sol.message}")
        self.t_end = t_end

    def __call__(self, t) -> dict:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if np.any(t < 0) or np.any(t > self.t_end * (1 + 1e-12)):
            raise ValueError(f"t must lie in [0, {self.t_end}] (the reference's horizon)")
        y = self.sol.sol(t)
        qv = self.to_qv.map(t.size)(y[0][None, :], y[1][None, :])
        return {"theta": y[0], "omega": y[1], "q": np.array(qv[0]).T, "v": np.array(qv[1]).T}


def slider_crank(l1: float = 0.05, l2: float = 0.12, m1: float = 0.30, m2: float = 0.21, m3: float = 0.14,
                 J1: float = 1e-5, J2: float = 2.5e-4, g: float = 9.81, theta0: float = 0.0,
                 omega0: float = 30.0, torque: float = 0.0, t_end: float = 1.0) -> Scene:
    """A slider-crank in the vertical plane: crank (length l1, mass m1, inertia J1 about its centre)
    turning about the origin, connecting rod (l2, m2, J2), slider (m3) on the horizontal axis
    through the crank's pivot; the dimensions and masses of Flores et al. (2008) by default.

    Coordinates q = (theta1, theta2, s): the crank's and the rod's angles to the axis and the
    slider's position. The mass matrix depends on q (the rod's kinetic energy couples the angles),
    the forces are gravity, an optional constant torque on the crank and the Coriolis and
    centrifugal terms of the q-dependent mass matrix, and two nonlinear bilateral constraints close
    the loop: l1 cos theta1 + l2 cos theta2 - s = 0, l1 sin theta1 + l2 sin theta2 = 0 (no dead
    point for l2 > l1). Started at crank angle ``theta0`` with angular velocity ``omega0`` (the
    other velocities consistent). Reference: :class:`SliderCrankReference`.

    Examples
    --------
    >>> from lcp.scenes.classical import slider_crank
    >>> sc = slider_crank(t_end=0.1)
    >>> sc.system.n, sc.system.n_bilateral, sc.system.mass_is_constant
    (3, 2, False)
    >>> ref = sc.exact([0.0])
    >>> [round(float(x), 6) + 0.0 for x in ref["q"][0]], round(float(ref["omega"][0]), 6)
    ([0.0, 0.0, 0.17], 30.0)
    """
    for k, val in dict(l1=l1, l2=l2, m1=m1, m2=m2, m3=m3, J1=J1, J2=J2, t_end=t_end).items():
        if not isinstance(val, (int, float, np.floating, np.integer)) or not math.isfinite(val) or val <= 0:
            raise ValueError(f"{k} must be finite and > 0, got {val!r}")
    for k, val in dict(g=g, theta0=theta0, omega0=omega0, torque=torque).items():
        if not isinstance(val, (int, float, np.floating, np.integer)) or not math.isfinite(val):
            raise ValueError(f"{k} must be a finite number, got {val!r}")
    if l2 <= l1:
        raise ValueError(f"l2 must exceed l1 (a crank that turns round), got l1 = {l1!r}, l2 = {l2!r}")
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    A = _mass(q, l1, l2, m1, m2, m3, J1, J2)
    # Lagrange: A v' = -(dA/dt v - d/dq (1/2 v' A v)) - dV/dq + Q
    Av = ca.mtimes(A, v)
    coriolis = ca.mtimes(ca.jacobian(Av, q), v) - ca.gradient(0.5 * ca.dot(v, Av), q)
    F = -coriolis - ca.gradient(_potential(q, l1, l2, m1, m2, g), q) + ca.vertcat(torque, 0, 0)
    phi = ca.vertcat(l1 * ca.cos(q[0]) + l2 * ca.cos(q[1]) - q[2], l1 * ca.sin(q[0]) + l2 * ca.sin(q[1]))
    system = System(q, v, A, F, constraints=phi, names=("theta1", "theta2", "s"))
    params = dict(l1=l1, l2=l2, m1=m1, m2=m2, m3=m3, J1=J1, J2=J2, g=g, theta0=theta0, omega0=omega0,
                  torque=torque)
    ref = SliderCrankReference(params, float(t_end))
    start = ref(0.0)
    return Scene(system, start["q"][0], start["v"][0], float(t_end), "slider_crank", params, ref)
