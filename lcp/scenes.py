"""Ready-made scenes: a system, its initial state, a default horizon and (where known) the exact solution.

- :func:`jean_pratt`: the paper's system (docs/models.md), reduced (x, y) or in full
  coordinates (x, y, Y) with the slide as a bilateral constraint.
- :func:`block_chain`: K blocks on a frictional floor joined by springs (K contacts).
- spatial contacts (a block sliding in a plane, the Coulomb disk): :func:`plane_slide`,
  :func:`incline_slide`, :func:`lateral_force_slide`, :func:`jean_pratt_spatial`
  (:mod:`lcp.spatial_scenes`).
"""
from __future__ import annotations

import functools
import math
from typing import Callable

import casadi as ca
import numpy as np

from lem.jean_pratt import check_parameters, tan_alpha

from .constant_model import ConstantModel
from .exact import JeanPrattExact
from .system import Contact, System

__all__ = ["Scene", "jean_pratt", "block_chain"]


class Scene:
    """A system with its initial state.

    Attributes
    ----------
    system : System
        The CasADi model. A scene may build it on first access (``build_system``): the paths that
        run from the scene's :class:`~lcp.constant_model.ConstantModel` never need it.
    q0, v0 : ndarray, shape (n,)
    t_end : float
        Default horizon.
    name : str
    params : dict
        The parameters the scene was built from.
    solution : JeanPrattExact or None
        Exact solution, if known (:meth:`exact` evaluates it).
    model : ConstantModel or None
        The numbers of a constant system, where the builder knows them in closed form.
    """

    def __init__(self, system: System | None, q0, v0, t_end: float, name: str, params: dict | None = None,
                 solution: JeanPrattExact | None = None, no_exact_reason: str = "", model=None,
                 build_system: Callable[[], System] | None = None):
        if system is None and build_system is None:
            raise ValueError("a Scene needs a system or a build_system callable")
        self._system, self._build_system = system, build_system
        self.q0, self.v0, self.t_end, self.name = q0, v0, t_end, name
        self.params = {} if params is None else params
        self.solution, self.no_exact_reason, self.model = solution, no_exact_reason, model

    @property
    def system(self) -> System:
        if self._system is None:
            self._system = self._build_system()
        return self._system

    @system.setter
    def system(self, value: System):
        self._system = value

    @property
    def system_built(self) -> bool:
        """Whether the CasADi System exists already (it is built on first access otherwise)."""
        return self._system is not None

    def __repr__(self):
        return f"Scene(name={self.name!r}, params={self.params!r}, t_end={self.t_end!r})"

    def exact(self, t) -> dict:
        """Exact x, xdot, N, f (and y = 0) at times t; see :class:`lcp.exact.JeanPrattExact`."""
        if self.solution is None:
            raise ValueError(f"scene '{self.name}' has no exact solution"
                             + (f": {self.no_exact_reason}" if self.no_exact_reason else ""))
        return self.solution(t)

    def __getattr__(self, name):
        # kappa, N0, B, tau0, x_stop, shocks ... of the exact solution, as scene attributes
        sol = self.__dict__.get("solution")
        if name in ("kappa", "N0", "B", "tau0", "x_stop", "shocks", "A", "tan", "consistent", "impulse",
                    "switch_times"):
            if sol is not None:
                return getattr(sol, name)
            raise AttributeError(f"{name}: scene '{self.__dict__.get('name')}' has no exact solution "
                                 f"({self.__dict__.get('no_exact_reason', '')})")
        raise AttributeError(name)


def _check_params(**kw):
    for k, val in kw.items():
        if type(val) is float and math.isfinite(val):
            continue  # the common case, without NumPy's scalar call
        if not isinstance(val, (int, float, np.floating, np.integer)) or not np.isfinite(val):
            raise ValueError(f"{k} must be a finite number, got {val!r}")


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


def block_chain(K: int = 3, m=1.0, k_spring: float = 50.0, mu=0.3, g: float = 9.81, v0=None,
                spacing: float = 1.0, damping: float = 0.0, t_end: float = 1.0) -> Scene:
    """K blocks on a frictional floor joined by linear springs: a scene with K contacts.

    Block i has coordinates (x_i, y_i), gap y_i and tangent x_i; springs of stiffness ``k_spring``
    (and optional dashpots ``damping``) join neighbours at rest length ``spacing``.

    Parameters
    ----------
    K : int
        Number of blocks, >= 1.
    m, mu : float or sequence of K floats
        Masses (> 0) and friction coefficients (>= 0), per block or shared.
    k_spring, damping : float
        Spring stiffness and dashpot coefficient (>= 0).
    v0 : sequence of K floats, optional
        Initial horizontal velocities; by default the first block is launched at 2 m/s and the
        others are at rest, so the chain sticks and slips.
    t_end : float
        Default horizon.

    Examples
    --------
    >>> from lcp.scenes import block_chain
    >>> sc = block_chain(4)
    >>> sc.system.n, sc.system.n_contacts
    (8, 4)
    """
    if not isinstance(K, (int, np.integer)) or K < 1:
        raise ValueError(f"K must be an integer >= 1, got {K!r}")
    masses = np.broadcast_to(np.asarray(m, dtype=float), (K,)).copy()
    mus = np.broadcast_to(np.asarray(mu, dtype=float), (K,)).copy()
    if np.any(~np.isfinite(masses)) or np.any(masses <= 0):
        raise ValueError(f"m must be finite and > 0, got {m!r}")
    if np.any(~np.isfinite(mus)) or np.any(mus < 0):
        raise ValueError(f"mu must be finite and >= 0, got {mu!r}")
    _check_params(k_spring=k_spring, g=g, spacing=spacing, damping=damping, t_end=t_end)
    if k_spring < 0 or damping < 0:
        raise ValueError("k_spring and damping must be >= 0")
    if t_end <= 0:
        raise ValueError(f"t_end must be > 0, got {t_end!r}")
    n = 2 * K
    q, v = ca.SX.sym("q", n), ca.SX.sym("v", n)
    x, y = q[0::2], q[1::2]
    vx = v[0::2]
    F = [ca.SX(0)] * n
    for i in range(K):
        F[2 * i + 1] = -masses[i] * g
    for i in range(K - 1):
        stretch = x[i + 1] - x[i] - spacing
        rate = vx[i + 1] - vx[i]
        tension = k_spring * stretch + damping * rate
        F[2 * i] = F[2 * i] + tension
        F[2 * i + 2] = F[2 * i + 2] - tension
    # structurally diagonal (not a dense array with zeros): the n^2 structural entries of a dense
    # mass matrix would dominate every evaluation, check and assembly of a long chain
    mass = ca.diag(ca.SX(np.repeat(masses, 2)))
    contacts = [Contact(gap=y[i], tangent=x[i], mu=float(mus[i]), name=f"block{i}") for i in range(K)]
    names = [nm for i in range(K) for nm in (f"x{i}", f"y{i}")]
    system = System(q, v, mass, ca.vertcat(*F), contacts=contacts, names=names)
    q0 = np.zeros(n)
    q0[0::2] = spacing * np.arange(K)
    if v0 is None:
        v0 = np.zeros(K)
        v0[0] = 2.0
    v0 = np.asarray(v0, dtype=float)
    if v0.shape != (K,) or not np.all(np.isfinite(v0)):
        raise ValueError(f"v0 must be {K} finite numbers, got {v0!r}")
    vv = np.zeros(n)
    vv[0::2] = v0
    params = dict(K=K, m=masses, k_spring=k_spring, mu=mus, g=g, spacing=spacing, damping=damping)
    return Scene(system, q0, vv, float(t_end), f"block_chain_{K}", params, None)


_SPATIAL = ("plane_slide", "incline_slide", "lateral_force_slide", "jean_pratt_spatial")


def __getattr__(name):
    # the scenes with spatial contacts live in lcp.spatial_scenes (loaded on first use)
    if name in _SPATIAL:
        from . import spatial_scenes

        return getattr(spatial_scenes, name)
    raise AttributeError(f"module 'lcp.scenes' has no attribute {name!r}")
