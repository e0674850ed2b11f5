"""The Jean-Pratt scene: the paper's system, reduced (x, y) or in full coordinates (x, y, Y).

Holds :func:`jean_pratt` (the System, its start and its exact solution,
:class:`~lcp.scenes.jean_pratt_exact.JeanPrattExact`). Imports the model and the constant-model
numbers of the time stepping; must not import the simulation, sweeps or optimal control.
"""
from __future__ import annotations

import functools
import math
from typing import Callable

import casadi as ca
import numpy as np

from lem.jean_pratt import check_parameters, tan_alpha

from lcp.timestepping.constant_model import ConstantModel
from lcp.scenes.jean_pratt_exact import JeanPrattExact
from lcp.model.system import Contact, System
from lcp.scenes.scene import Scene, check_params as _check_params

__all__ = ["jean_pratt"]


def jean_pratt(m: float = 1.0, M: float = 1.0, alpha: float = math.pi / 4, R: float = 0.5,
               v0: float = 1.0, g: float = 9.81, phi: float = 0.0, coordinates: str = "reduced",
               t_end: float | None = None, load: Callable | None = None) -> Scene:
    """The Jean-Pratt system: block m on a frictional line, coupled by a slide of slope tan(alpha)
    to a body M on a vertical guide.

    Parameters
    ----------
    m, M : float
        Masses of the block (> 0) and of the guided body (>= 0).
    alpha : float
        Slide angle, strictly inside (-pi/2, pi/2). alpha = +-pi/4 uses tan = +-1 exactly.
    R : float
        Coulomb friction coefficient at P, >= 0.
    v0 : float
        Initial sliding velocity xd(0).
    g : float
        Gravity, >= 0.
    phi : float
        Net horizontal load on m (0 in the paper, where -M g tan(alpha) cancels M's push).
    coordinates : {"reduced", "full"}
        ``"reduced"``: q = (x, y), the constant mass matrix of docs/models.md.
        ``"full"``: q = (x, y, Y) with the slide Y = y - x tan(alpha) as a bilateral constraint,
        which exercises the general model's constraint elimination.
    t_end : float, optional
        Default horizon; by default max(0.3, 2 tau0).
    load : callable, optional
        A time-dependent horizontal load on m added to phi: ``load(t)`` receives the CasADi time
        symbol and returns an expression (e.g. ``lambda t: 12 * casadi.sin(2 * pi * t)``). The
        scene then has no exact solution (``scene.exact`` raises).

    Returns
    -------
    Scene
        With ``scene.exact(t)`` and the attributes kappa, N0, B, tau0, x_stop, shocks. Where the
        load lifts the block off the line (an open contact) the scene still simulates, but has no
        exact solution (``scene.exact`` raises ValueError saying why).

    Examples
    --------
    >>> from lcp.scenes import jean_pratt
    >>> sc = jean_pratt()
    >>> round(sc.kappa, 12), round(sc.tau0, 6), sc.q0, sc.v0
    (0.25, 0.152905, array([0., 0.]), array([1., 0.]))
    """
    _check_params(m=m, M=M, alpha=alpha, R=R, g=g, v0=v0, phi=phi)  # one scene: numbers, not arrays
    check_parameters(m, M, alpha, R, g)
    if coordinates not in ("reduced", "full"):
        raise ValueError(f"coordinates must be 'reduced' or 'full', got {coordinates!r}")
    t = tan_alpha(alpha)
    params = dict(m=m, M=M, alpha=alpha, R=R, v0=v0, g=g, phi=phi, coordinates=coordinates, load=load)
    if load is not None and not callable(load):
        raise ValueError("load must be a callable of the CasADi time symbol")
    if M == 0 and coordinates == "full":
        raise ValueError("M must be > 0 with coordinates='full' (the guided body's mass matrix is singular)")
    build = functools.partial(_jean_pratt_system, m, M, t, R, g, phi, coordinates, load)
    model = None
    if coordinates == "reduced":
        q0, v0v = np.zeros(2), np.array([v0, 0.0])
        if load is None:
            # the numbers of the model in closed form: the fast paths need no CasADi work
            # (valid by construction: m > 0 and M >= 0 make A positive definite, all checked above)
            model = ConstantModel.trusted(A=np.array([[m + M * t * t, -M * t], [-M * t, m + M]]),
                                          F0=np.array([phi, -(m + M) * g], dtype=float), H=_JP_H, gap0=_ZERO1,
                                          mu=np.array([float(R)]), e=_ZERO1, names=("x", "y"), contact_names=("P",))
    else:
        q0, v0v = np.zeros(3), np.array([v0, 0.0, -v0 * t])
    # a user's load expression is checked now, not at the first simulation
    system = build() if load is not None else None
    sol, why = None, "a time-dependent load"
    if load is None:
        try:
            sol = JeanPrattExact(m=m, M=M, alpha=alpha, R=R, v0=v0, g=g, phi=phi)
        except ValueError as exc:  # lift-off: the scene is fine to simulate, only exact() is missing
            why = str(exc)
    if t_end is None:
        # (a stop beyond the largest float, R ~ 1e-310, gives the 0.3 s default too)
        t_end = max(0.3, 2 * sol.tau0) if sol is not None and math.isfinite(2 * sol.tau0) else 0.3
    _check_params(t_end=t_end)
    if t_end <= 0:
        raise ValueError(f"t_end must be > 0, got {t_end!r}")
    return Scene(system, q0, v0v, float(t_end), "jean_pratt", params, sol, no_exact_reason=why, model=model,
                 build_system=build)


_JP_H = np.array([[0.0, 1.0], [1.0, 0.0]])  # rows: normal (gap y), tangent (x)
_ZERO1 = np.zeros(1)


def _jean_pratt_system(m, M, t, R, g, phi, coordinates, load) -> System:
    """The CasADi System of the Jean-Pratt scene (built when a path needs it)."""
    time_sym = ca.SX.sym("t")
    horizontal = phi
    if load is not None:
        try:
            horizontal = phi + ca.SX(load(time_sym))
        except Exception as exc:  # noqa: BLE001 - report any failure of the user's expression
            raise ValueError(f"load(t) must return a scalar CasADi expression: {exc}") from exc
        if horizontal.numel() != 1:
            raise ValueError("load(t) must return a scalar CasADi expression")
    if coordinates == "reduced":
        q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
        mass = ca.SX(np.array([[m + M * t * t, -M * t], [-M * t, m + M]]))
        force = ca.vertcat(horizontal, -(m + M) * g)
        return System(q, v, mass, force, contacts=[Contact(gap=q[1], tangent=q[0], mu=R, name="P")],
                      names=("x", "y"), t=time_sym)
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    mass = ca.SX(np.diag([m, m, M]))
    # the applied -M g tan(alpha) + phi on m cancels M's push through the slide when phi = 0
    force = ca.vertcat(-M * g * t + horizontal, -m * g, -M * g)
    slide = q[2] - q[1] + q[0] * t
    return System(q, v, mass, force, contacts=[Contact(gap=q[1], tangent=q[0], mu=R, name="P")],
                  constraints=slide, names=("x", "y", "Y"), t=time_sym)
