"""Flores, Leine and Glocker's slider-crank with a translational clearance joint.

Holds :func:`slider_crank_clearance` (the scene, re-exported by :mod:`lcp.scenes.classical`),
:data:`FLORES` (the published data) and :func:`slider_crank_clearance_energy`. Imports the model
(:mod:`lcp.model`), :class:`~lcp.scenes.scene.Scene` and the ideal slider-crank's reference
(:mod:`lcp.scenes.slider_crank`); never the simulation, the time stepping or the event method.

The model is the one of Flores, Leine and Glocker (Multibody Syst. Dyn. 23, 2010, Table 1) as
written in Siconos's tutorial (examples/Mechanics/SliderCrank, SCConst.h and its plugin): three
coordinates q = (theta1, theta2, theta3), the crank's and the rod's angles and the slider's tilt.
The slider (a 2a x 2b block, mass m3, inertia J3) is pinned at the rod's tip
P = l1 e(theta1) + l2 e(theta2) and moves in a guide of width d = 2 (b + c): its four corners are
the four contacts, with gaps

    g_{1,2} = d/2 - (P_y -+ a sin theta3 + b cos theta3)   (upper corners, left/right),
    g_{3,4} = d/2 + (P_y -+ a sin theta3 - b cos theta3)   (lower corners),

and the corners' horizontal positions as tangents (Coulomb mu, Newton e). The mass matrix depends
on q (the slider's mass moves with P), the forces are gravity and the Coriolis and centrifugal terms
of that matrix (from Lagrange's equations, as the ideal crank of :mod:`lcp.scenes.slider_crank`).

Reference: with zero clearance (c = 0) and no friction the four contacts hold P_y = 0 and
theta3 = 0 and the mechanism is the ideal one-degree-of-freedom slider-crank, whose motion
:class:`~lcp.scenes.slider_crank.SliderCrankReference` integrates (``scene.exact``); with clearance
there is no closed form (Moreau-Jean's limit h -> 0 and the energy's bookkeeping are the checks).
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from lcp.model.system import Contact, System
from lcp.scenes.scene import Scene, check_params
from lcp.scenes.slider_crank import SliderCrankReference

__all__ = ["FLORES", "slider_crank_clearance", "slider_crank_clearance_energy"]

#: Table 1 of Flores, Leine and Glocker (2010), SI units, and the start of Siconos's tutorial
FLORES = dict(l1=0.1530, l2=0.3060, a=0.05, b=0.025, c=0.001, m1=0.038, m2=0.038, m3=0.0760,
              J1=7.4e-5, J2=5.9e-4, J3=2.7e-6, g=9.81, e=0.4, mu=0.01,
              omega1=150.0, omega3=-0.01)


def _mass(q, p):
    k = (0.5 * p["m2"] + p["m3"]) * p["l1"] * p["l2"] * ca.cos(q[1] - q[0])
    return ca.blockcat([[p["J1"] + (0.25 * p["m1"] + p["m2"] + p["m3"]) * p["l1"] ** 2, k, 0],
                        [k, p["J2"] + (0.25 * p["m2"] + p["m3"]) * p["l2"] ** 2, 0],
                        [0, 0, p["J3"]]])


def _potential(q, p):
    return p["g"] * ((0.5 * p["m1"] + p["m2"] + p["m3"]) * p["l1"] * ca.sin(q[0])
                     + (0.5 * p["m2"] + p["m3"]) * p["l2"] * ca.sin(q[1]))


def slider_crank_clearance_energy(params: dict, q, v) -> np.ndarray:
    """Total energy 1/2 v'A(q)v + V(q) along rows of q and v."""
    qs, vs = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    E = ca.Function("E", [qs, vs], [0.5 * ca.dot(vs, ca.mtimes(_mass(qs, params), vs)) + _potential(qs, params)])
    q, v = np.atleast_2d(q), np.atleast_2d(v)
    return np.array(E.map(q.shape[0])(q.T, v.T)).ravel()


def slider_crank_clearance(t_end: float = 0.2, c: float | None = None, e: float | None = None,
                           mu: float | None = None, omega1: float | None = None, omega3: float | None = None,
                           **overrides) -> Scene:
    """The slider-crank with a clearance joint (:data:`FLORES`: Flores et al. 2010, Siconos's tutorial).

    Parameters
    ----------
    t_end : float
        Default horizon (0.2 s as in the tutorial: about five crank revolutions at 150 rad/s).
    c : float, optional
        The clearance (guide half-width minus the slider's half-height), >= 0; 1 mm by default.
        With c = 0 the scene carries the ideal (frictionless) slider-crank's motion as ``exact``
        (pass ``omega3=0`` and ``mu=0``: the start does not tilt, and the guide's friction, which
        the ideal crank has not, acts on the corners' normal forces).
    e, mu : float, optional
        Restitution and friction of the four corners (0.4 and 0.01 by default).
    omega1, omega3 : float, optional
        The crank's angular velocity at theta = 0 (150 rad/s) and the slider's tilt rate (-0.01);
        the rod's rate follows from P_y' = 0 (theta2' = -l1 omega1 / l2).
    **overrides
        Any other entry of :data:`FLORES`.

    Examples
    --------
    >>> from lcp.scenes.slider_crank_clearance import slider_crank_clearance
    >>> sc = slider_crank_clearance()
    >>> sc.system.n, sc.system.n_contacts, sc.system.mass_is_constant
    (3, 4, False)
    >>> [round(float(g), 6) for g in sc.system.gaps(sc.q0)]
    [0.001, 0.001, 0.001, 0.001]
    """
    p = dict(FLORES)
    for k, val in dict(c=c, e=e, mu=mu, omega1=omega1, omega3=omega3).items():
        if val is not None:
            overrides[k] = val
    unknown = set(overrides) - set(p)
    if unknown:
        raise ValueError(f"unknown slider-crank parameter(s) {sorted(unknown)}; known: {sorted(p)}")
    p.update(overrides)
    check_params(t_end=t_end, **p)
    for k in ("l1", "l2", "a", "b", "m1", "m2", "m3", "J1", "J2", "J3"):
        if p[k] <= 0:
            raise ValueError(f"{k} must be > 0, got {p[k]!r}")
    if t_end <= 0:
        raise ValueError(f"t_end must be > 0, got {t_end!r}")
    if p["l2"] <= p["l1"]:
        raise ValueError(f"l2 must exceed l1 (a crank that turns round), got l1 = {p['l1']!r}, l2 = {p['l2']!r}")
    if p["c"] < 0 or p["mu"] < 0 or not 0 <= p["e"] <= 1:
        raise ValueError(f"need c >= 0, mu >= 0 and e in [0, 1], got c = {p['c']!r}, mu = {p['mu']!r}, e = {p['e']!r}")
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    A = _mass(q, p)
    Av = ca.mtimes(A, v)
    coriolis = ca.mtimes(ca.jacobian(Av, q), v) - ca.gradient(0.5 * ca.dot(v, Av), q)
    F = -coriolis - ca.gradient(_potential(q, p), q)
    l1, l2, a, b = p["l1"], p["l2"], p["a"], p["b"]
    half = b + p["c"]  # d / 2
    Px, Py = l1 * ca.cos(q[0]) + l2 * ca.cos(q[1]), l1 * ca.sin(q[0]) + l2 * ca.sin(q[1])
    s3, c3 = ca.sin(q[2]), ca.cos(q[2])
    corners = [  # (gap, horizontal position) of the four corners, Siconos's g1..g4
        (half - (Py - a * s3 + b * c3), Px - a * c3 - b * s3),
        (half - (Py + a * s3 + b * c3), Px + a * c3 - b * s3),
        (half + (Py - a * s3 - b * c3), Px - a * c3 + b * s3),
        (half + (Py + a * s3 - b * c3), Px + a * c3 + b * s3),
    ]
    contacts = [Contact(gap=g, tangent=x, mu=p["mu"], e=p["e"], name=f"corner {i + 1}")
                for i, (g, x) in enumerate(corners)]
    system = System(q, v, A, F, contacts=contacts, names=("theta1", "theta2", "theta3"))
    q0 = np.zeros(3)
    v0 = np.array([p["omega1"], -l1 * p["omega1"] / l2, p["omega3"]])
    solution, reason = None, "with clearance there is no closed form (Moreau-Jean's limit h -> 0 is the reference)"
    if p["c"] == 0.0 and p["omega3"] == 0.0 and p["mu"] == 0.0:
        # the ideal crank's slider carries m3 on the axis; its Siconos-form mass matrix is the same
        # on the manifold P_y = 0, theta3 = 0 (the slider's rotation and vertical motion are held)
        ideal = dict(l1=l1, l2=l2, m1=p["m1"], m2=p["m2"], m3=p["m3"], J1=p["J1"], J2=p["J2"], g=p["g"],
                     theta0=0.0, omega0=p["omega1"], torque=0.0)
        solution, reason = _IdealMotion(SliderCrankReference(ideal, float(t_end))), ""
    return Scene(system, q0, v0, float(t_end), "slider_crank_clearance", p, solution, no_exact_reason=reason)


class _IdealMotion:
    """The ideal slider-crank's motion in this scene's coordinates (theta1, theta2, theta3 = 0)."""

    def __init__(self, ref: SliderCrankReference):
        self.ref = ref

    def __call__(self, t) -> dict:
        out = self.ref(t)
        q, v = out["q"].copy(), out["v"].copy()
        q[:, 2], v[:, 2] = 0.0, 0.0
        return {"theta": out["theta"], "omega": out["omega"], "q": q, "v": v}
