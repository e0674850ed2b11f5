"""Optimal control through frictional contact: Moreau-Jean steps as constraints of an MPCC.

Direct transcription on N steps of size h = T/N (T fixed, or free for minimum-time problems). The
unknowns are, at the nodes k = 0..N, the state (q_k, v_k) and the control u_k (node values, linearly
interpolated in time: a first-order hold), and over each step k = 0..N-1 the contact impulses. The
constraints are exactly one step of :mod:`lcp.timestepping` (physics.md section 3):

    W_h (v_{k+1} - v_k) = r_k + H' p_k + G' lambda_k,     G v_{k+1} + phi_t = 0,
    q_{k+1} = q_k + h ((1 - theta) v_k + theta v_{k+1}),
    r_k = h ((1 - theta) F(t_k, q_k, v_k, u_k) + theta F(t_k + h, q_k, v_k, u_{k+1})) - h^2 theta K v_k,

where F(t, q, v, u) = F(t, q, v) + B(q) u is the system's force plus the control force,
W_h = A + h theta C + h^2 theta^2 K, K = -dF/dq and C = -dF/dv, all at (t_k, q_k, v_k, u_k), and
H = H(q_k). The theta-method sees the control at both ends of a step, so with theta = 1/2 it
integrates the first-order hold exactly; :func:`replay` feeds the same hold to :func:`lcp.simulate`
as a time-dependent force, which reproduces the optimizer's trajectory step for step at the same h.

The discrete Coulomb law of each contact is the LCP of
:meth:`lcp.contact_problem.ContactProblem.to_lcp`, with p_T = beta+ - beta-:

    0 <= p_N    perp  u_N + e min(u_N-, 0)    >= 0,
    0 <= beta+  perp  lambda + u_T            >= 0,
    0 <= beta-  perp  lambda - u_T            >= 0,
    0 <= lambda perp  mu p_N - beta+ - beta-  >= 0,      u = H(q_k) v_{k+1}, u_N- = H_N(q_k) v_k.

The right-hand sides are lifted into slack variables w >= 0, and each pair a perp w is relaxed as in
Scholtes (2001): a >= 0, w >= 0, a w <= sigma. The unknowns a are scaled as forces (p_N / h,
beta / h), so a w is a power (force times velocity) and a given sigma means the same for every N.
The relaxation parameter goes down geometrically; each NLP (one IPOPT instance, built once, sigma
a parameter) is warm-started from the previous solution, until the Coulomb residual, recomputed
independently from the optimizer's states with :meth:`~lcp.contact_problem.ContactProblem.residual`,
is below the requested tolerance. A final polishing solve fixes, pair by pair, the smaller member at
zero (the active set the homotopy has identified), which makes the complementarity exact (as
nosnoc's polishing of the homotopy solution); it is kept only if IPOPT converges and the residual does not grow.

Limitation: every contact is treated as active at every step (the velocity-level law). Moreau-Jean
also skips a contact whose predicted gap is positive; :attr:`OCPResult.inactive_conflicts` counts
the steps where that would change the step (a positive predicted gap with a nonzero normal
impulse), i.e. where a replay can depart from the optimizer's trajectory.

References
----------
S. Scholtes, Convergence properties of a regularization scheme for mathematical programs with
complementarity constraints, SIAM J. Optim. 11 (2001) 918-936.
M. Jean, The non-smooth contact dynamics method, CMAME 177 (1999) 235-257.
A. Nurkanovic et al., NOSNOC: a software package for non-smooth optimal control (2022).
"""
from __future__ import annotations

from dataclasses import dataclass, field
import time
from typing import Callable

import casadi as ca
import numpy as np

from .contact_problem import MODE_NAMES, ContactProblem
from .result import StepImpulses
from .system import System

__all__ = ["HomotopyOptions", "Step", "HomotopyStage", "OCPGuess", "OCPResult", "ReplayResult",
           "OptimalControlProblem", "OCP_STATUS_MESSAGES", "tangential_push", "controlled_system",
           "replay", "effort"]

#: status code -> meaning; success is ``status >= 0``.
OCP_STATUS_MESSAGES = {
    0: "Solved: the complementarity residual is within tolerance.",
    1: "Solved by the relaxation homotopy; the polishing solve was rejected and the homotopy iterate kept.",
    -1: "IPOPT failed during the relaxation homotopy.",
    -2: "The homotopy ended with a complementarity residual above tolerance.",
}


def _positive(name, value, allow_zero=False):
    if not isinstance(value, (int, float, np.floating, np.integer)) or not np.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    if value < 0 or (value == 0 and not allow_zero):
        raise ValueError(f"{name} must be {'>= 0' if allow_zero else '> 0'}, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class HomotopyOptions:
    """Options of the Scholtes relaxation homotopy and of IPOPT.

    Parameters
    ----------
    sigma0 : float
        First relaxation parameter (> 0): complementarity pairs satisfy a w <= sigma (a force times
        a velocity, in W).
    factor : float
        sigma is multiplied by this factor (in (0, 1)) after each stage.
    sigma_min : float
        Smallest sigma tried (> 0, <= sigma0).
    tol : float
        Target Coulomb residual (impulse units, :meth:`ContactProblem.residual`, maximum over the
        steps). The homotopy stops as soon as the residual is below it.
    polish : bool
        Finish with one solve whose complementarity is exact (the smaller member of each pair fixed
        at zero); kept only if IPOPT converges and the residual does not grow.
    max_iter : int
        IPOPT iteration limit per stage.
    ipopt_tol : float
        IPOPT's convergence tolerance (``tol`` and ``constr_viol_tol``).
    ipopt_options : dict, optional
        More IPOPT options (without the ``ipopt.`` prefix); they override the defaults.
    """

    sigma0: float = 1.0
    factor: float = 0.1
    sigma_min: float = 1e-12
    tol: float = 1e-8
    polish: bool = True
    max_iter: int = 500
    ipopt_tol: float = 1e-10
    ipopt_options: dict | None = None

    def __post_init__(self):
        _positive("sigma0", self.sigma0)
        _positive("sigma_min", self.sigma_min)
        _positive("tol", self.tol)
        _positive("ipopt_tol", self.ipopt_tol)
        if not 0 < float(self.factor) < 1:
            raise ValueError(f"factor must lie in (0, 1), got {self.factor!r}")
        if self.sigma_min > self.sigma0:
            raise ValueError(f"sigma_min must be <= sigma0, got {self.sigma_min!r} > {self.sigma0!r}")
        if not isinstance(self.max_iter, (int, np.integer)) or self.max_iter < 1:
            raise ValueError(f"max_iter must be an integer >= 1, got {self.max_iter!r}")
        if self.ipopt_options is not None and not isinstance(self.ipopt_options, dict):
            raise ValueError("ipopt_options must be a dict")

    @property
    def n_stages(self) -> int:
        """Most relaxation stages: sigma0, sigma0 factor, ..., down to sigma_min."""
        return 1 + int(np.ceil(np.log(self.sigma_min / self.sigma0) / np.log(self.factor) - 1e-9))


@dataclass
class Step:
    """One transcription step, as given to the user's cost and constraint callables.

    Every attribute is a CasADi expression (numbers after the solve, in :meth:`OCPResult.steps`).

    Attributes
    ----------
    k : int
        Step index, 0..N-1.
    t0, t1, h : casadi.SX
        Start and end time, and step size.
    q0, q1, v0, v1 : casadi.SX, shape (n, 1)
        State at the start and at the end of the step.
    u0, u1 : casadi.SX, shape (nu, 1)
        Control at the start and at the end (linear in between).
    p_N, p_T : casadi.SX, shape (m, 1)
        Contact impulses over the step.
    N, f : casadi.SX, shape (m, 1)
        Mean normal and friction forces over the step, p_N / h and p_T / h.
    """

    k: int
    t0: object
    t1: object
    h: object
    q0: object
    q1: object
    v0: object
    v1: object
    u0: object
    u1: object
    p_N: object
    p_T: object

    @property
    def N(self):
        return self.p_N / self.h

    @property
    def f(self):
        return self.p_T / self.h


def effort(step: Step):
    """Mean of |u|^2 over a step for the linear control hold: (u0^2 + u0 u1 + u1^2) / 3 summed.

    Use as ``stage_cost=effort`` for the exact integral of |u|^2 dt.
    """
    u0, u1 = step.u0, step.u1
    return ca.sum1(u0 * u0 + u0 * u1 + u1 * u1) / 3


@dataclass
class HomotopyStage:
    """One solve of the homotopy.

    Attributes
    ----------
    sigma : float
        Relaxation parameter (``0.0`` marks the polishing solve).
    iterations : int
        IPOPT iterations.
    residual : float
        Coulomb residual of the iterate (impulse units, maximum over steps).
    max_product : float
        Largest complementarity product a w over all pairs.
    cost : float
    return_status : str
        IPOPT's return status.
    success : bool
    time : float
        Wall time of the solve (s).
    """

    sigma: float
    iterations: int
    residual: float
    max_product: float
    cost: float
    return_status: str
    success: bool
    time: float


@dataclass
class OCPGuess:
    """An initial guess on the problem's grid, usually from a simulation (:meth:`OptimalControlProblem.guess`).

    Attributes
    ----------
    T : float
    q, v : ndarray, shape (N + 1, n)
    u : ndarray, shape (N + 1, nu)
    p_N, p_T : ndarray, shape (N, m)
    source : str
    """

    T: float
    q: np.ndarray
    v: np.ndarray
    u: np.ndarray
    p_N: np.ndarray
    p_T: np.ndarray
    source: str = "user"


@dataclass
class OCPResult(StepImpulses):
    """The solution of an :class:`OptimalControlProblem`.

    Attributes
    ----------
    t : ndarray, shape (N + 1,)
        Nodes, t_k = k T / N.
    q, v : ndarray, shape (N + 1, n)
        States at the nodes.
    u : ndarray, shape (N + 1, nu)
        Controls at the nodes (linear in between).
    p_N, p_T : ndarray, shape (N, m)
        Contact impulses per step; :attr:`N` and :attr:`f` are the mean forces p / h.
    modes : ndarray of int8, shape (N, m)
        Contact mode per step (0 open, 1 stick, 2 slide+, 3 slide-, :data:`lcp.contact_problem.MODE_NAMES`).
    T, h : float
        Final time and step size.
    cost : float
        Objective value.
    peak : float
        The epigraph variable of ``max_cost`` (nan without one).
    complementarity_residual : float
        Coulomb residual, maximum over the steps, recomputed from the optimizer's states with
        :meth:`ContactProblem.residual` (impulse units).
    lcp_residual : float
        max |min(a, w)| over the complementarity pairs of the NLP.
    dynamics_residual : float
        max |v_{k+1} - (v_free + S H' p_k)| over the steps (velocity units), recomputed in NumPy.
    inactive_conflicts : int
        Steps where Moreau-Jean would deactivate a contact carrying an impulse here.
    status : int
        See :data:`OCP_STATUS_MESSAGES`; ``success = status >= 0``.
    message : str
    homotopy : list of HomotopyStage
        One entry per solve (the polishing solve has sigma = 0).
    iterations : int
        IPOPT iterations over all solves.
    solve_time, build_time : float
        Wall time of the solves and of building the NLP (s).
    problem : OptimalControlProblem
        The problem (for :func:`replay`).
    """

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    u: np.ndarray
    p_N: np.ndarray
    p_T: np.ndarray
    modes: np.ndarray
    T: float
    h: float
    cost: float
    peak: float
    complementarity_residual: float
    lcp_residual: float
    dynamics_residual: float
    inactive_conflicts: int
    status: int
    message: str
    homotopy: list
    iterations: int
    solve_time: float
    build_time: float
    problem: "OptimalControlProblem" = field(repr=False, default=None)

    @property
    def homotopy_steps(self) -> int:
        """Relaxation stages solved (the polishing solve not counted)."""
        return sum(1 for s in self.homotopy if s.sigma > 0)

    def control(self, t) -> np.ndarray:
        """The control at times t (linear hold; constant extrapolation), shape t.shape + (nu,)."""
        t = np.asarray(t, dtype=float)
        return np.stack([np.interp(t, self.t, self.u[:, j]) for j in range(self.u.shape[1])], axis=-1)

    def __repr__(self) -> str:
        return (f"OCPResult(N={len(self.t) - 1}, T={self.T:.6g}, cost={self.cost:.6g}, "
                f"residual={self.complementarity_residual:.2e}, iterations={self.iterations}, "
                f"status={self.status}, message={self.message!r})")


@dataclass
class ReplayResult:
    """An open-loop replay of an optimal control through :func:`lcp.simulate`.

    Attributes
    ----------
    sim : SimulationResult
        The replay.
    method : str
    h : float
        Replay step (nan for the event integrator).
    t : ndarray, shape (N + 1,)
        The optimizer's nodes.
    q, v : ndarray, shape (N + 1, n)
        The replay at those nodes.
    error_q, error_v : ndarray, shape (n,)
        max over the nodes of |q_opt - q_replay| and |v_opt - v_replay|, per coordinate.
    """

    sim: object
    method: str
    h: float
    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    error_q: np.ndarray
    error_v: np.ndarray

    @property
    def max_error_q(self) -> float:
        return float(np.max(self.error_q))

    @property
    def max_error_v(self) -> float:
        return float(np.max(self.error_v))


# ---------------------------------------------------------------------------------------- helpers
def tangential_push(system: System, contact: int = 0) -> ca.SX:
    """Control matrix B(q) = H_T(q)' of one contact: a force along that contact's tangent.

    For the Jean-Pratt block this is the horizontal force on m (``phi`` in the scene).

    Examples
    --------
    >>> import casadi as ca, numpy as np
    >>> from lcp.scenes import jean_pratt
    >>> from lcp.ocp import tangential_push
    >>> np.array(ca.evalf(tangential_push(jean_pratt().system))).ravel()
    array([1., 0.])
    """
    if not isinstance(system, System):
        raise ValueError(f"system must be a System, got {type(system).__name__}")
    m = system.n_contacts
    if not isinstance(contact, (int, np.integer)) or not 0 <= contact < m:
        raise ValueError(f"contact must be an index in [0, {m}), got {contact!r}")
    return system.H_expr[m + contact, :].T


def _control_matrix(system: System, B) -> ca.SX:
    n = system.n
    try:
        Bx = B if isinstance(B, ca.SX) else ca.SX(np.asarray(B, dtype=float))
    except Exception as exc:  # noqa: BLE001 - CasADi/NumPy raise various types
        raise ValueError("control_matrix must be an array or a CasADi SX expression of q") from exc
    if Bx.shape[0] != n:
        if Bx.numel() == n:
            Bx = ca.reshape(Bx, n, 1)
        else:
            raise ValueError(f"control_matrix must have {n} rows, got shape {Bx.shape}")
    if Bx.shape[1] < 1:
        raise ValueError("control_matrix must have at least one column")
    if ca.depends_on(Bx, ca.vertcat(system.v_sym, system.t_sym)):
        raise ValueError("control_matrix may depend on q only")
    syms = ca.symvar(Bx)
    qs = {s.name() for s in ca.symvar(system.q_sym)}
    if any(s.name() not in qs for s in syms):
        raise ValueError("control_matrix contains symbols other than the system's q")
    return Bx


def controlled_system(system: System, control_matrix, t_nodes, u_nodes) -> System:
    """The system with the control force B(q) u(t) added, u linear between the nodes.

    Parameters
    ----------
    system : System
    control_matrix : array_like or casadi.SX, shape (n, nu)
    t_nodes : array_like, shape (K,)
        Increasing times.
    u_nodes : array_like, shape (K, nu) or (K,)
        Control values at the nodes (extrapolated linearly outside, which the replay never uses).

    Returns
    -------
    System
        Same coordinates, mass, contacts and constraints; its force depends on time.

    Examples
    --------
    >>> import lcp
    >>> from lcp.ocp import controlled_system, tangential_push
    >>> sc = lcp.scenes.jean_pratt(v0=0.0)
    >>> s = controlled_system(sc.system, tangential_push(sc.system), [0, 1], [0.0, 20.0])
    >>> s.force([0, 0], [0, 0], t=0.5)
    array([ 10.  , -19.62])
    """
    B = _control_matrix(system, control_matrix)
    nu = B.shape[1]
    t_nodes = np.asarray(t_nodes, dtype=float).ravel()
    u_nodes = np.asarray(u_nodes, dtype=float).reshape(len(t_nodes), -1)
    if u_nodes.shape[1] != nu:
        raise ValueError(f"u_nodes must have {nu} columns, got {u_nodes.shape[1]}")
    if len(t_nodes) < 2 or np.any(np.diff(t_nodes) <= 0) or not np.all(np.isfinite(t_nodes)):
        raise ValueError("t_nodes must be at least two finite, increasing times")
    if not np.all(np.isfinite(u_nodes)):
        raise ValueError("u_nodes must be finite")
    t = system.t_sym
    u = ca.vertcat(*[ca.pw_lin(t, ca.DM(t_nodes), ca.DM(u_nodes[:, j])) for j in range(nu)])
    force = system.force_expr + ca.mtimes(B, u)
    return System(system.q_sym, system.v_sym, system.mass_expr, force, contacts=system.contacts,
                  constraints=system.constraints_expr if system.n_bilateral else None, t=t,
                  names=system.names)


# ---------------------------------------------------------------------------------------- problem
class OptimalControlProblem:
    """Optimal control of a system with frictional contacts, transcribed with Moreau-Jean steps.

    minimize   terminal_cost(T, q_N, v_N) + sum_k h stage_cost(step_k) + max_k max_cost(step_k)
               + control_rate_weight sum_k |u_{k+1} - u_k|^2 / h
    subject to the Moreau-Jean step and the discrete Coulomb law at every step (module docstring),
               u_min <= u_k <= u_max,  q_0, v_0 given,
               terminal_constraints(q_N, v_N) = 0,  path_constraints(step_k) <= 0,
               T fixed, or T in T_bounds when ``free_time``.

    Parameters
    ----------
    system : System or Scene
        The model; a Scene also supplies q0 and v0.
    N : int
        Number of steps (control intervals), >= 1.
    control_matrix : array_like or casadi.SX, shape (n, nu)
        B(q): the generalized force of the control is B(q) u. See :func:`tangential_push`.
    u_min, u_max : float or array_like, shape (nu,)
        Control bounds (u_min <= u_max; +-inf allowed).
    T : float
        The final time, or its initial guess when ``free_time``.
    free_time : bool
        Make T a decision variable (h = T / N), for minimum-time problems (``terminal_cost=
        lambda T, q, v: T``).
    T_bounds : (float, float)
        Bounds of T when free.
    q0, v0 : array_like, shape (n,)
        Initial state (the scene's by default).
    theta : float
        Theta of the Moreau-Jean step, in [1/2, 1].
    stage_cost : callable(Step) -> scalar, optional
        Integrated as sum_k h stage_cost(step_k). :func:`effort` gives the exact integral of |u|^2.
    terminal_cost : callable(T, q, v) -> scalar, optional
    terminal_constraints : callable(q, v) -> vector, optional
        Equalities at the final node.
    path_constraints : callable(Step) -> vector, optional
        Inequalities (<= 0) at every step.
    max_cost : callable(Step) -> scalar, optional
        Minimizes its maximum over the steps (an epigraph variable), e.g. the peak normal force
        ``lambda s: s.N[0]``.
    control_rate_weight : float
        Adds this weight times the integral of |du/dt|^2. With theta = 1/2 a step only sees the
        mean (u_k + u_{k+1}) / 2, so an alternating (u_k) is invisible to the dynamics; when the
        cost does not penalize it either (minimum time, peak force), a small weight (1e-6) selects
        the smoothest of the equally good controls.

    Examples
    --------
    Push the Jean-Pratt block (friction 0.5) from rest to rest 0.2 m further in minimum time with
    |u| <= 20 N (the bang-bang bound for continuous time is 0.2811 s):

    >>> import casadi as ca, lcp
    >>> from lcp.ocp import OptimalControlProblem, tangential_push
    >>> sc = lcp.scenes.jean_pratt(v0=0.0)
    >>> ocp = OptimalControlProblem(sc, 10, control_matrix=tangential_push(sc.system), u_min=-20,
    ...                             u_max=20, T=0.5, free_time=True, T_bounds=(0.05, 2.0),
    ...                             terminal_cost=lambda T, q, v: T,
    ...                             terminal_constraints=lambda q, v: ca.vertcat(q[0] - 0.2, v[0]))
    >>> res = ocp.solve()
    >>> res.success, res.complementarity_residual <= 1e-8, round(res.T, 3)
    (True, True, 0.283)
    """

    def __init__(self, system, N: int, *, control_matrix, u_min=-np.inf, u_max=np.inf, T: float = 1.0,
                 free_time: bool = False, T_bounds=(1e-3, 1e3), q0=None, v0=None, theta: float = 0.5,
                 stage_cost: Callable | None = None, terminal_cost: Callable | None = None,
                 terminal_constraints: Callable | None = None, path_constraints: Callable | None = None,
                 max_cost: Callable | None = None, control_rate_weight: float = 0.0):
        from .scenes import Scene

        if isinstance(system, Scene):
            q0 = system.q0 if q0 is None else q0
            v0 = system.v0 if v0 is None else v0
            system = system.system
        if not isinstance(system, System):
            raise ValueError(f"system must be a System or a Scene, got {type(system).__name__}")
        if q0 is None or v0 is None:
            raise ValueError("q0 and v0 are required with a bare System")
        self.system = system
        self.q0, self.v0 = system.check_state(q0, v0)
        if not isinstance(N, (int, np.integer)) or isinstance(N, bool) or N < 1:
            raise ValueError(f"N must be an integer >= 1, got {N!r}")
        self.N = int(N)
        self.B = _control_matrix(system, control_matrix)
        self.nu = nu = self.B.shape[1]
        self.u_min = np.broadcast_to(np.asarray(u_min, dtype=float), (nu,)).copy()
        self.u_max = np.broadcast_to(np.asarray(u_max, dtype=float), (nu,)).copy()
        if np.any(np.isnan(self.u_min)) or np.any(np.isnan(self.u_max)) or np.any(self.u_min > self.u_max):
            raise ValueError(f"u_min and u_max must satisfy u_min <= u_max, got {u_min!r}, {u_max!r}")
        if not isinstance(theta, (int, float, np.floating)) or not 0.5 <= theta <= 1.0:
            raise ValueError(f"theta must lie in [1/2, 1], got {theta!r}")
        self.theta = float(theta)
        self.T = _positive("T", T)
        self.free_time = bool(free_time)
        try:
            lo, hi = (float(x) for x in T_bounds)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"T_bounds must be a pair of numbers, got {T_bounds!r}") from exc
        if not (0 < lo <= hi) or np.isnan(hi):
            raise ValueError(f"T_bounds must satisfy 0 < lower <= upper, got {T_bounds!r}")
        if self.free_time and not lo <= self.T <= hi:
            raise ValueError(f"T (the initial guess) must lie within T_bounds {T_bounds!r}, got {T!r}")
        self.T_bounds = (lo, hi)
        for name, fn in (("stage_cost", stage_cost), ("terminal_cost", terminal_cost),
                         ("terminal_constraints", terminal_constraints),
                         ("path_constraints", path_constraints), ("max_cost", max_cost)):
            if fn is not None and not callable(fn):
                raise ValueError(f"{name} must be callable or None")
        self.stage_cost, self.terminal_cost = stage_cost, terminal_cost
        self.terminal_constraints, self.path_constraints = terminal_constraints, path_constraints
        self.max_cost = max_cost
        self.control_rate_weight = _positive("control_rate_weight", control_rate_weight, allow_zero=True)
        self._nlp = None
        self._step_map = None
        self.build_time = 0.0

    # ------------------------------------------------------------------ the Moreau-Jean step
    def _step_function(self) -> ca.Function:
        """(t, h, q, v, u0, u1) -> (W_h, r, H, G, phi_t(t + h), gap): one step, as in lcp.timestepping."""
        sys, th = self.system, self.theta
        t, q, v = sys.t_sym, sys.q_sym, sys.v_sym
        h = ca.SX.sym("h")
        u0, u1 = ca.SX.sym("u0", self.nu), ca.SX.sym("u1", self.nu)
        F0 = sys.force_expr + ca.mtimes(self.B, u0)
        F1 = ca.substitute(sys.force_expr, t, t + h) + ca.mtimes(self.B, u1)
        K = -ca.jacobian(F0, q)
        C = -ca.jacobian(F0, v)
        A = sys.mass_expr
        Wh = A + h * th * C + (h * th) ** 2 * K
        r = h * ((1 - th) * F0 + th * F1) - h * h * th * ca.mtimes(K, v)
        G = ca.jacobian(sys.constraints_expr, q)
        phi_t1 = ca.substitute(ca.jacobian(sys.constraints_expr, t), t, t + h)
        return ca.Function("mj_step", [t, h, q, v, u0, u1], [Wh, r, sys.H_expr, G, phi_t1, sys.gap_expr])

    def _build(self):
        t_start = time.perf_counter()
        sys, N, n, nu, th = self.system, self.N, self.system.n, self.nu, self.theta
        m, nb = sys.n_contacts, sys.n_bilateral
        step = self._step_function()
        self._step = step
        mu, e = ca.DM(sys.mu), ca.DM(sys.e)

        xs, lbx, ubx = [], [], []
        offset = [0]

        def var(name, size, lb, ub):
            s = ca.SX.sym(name, size)
            xs.append(s)
            lbx.append(np.broadcast_to(lb, (size,)).astype(float))
            ubx.append(np.broadcast_to(ub, (size,)).astype(float))
            idx = np.arange(offset[0], offset[0] + size)
            offset[0] += size
            return s, idx

        sigma = ca.SX.sym("sigma")
        q0p, v0p = ca.SX.sym("q0", n), ca.SX.sym("v0", n)
        P = ca.vertcat(sigma, q0p, v0p)
        ix = {}
        if self.free_time:
            Tv, ix["T"] = var("T", 1, self.T_bounds[0], self.T_bounds[1])
        else:
            Tv = ca.SX(self.T)
        z = None
        if self.max_cost is not None:
            z, ix["z"] = var("z", 1, -np.inf, np.inf)
        h = Tv / N
        q_nodes, v_nodes, u_nodes = [q0p], [v0p], []
        ix["q"], ix["v"], ix["u"] = [], [], []
        for k in range(N + 1):
            uk, i = var(f"u{k}", nu, self.u_min, self.u_max)
            u_nodes.append(uk)
            ix["u"].append(i)
        for k in range(1, N + 1):
            qk, i = var(f"q{k}", n, -np.inf, np.inf)
            q_nodes.append(qk)
            ix["q"].append(i)
            vk, i = var(f"v{k}", n, -np.inf, np.inf)
            v_nodes.append(vk)
            ix["v"].append(i)
        names = ("pN", "bp", "bm", "lam", "wN", "wp", "wm", "wl")
        for nm in names + ("lb",):
            ix[nm] = []
        g, lbg, ubg = [], [], []

        def constrain(expr, lo, hi):
            expr = ca.vec(expr)
            g.append(expr)
            lbg.append(np.broadcast_to(lo, (expr.shape[0],)).astype(float))
            ubg.append(np.broadcast_to(hi, (expr.shape[0],)).astype(float))

        J = ca.SX(0)
        for k in range(N):
            blk = {}
            for nm in names:
                blk[nm], i = var(f"{nm}{k}", m, 0.0, np.inf)
                ix[nm].append(i)
            lamb, i = var(f"lb{k}", nb, -np.inf, np.inf)
            ix["lb"].append(i)
            tk = k * h
            qa, qb, va, vb = q_nodes[k], q_nodes[k + 1], v_nodes[k], v_nodes[k + 1]
            ua, ub = u_nodes[k], u_nodes[k + 1]
            Wh, r, H, G, phi_t1, _ = step(tk, h, qa, va, ua, ub)
            # the complementarity variables are forces (impulse / h), so that the relaxation a w <= sigma
            # means the same for every N (a product of a force and a velocity: a power)
            pN = h * blk["pN"]
            pT = h * (blk["bp"] - blk["bm"])
            p = ca.vertcat(pN, pT)
            dyn = ca.mtimes(Wh, vb - va) - r
            if m:
                dyn = dyn - ca.mtimes(H.T, p)
            if nb:
                dyn = dyn - ca.mtimes(G.T, lamb)
                constrain(ca.mtimes(G, vb) + phi_t1, 0.0, 0.0)
            constrain(dyn, 0.0, 0.0)
            constrain(qb - qa - h * ((1 - th) * va + th * vb), 0.0, 0.0)
            if m:
                HN, HT = H[:m, :], H[m:, :]
                uN, uT = ca.mtimes(HN, vb), ca.mtimes(HT, vb)
                lam = blk["lam"]
                # lifted right-hand sides of the LCP (ContactProblem.to_lcp)
                constrain(blk["wN"] - (uN + e * ca.fmin(ca.mtimes(HN, va), 0)), 0.0, 0.0)
                constrain(blk["wp"] - (lam + uT), 0.0, 0.0)
                constrain(blk["wm"] - (lam - uT), 0.0, 0.0)
                constrain(blk["wl"] - (mu * blk["pN"] - blk["bp"] - blk["bm"]), 0.0, 0.0)
                a = ca.vertcat(blk["pN"], blk["bp"], blk["bm"], lam)
                w = ca.vertcat(blk["wN"], blk["wp"], blk["wm"], blk["wl"])
                constrain(a * w - sigma, -np.inf, 0.0)  # Scholtes
            st = Step(k, tk, tk + h, h, qa, qb, va, vb, ua, ub, pN, pT)
            if self.stage_cost is not None:
                J = J + h * _scalar(self.stage_cost(st), "stage_cost")
            if self.control_rate_weight:
                J = J + self.control_rate_weight * ca.sumsqr(ub - ua) / h
            if self.path_constraints is not None:
                pc = ca.vec(ca.SX(self.path_constraints(st)))
                constrain(pc, -np.inf, 0.0)
            if self.max_cost is not None:
                constrain(_scalar(self.max_cost(st), "max_cost") - z, -np.inf, 0.0)
        if self.terminal_cost is not None:
            J = J + _scalar(self.terminal_cost(Tv, q_nodes[-1], v_nodes[-1]), "terminal_cost")
        if self.terminal_constraints is not None:
            constrain(ca.vec(ca.SX(self.terminal_constraints(q_nodes[-1], v_nodes[-1]))), 0.0, 0.0)
        if z is not None:
            J = J + z
        x = ca.vertcat(*xs)
        gg = ca.vertcat(*g) if g else ca.SX.zeros(0, 1)
        nlp = {"x": x, "f": J, "g": gg, "p": P}
        self._ix = {key: (np.array(val) if isinstance(val, list) else val) for key, val in ix.items()}
        self._lbx, self._ubx = np.concatenate(lbx), np.concatenate(ubx)
        self._lbg = np.concatenate(lbg) if lbg else np.zeros(0)
        self._ubg = np.concatenate(ubg) if ubg else np.zeros(0)
        self._nlp = nlp
        self._solvers = {}
        self.build_time = time.perf_counter() - t_start

    def _solver(self, options: HomotopyOptions, warm: bool) -> ca.Function:
        key = (warm, options.max_iter, options.ipopt_tol, tuple(sorted((options.ipopt_options or {}).items())))
        if key not in self._solvers:
            t0 = time.perf_counter()
            ip = {"print_level": 0, "sb": "yes", "tol": options.ipopt_tol,
                  "constr_viol_tol": options.ipopt_tol, "max_iter": int(options.max_iter),
                  "mu_strategy": "adaptive", "bound_relax_factor": 0.0}
            if warm:
                # the previous stage's solution is close: start IPOPT's barrier small so that the
                # warm start is not pushed back into the interior
                ip.update({"warm_start_init_point": "yes", "mu_init": 1e-6,
                           "warm_start_bound_push": 1e-9, "warm_start_mult_bound_push": 1e-9})
            ip.update(options.ipopt_options or {})
            self._solvers[key] = ca.nlpsol("ocp_warm" if warm else "ocp", "ipopt", self._nlp,
                                           {"print_time": False, "ipopt": ip})
            self.build_time += time.perf_counter() - t0
        return self._solvers[key]

    # ------------------------------------------------------------------ guesses
    def guess(self, u=0.0, T: float | None = None, solver: str = "auto") -> OCPGuess:
        """An initial guess from a simulation: replay the control ``u`` through :func:`lcp.simulate`.

        Parameters
        ----------
        u : float, array_like or callable
            The control: a constant (nu,), node values (N + 1, nu), or a function of t.
        T : float, optional
            Horizon (the problem's T by default).
        solver : str
            One-step contact solver of the simulation.
        """
        from .simulation import simulate

        T = self.T if T is None else _positive("T", T)
        t = np.linspace(0.0, T, self.N + 1)
        if callable(u):
            un = np.array([np.broadcast_to(np.asarray(u(tk), dtype=float), (self.nu,)) for tk in t])
        else:
            ua = np.asarray(u, dtype=float)
            un = (np.broadcast_to(ua, (self.nu,))[None, :].repeat(self.N + 1, 0) if ua.size == self.nu
                  else ua.reshape(self.N + 1, self.nu))
        un = np.clip(un, self.u_min, self.u_max)
        sysc = controlled_system(self.system, self.B, t, un)
        sim = simulate(sysc, T, h=T / self.N, theta=self.theta, solver=solver, q0=self.q0, v0=self.v0)
        if not sim.success or len(sim.t) != self.N + 1:
            raise ValueError(f"the guess simulation failed: {sim.message}")
        return OCPGuess(T=T, q=sim.q, v=sim.v, u=un, p_N=sim.p_N, p_T=sim.p_T, source="simulation")

    def _x0(self, gs: OCPGuess) -> np.ndarray:
        """Fill every NLP variable from a guess, the Coulomb multipliers from the impulses."""
        ix, N = self._ix, self.N
        x0 = np.zeros(len(self._lbx))
        if self.free_time:
            x0[ix["T"]] = np.clip(gs.T, *self.T_bounds)
        for k in range(N + 1):
            x0[ix["u"][k]] = gs.u[k]
        for k in range(1, N + 1):
            x0[ix["q"][k - 1]] = gs.q[k]
            x0[ix["v"][k - 1]] = gs.v[k]
        m = self.system.n_contacts
        if m:
            h = gs.T / N
            mu, e = self.system.mu, self.system.e
            for k in range(N):
                H = self.system.contact_jacobian(gs.q[k])
                uN, uT = H[:m] @ gs.v[k + 1], H[m:] @ gs.v[k + 1]
                pN, pT = np.maximum(gs.p_N[k], 0.0) / h, gs.p_T[k] / h  # forces
                bp, bm = np.maximum(pT, 0.0), np.maximum(-pT, 0.0)
                lam = np.abs(uT)
                vals = {"pN": pN, "bp": bp, "bm": bm, "lam": lam,
                        "wN": np.maximum(uN + e * np.minimum(H[:m] @ gs.v[k], 0.0), 0.0),
                        "wp": np.maximum(lam + uT, 0.0), "wm": np.maximum(lam - uT, 0.0),
                        "wl": np.maximum(mu * pN - bp - bm, 0.0)}
                for nm, val in vals.items():
                    x0[ix[nm][k]] = val
        if self.max_cost is not None:
            x0[ix["z"]] = 0.0
        return x0

    def _guess_from(self, guess) -> OCPGuess:
        if guess is None:
            mid = np.where(np.isfinite(self.u_min) & np.isfinite(self.u_max), 0.5 * (self.u_min + self.u_max),
                           np.clip(0.0, self.u_min, self.u_max))
            return self.guess(u=mid)
        if isinstance(guess, OCPResult):
            return _resample(guess, self.N)
        if isinstance(guess, OCPGuess):
            if guess.q.shape != (self.N + 1, self.system.n) or guess.u.shape != (self.N + 1, self.nu):
                return _resample(guess, self.N)
            return guess
        raise ValueError(f"guess must be None, an OCPGuess or an OCPResult, got {type(guess).__name__}")

    # ------------------------------------------------------------------ solve
    def solve(self, guess=None, options: HomotopyOptions | None = None, **option_kw) -> OCPResult:
        """Solve by the Scholtes homotopy from a guess.

        Parameters
        ----------
        guess : OCPGuess, OCPResult or None
            Initial guess; an OCPResult of another N is resampled. By default, the simulation of
            the mid-range control (:meth:`guess`).
        options : HomotopyOptions, optional
        **option_kw
            Fields of :class:`HomotopyOptions` (instead of ``options``).

        Returns
        -------
        OCPResult
        """
        if options is None:
            options = HomotopyOptions(**option_kw)
        elif option_kw:
            raise ValueError("give either options or keyword options, not both")
        if not isinstance(options, HomotopyOptions):
            raise ValueError(f"options must be HomotopyOptions, got {type(options).__name__}")
        if self._nlp is None:
            self._build()
        gs = self._guess_from(guess)
        cold, warm = self._solver(options, False), self._solver(options, True)
        x = self._x0(gs)
        P0 = np.concatenate([[0.0], self.q0, self.v0])
        lam_x = lam_g = None
        history: list[HomotopyStage] = []
        status, message = -2, OCP_STATUS_MESSAGES[-2]
        t_solve = time.perf_counter()
        sigma = float(options.sigma0)
        best = None
        for i in range(options.n_stages):
            P0[0] = sigma
            args = dict(x0=x, lbx=self._lbx, ubx=self._ubx, lbg=self._lbg, ubg=self._ubg, p=P0)
            t0 = time.perf_counter()
            if lam_x is None:
                sol = cold(**args)
                st = cold.stats()
            else:
                sol = warm(lam_x0=lam_x, lam_g0=lam_g, **args)
                st = warm.stats()
            dt = time.perf_counter() - t0
            xs = np.array(sol["x"]).ravel()
            diag = self._diagnose(xs)
            ok = bool(st["success"]) or st["return_status"] == "Solved_To_Acceptable_Level"
            history.append(HomotopyStage(sigma, int(st["iter_count"]), diag["residual"], diag["max_product"],
                                         float(sol["f"]), st["return_status"], ok, dt))
            if not ok:
                status = -1
                message = (f"{OCP_STATUS_MESSAGES[-1]} Stage {i} (sigma = {sigma:.3g}): "
                           f"IPOPT returned {st['return_status']}.")
                break
            x, lam_x, lam_g = xs, np.array(sol["lam_x"]).ravel(), np.array(sol["lam_g"]).ravel()
            best = (x, float(sol["f"]), diag)
            if diag["residual"] <= options.tol:
                status, message = 0, OCP_STATUS_MESSAGES[0]
                break
            sigma = max(sigma * options.factor, options.sigma_min)
        if best is not None and status == -2:
            message = (f"{OCP_STATUS_MESSAGES[-2]} Residual {best[2]['residual']:.3g} > tol = {options.tol:.3g} "
                       f"at sigma = {history[-1].sigma:.3g}.")
        if best is not None and options.polish:
            pol = self._polish(best[0], lam_x, lam_g, P0, warm)
            if pol is not None:
                xp, fp, diagp, st, dt = pol
                okp = bool(st["success"])
                history.append(HomotopyStage(0.0, int(st["iter_count"]), diagp["residual"], diagp["max_product"],
                                             fp, st["return_status"], okp, dt))
                if okp and diagp["residual"] <= max(best[2]["residual"], options.tol):
                    best = (xp, fp, diagp)
                    if diagp["residual"] <= options.tol and status != 0:
                        # the last converged stage identified the active set; polishing finished it
                        message = (f"{OCP_STATUS_MESSAGES[0]} (By the polishing solve; before it: {message})")
                        status = 0
                elif status == 0:
                    status, message = 1, OCP_STATUS_MESSAGES[1]
        solve_time = time.perf_counter() - t_solve
        if best is None:
            xs = x
            diag = self._diagnose(np.asarray(xs))
            cost = float("nan")
        else:
            xs, cost, diag = best
        return self._result(xs, cost, diag, status, message, history, solve_time)

    def _polish(self, x, lam_x, lam_g, P, solver):
        """Fix the smaller member of each complementarity pair at zero and re-solve."""
        if self.system.n_contacts == 0:
            return None
        ix = self._ix
        lbx, ubx = self._lbx.copy(), self._ubx.copy()
        for a_nm, w_nm in (("pN", "wN"), ("bp", "wp"), ("bm", "wm"), ("lam", "wl")):
            ia, iw = ix[a_nm].ravel(), ix[w_nm].ravel()
            a_small = x[ia] <= x[iw]
            ubx[ia[a_small]] = 0.0
            ubx[iw[~a_small]] = 0.0
        x0 = np.clip(x, lbx, ubx)
        t0 = time.perf_counter()
        sol = solver(x0=x0, lam_x0=lam_x, lam_g0=lam_g, lbx=lbx, ubx=ubx, lbg=self._lbg, ubg=self._ubg, p=P)
        dt = time.perf_counter() - t0
        xs = np.array(sol["x"]).ravel()
        return xs, float(sol["f"]), self._diagnose(xs), solver.stats(), dt

    # ------------------------------------------------------------------ checks, independent of IPOPT
    def _unpack(self, x):
        ix, N, n = self._ix, self.N, self.system.n
        T = float(x[ix["T"]][0]) if self.free_time else self.T
        q = np.vstack([self.q0] + [x[i] for i in ix["q"]]).reshape(N + 1, n)
        v = np.vstack([self.v0] + [x[i] for i in ix["v"]]).reshape(N + 1, n)
        u = np.vstack([x[i] for i in ix["u"]]).reshape(N + 1, self.nu)
        m = self.system.n_contacts
        if m:
            h = T / N
            pN = h * x[ix["pN"]].reshape(N, m)
            pT = h * (x[ix["bp"]] - x[ix["bm"]]).reshape(N, m)
        else:
            pN = pT = np.zeros((N, 0))
        return T, q, v, u, pN, pT

    def _diagnose(self, x) -> dict:
        """Coulomb residual (ContactProblem.residual), dynamics residual and modes, per step, in NumPy."""
        T, q, v, u, pN, pT = self._unpack(x)
        N, n, m, nb = self.N, self.system.n, self.system.n_contacts, self.system.n_bilateral
        h, th = T / N, self.theta
        mu, e = self.system.mu, self.system.e
        if self._step_map is None:
            self._step_map = self._step.map(N)
        out = self._step_map(h * np.arange(N)[None, :], h, q[:-1].T, v[:-1].T, u[:-1].T, u[1:].T)

        def blocks(a, r, c):  # (r, c N) -> (N, r, c)
            return np.array(a, dtype=float).reshape(r, N, c).transpose(1, 0, 2)

        Wh = blocks(out[0], n, n)
        r = blocks(out[1], n, 1)[..., 0]
        H = blocks(out[2], 2 * m, n)
        G = blocks(out[3], nb, n)
        phi_t1 = blocks(out[4], nb, 1)[..., 0]
        gap = blocks(out[5], m, 1)[..., 0]
        KKT = np.zeros((N, n + nb, n + nb))
        KKT[:, :n, :n] = Wh
        KKT[:, :n, n:] = G.transpose(0, 2, 1)
        KKT[:, n:, :n] = G
        rhs = np.concatenate([r, -phi_t1 - np.einsum("kij,kj->ki", G, v[:-1])], axis=1)
        vfree = v[:-1] + np.linalg.solve(KKT, rhs[..., None])[:, :n, 0]
        res, conflicts = 0.0, 0
        modes = np.full((N, m), -1, dtype=np.int8)
        if m:
            SHt = np.linalg.solve(KKT, np.concatenate([H.transpose(0, 2, 1), np.zeros((N, nb, 2 * m))], axis=1))[:, :n]
            W = H @ SHt
            uN_minus = np.einsum("kij,kj->ki", H[:, :m], v[:-1])
            qf = np.einsum("kij,kj->ki", H, vfree)
            gap_pred = gap + h * ((1 - th) * uN_minus + th * qf[:, :m])
            qf[:, :m] += e * np.minimum(uN_minus, 0.0)  # restitution of approaching contacts only
            p = np.concatenate([pN, pT], axis=1)
            for k in range(N):
                pb = ContactProblem(W[k], qf[k], mu)
                res = max(res, pb.residual(p[k]))
                modes[k] = pb.modes(p[k], rtol=1e-6)
                conflicts += int(np.any((gap_pred[k] > 0) & (pN[k] > 1e-9 * max(1.0, pb.scale))))
            vplus = vfree + np.einsum("kij,kj->ki", SHt, p)
        else:
            vplus = vfree
        dres = float(np.max(np.abs(vplus - v[1:])))
        ix = self._ix
        if m:
            a = np.concatenate([x[ix[nm]].ravel() for nm in ("pN", "bp", "bm", "lam")])
            w = np.concatenate([x[ix[nm]].ravel() for nm in ("wN", "wp", "wm", "wl")])
            max_product = float(np.max(a * w))
            lcp_res = float(np.max(np.abs(np.minimum(a, w))))
        else:
            max_product = lcp_res = 0.0
        return {"residual": res, "dynamics": dres, "modes": modes, "conflicts": conflicts,
                "max_product": max_product, "lcp": lcp_res}

    def _result(self, x, cost, diag, status, message, history, solve_time) -> OCPResult:
        T, q, v, u, pN, pT = self._unpack(x)
        peak = float(x[self._ix["z"]][0]) if self.max_cost is not None else float("nan")
        return OCPResult(t=np.linspace(0.0, T, self.N + 1), q=q, v=v, u=u, p_N=pN, p_T=pT,
                         modes=diag["modes"], T=T, h=T / self.N, cost=cost, peak=peak,
                         complementarity_residual=diag["residual"], lcp_residual=diag["lcp"],
                         dynamics_residual=diag["dynamics"], inactive_conflicts=diag["conflicts"],
                         status=status, message=message, homotopy=history,
                         iterations=sum(s.iterations for s in history), solve_time=solve_time,
                         build_time=self.build_time, problem=self)


def _scalar(expr, name):
    x = ca.SX(expr)
    if x.numel() != 1:
        raise ValueError(f"{name} must return a scalar, got shape {x.shape}")
    return x


def _resample(res, N: int) -> OCPGuess:
    """Interpolate a solution or guess onto N steps (impulses as forces, rescaled by the new h)."""
    T = float(res.T)
    M = res.q.shape[0] - 1
    t_old = np.linspace(0.0, T, M + 1)
    t_new = np.linspace(0.0, T, N + 1)

    def interp(a, told, tnew):
        return np.stack([np.interp(tnew, told, a[:, j]) for j in range(a.shape[1])], axis=1) \
            if a.shape[1] else np.zeros((len(tnew), 0))

    tm_old = 0.5 * (t_old[1:] + t_old[:-1])
    tm_new = 0.5 * (t_new[1:] + t_new[:-1])
    h_old, h_new = T / M, T / N
    return OCPGuess(T=T, q=interp(res.q, t_old, t_new), v=interp(res.v, t_old, t_new),
                    u=interp(res.u, t_old, t_new),
                    p_N=interp(res.p_N / h_old, tm_old, tm_new) * h_new,
                    p_T=interp(res.p_T / h_old, tm_old, tm_new) * h_new, source="resampled")


# ---------------------------------------------------------------------------------------- replay
def replay(result: OCPResult, refine: int = 10, method: str = "moreau-jean", solver: str = "auto",
           theta: float | None = None, **method_options) -> ReplayResult:
    """Replay an optimal control open-loop through :func:`lcp.simulate` and measure the mismatch.

    The control is the optimizer's first-order hold, as a time-dependent force
    (:func:`controlled_system`). With ``refine=1`` and the problem's theta, Moreau-Jean repeats the
    optimizer's steps, so the mismatch is the solver precision; with ``refine > 1`` (step
    h / refine) it measures the time-discretization error of the transcription.

    Parameters
    ----------
    result : OCPResult
    refine : int
        Replay steps per optimizer step (Moreau-Jean), >= 1.
    method : str
        ``"moreau-jean"`` or ``"event"`` (:mod:`lcp.events`, when available).
    solver : str
        One-step contact solver (Moreau-Jean).
    theta : float, optional
        Theta of the replay (the problem's by default).
    **method_options
        Passed to :func:`lcp.simulate` for other methods.

    Returns
    -------
    ReplayResult
        The replay at the optimizer's nodes and the max mismatch per coordinate.
    """
    from .simulation import simulate

    if not isinstance(result, OCPResult) or result.problem is None:
        raise ValueError("result must be an OCPResult returned by OptimalControlProblem.solve")
    if not isinstance(refine, (int, np.integer)) or refine < 1:
        raise ValueError(f"refine must be an integer >= 1, got {refine!r}")
    pb = result.problem
    sysc = controlled_system(pb.system, pb.B, result.t, result.u)
    N = len(result.t) - 1
    if method == "moreau-jean":
        h = result.T / (N * refine)
        sim = simulate(sysc, result.T, h=h, theta=pb.theta if theta is None else theta, solver=solver,
                       q0=pb.q0, v0=pb.v0)
        if not sim.success:
            raise RuntimeError(f"replay failed: {sim.message}")
        q, v = sim.q[::refine][: N + 1], sim.v[::refine][: N + 1]
    else:
        h = float("nan")
        if method == "event":
            method_options.setdefault("t_eval", result.t)
        sim = simulate(sysc, result.T, method=method, q0=pb.q0, v0=pb.v0, **method_options)
        if not sim.success:
            raise RuntimeError(f"replay failed: {sim.message}")
        if len(sim.t) == N + 1 and np.allclose(sim.t, result.t, rtol=0, atol=1e-12 * result.T):
            q, v = sim.q, sim.v
        else:
            q = np.stack([np.interp(result.t, sim.t, sim.q[:, j]) for j in range(sim.q.shape[1])], axis=1)
            v = np.stack([np.interp(result.t, sim.t, sim.v[:, j]) for j in range(sim.v.shape[1])], axis=1)
    return ReplayResult(sim=sim, method=method, h=h, t=result.t, q=q, v=v,
                        error_q=np.max(np.abs(q - result.q), axis=0),
                        error_v=np.max(np.abs(v - result.v), axis=0))


__all__ += ["MODE_NAMES"]
