"""The optimal control problem: a controlled System, a horizon, costs and constraints."""
from __future__ import annotations

from collections.abc import Callable

import casadi as ca
import numpy as np

from lcp.model.control import HOLDS, ControlSchedule
from lcp.model.kinematics import refuse_kinematics
from lcp.model.system import System, moving_contact
from lcp.ocp.guess import multistart, simulate_guess
from lcp.ocp.model import add_control
from lcp.ocp.options import HomotopyOptions, positive
from lcp.ocp.pairs import check_pairs
from lcp.ocp.results import OCPGuess, OCPResult, Step
from lcp.ocp.solve import first_pass, solve_defaults
from lcp.ocp.spatial import check_spatial
from lcp.model.schedule import AffineSchedule

__all__ = ["OCP_HOLDS", "OptimalControlProblem"]

#: control holds of the transcription: those of :class:`lcp.model.control.ControlSchedule` and the
#: discontinuous piecewise-affine hold (:class:`lcp.model.schedule.AffineSchedule`)
OCP_HOLDS = HOLDS + ("affine",)


class OptimalControlProblem:
    """Optimal control of a system with frictional contacts, transcribed with Moreau-Jean steps.

    minimize   terminal_cost(T, q_N, v_N) + sum_k h_k stage_cost(step_k) + max_k max_cost(step_k)
               + control_rate_weight sum_k |u_{k+1} - u_k|^2 / h_k
    subject to the Moreau-Jean step and the discrete Coulomb law at every step
               (:mod:`lcp.ocp.transcription`), the control within the system's control bounds,
               q_0, v_0 given, terminal_constraints(q_N, v_N) = 0, path_constraints(step_k) <= 0,
               T fixed, or T in T_bounds when ``free_time``.

    Parameters
    ----------
    system : System or Scene
        The model, with its control input (``System(..., control=u, control_bounds=...)``); a
        Scene also supplies q0 and v0. The same System replays the solution
        (``lcp.simulate(system, T, control=result.control)``).
    N : int
        Number of steps (control intervals), >= 1.
    control_matrix : array_like or casadi.SX, shape (n, nu), optional
        For an uncontrolled system: B(q), the control force being B(q) u (:func:`add_control`
        builds the controlled System, stored as :attr:`system`). See :func:`tangential_push`.
    u_min, u_max : float or array_like, shape (nu,), optional
        Control bounds (the system's ``control_bounds`` by default).
    T : float
        The final time, or its initial guess when ``free_time``.
    free_time : bool
        Make T a decision variable, for minimum-time problems (``terminal_cost=lambda T, q, v: T``).
    T_bounds : (float, float)
        Bounds of T when free.
    q0, v0 : array_like, shape (n,)
        Initial state (the scene's by default).
    theta : float
        Theta of the Moreau-Jean step, in [1/2, 1].
    hold : {"auto", "constant", "linear", "affine"}
        The control between nodes: piecewise constant (one value per step), piecewise linear and
        continuous (one value per node), or affine on each step and free to jump at the nodes (a
        start and an end value per step, :class:`~lcp.model.schedule.AffineSchedule`). The
        control's impulse is integrated exactly by every hold; the affine hold also corrects the
        trapezoidal position update for forces affine in t (theta = 1/2 only), so that with free
        steps a smooth optimal control within a contact phase is represented and integrated
        exactly (:mod:`lcp.ocp.transcription`). ``"auto"``: affine with free steps where modelled.
    steps : {"auto", "uniform", "free"}
        Uniform steps T / N, or step lengths as unknowns (within ``step_bounds`` times T / N) with
        the cross complementarity that puts every switch on a node (:mod:`lcp.ocp.transcription`).
        ``"auto"``: free for planar contacts unless a step callable reads the step index ``k``
        with no ``node_times`` pinning the grid (:func:`step_indexed`); a failed solve on them is
        repeated on uniform steps (:func:`lcp.ocp.solve.solve_defaults`).
    step_bounds : (float, float)
        Bounds of a free step, relative to T / N. A step of a phase the optimum lacks shrinks to
        the lower bound and is then merged into a neighbour's phase; a lower bound of 1e-3 let
        short steps carry large forces the replay refused (misses of 0.3 m), so 0.05 stays.
    node_times : dict {k: t}, optional
        Pin node k at time t (free steps; e.g. the ends of a time window of a path constraint).
    stage_cost : callable(Step) -> scalar, optional
        Integrated as sum_k h_k stage_cost(step_k). :func:`effort` gives the exact integral of |u|^2.
    terminal_cost : callable(T, q, v) -> scalar, optional
    terminal_constraints : callable(q, v) -> vector, optional
        Equalities at the final node.
    path_constraints : callable(Step) -> vector, optional
        Inequalities (<= 0) at every step (``Step.k`` selects steps).
    path_equalities : callable(Step) -> vector, optional
        Equalities (= 0) at every step, e.g. a hold ``lambda s: ca.vertcat(s.q1[0] - d, s.v1[0])
        if 8 <= s.k < 12 else ca.SX.zeros(0, 1)`` (an equality written as two inequalities leaves
        IPOPT no interior).
    max_cost : callable(Step) -> scalar, optional
        Minimizes its maximum over the steps (an epigraph variable).
    control_rate_weight : float
        Adds this weight times sum |u_{k+1} - u_k|^2 / h: selects the smoothest of equally good
        controls (minimum time, peak force).
    replay_tol : float or None
        ``success`` requires the replay miss (:attr:`OCPResult.replay`) within it; None skips the
        replay.
    contact_law : {"auto", "gap", "velocity"}
        ``"gap"`` (the default, None, for planar contacts): 0 <= g(q_{k+1}) perp N_k >= 0, a force
        only where the gap is closed at both ends of the step, impulses at the nodes under the event
        method's impact law: a contact can open, fly and close. ``"velocity"`` (the default for
        spatial contacts): Moreau-Jean's law on every contact at every step (each stays closed).
        ``"auto"``: the gap law when a contact starts open, else the velocity law.
    complementarity : list of (callable(Step), callable(Step)), optional
        Path pairs 0 <= a(step) perp b(step) >= 0 at every step, relaxed with the contacts (:mod:`lcp.ocp.pairs`).
    integrator : {"theta", "radau"}
        The step: Moreau-Jean's theta step (:mod:`lcp.ocp.transcription`), or Radau IIA collocation with
        ``stages`` stages in each step (:mod:`lcp.ocp.collocation`: order 2 stages - 1 on smooth
        dynamics; the velocity law only, so contacts must start closed, ``contact_law`` defaulting to "auto").
    stages : int
        Radau IIA stages per step, 1 to 4 (``integrator="radau"``).

    Examples
    --------
    Push the Jean-Pratt block (friction 0.5) from rest to rest 0.2 m further in minimum time with
    |u| <= 20 N (bang-bang; the continuous optimum is 0.281085 s), on the default free steps:

    >>> import casadi as ca, lcp
    >>> from lcp.ocp import OptimalControlProblem, tangential_push
    >>> sc = lcp.scenes.jean_pratt(v0=0.0)
    >>> ocp = OptimalControlProblem(sc, 4, control_matrix=tangential_push(sc.system), u_min=-20,
    ...                             u_max=20, T=0.5, free_time=True, T_bounds=(0.05, 2.0),
    ...                             terminal_cost=lambda T, q, v: T,
    ...                             terminal_constraints=lambda q, v: ca.vertcat(q[0] - 0.2, v[0]))
    >>> res = ocp.solve()
    >>> res.success, round(res.T, 6), res.replay.final_miss < 1e-9
    (True, 0.281085, True)
    """

    def __init__(self, system, N: int, *, control_matrix=None, u_min=None, u_max=None, T: float = 1.0,
                 free_time: bool = False, T_bounds=(1e-3, 1e3), q0=None, v0=None, theta: float = 0.5,
                 hold: str = "auto", steps: str = "auto", step_bounds=(0.05, 4.0), node_times=None,
                 stage_cost: Callable | None = None, terminal_cost: Callable | None = None,
                 terminal_constraints: Callable | None = None, path_constraints: Callable | None = None,
                 path_equalities: Callable | None = None, max_cost: Callable | None = None, control_rate_weight: float = 0.0,
                 replay_tol: float | None = 1e-6, contact_law: str | None = None, complementarity=None,
                 integrator: str = "theta", stages: int = 2):
        from lcp.scenes.scene import Scene

        if isinstance(system, Scene):
            q0 = system.q0 if q0 is None else q0
            v0 = system.v0 if v0 is None else v0
            system = system.system
        if not isinstance(system, System):
            raise ValueError(f"system must be a System or a Scene, got {type(system).__name__}")
        _refuse_unmodelled(system)
        if control_matrix is not None:
            system = add_control(system, control_matrix,
                                 -np.inf if u_min is None else u_min, np.inf if u_max is None else u_max)
        elif not system.is_controlled:
            raise ValueError("the system has no control: build it with System(..., control=u) or give "
                             "control_matrix")
        if q0 is None or v0 is None:
            raise ValueError("q0 and v0 are required with a bare System")
        self.system = system
        self.q0, self.v0 = system.check_state(q0, v0)
        if not isinstance(N, (int, np.integer)) or isinstance(N, bool) or N < 1:
            raise ValueError(f"N must be an integer >= 1, got {N!r}")
        self.N, self.nu = int(N), system.nu
        lo, hi = system.control_bounds
        lo = lo if u_min is None else np.broadcast_to(np.asarray(u_min, dtype=float), (self.nu,))
        hi = hi if u_max is None else np.broadcast_to(np.asarray(u_max, dtype=float), (self.nu,))
        if np.any(np.isnan(lo)) or np.any(np.isnan(hi)) or np.any(lo > hi):
            raise ValueError(f"u_min and u_max must satisfy u_min <= u_max, got {u_min!r}, {u_max!r}")
        self.u_min, self.u_max = np.array(lo, dtype=float), np.array(hi, dtype=float)
        if not isinstance(theta, (int, float, np.floating)) or not 0.5 <= theta <= 1.0:
            raise ValueError(f"theta must lie in [1/2, 1], got {theta!r}")
        self.theta = float(theta)
        self.step_fractions = None  # fixed steps / T (None: uniform): a phase_guess grid
        #: the contact law of the transcription, "gap" or "velocity" ("auto" resolved)
        self.integrator, self.stages, self.contact_law = _integrator(system, self.q0, integrator, stages, contact_law)
        self.T = positive("T", T)
        self.free_time = bool(free_time)
        self.T_bounds = _pair("T_bounds", T_bounds)
        if self.free_time and not self.T_bounds[0] <= self.T <= self.T_bounds[1]:
            raise ValueError(f"T (the initial guess) must lie within T_bounds {T_bounds!r}, got {T!r}")
        for name, fn in (("stage_cost", stage_cost), ("terminal_cost", terminal_cost),
                         ("terminal_constraints", terminal_constraints),
                         ("path_constraints", path_constraints), ("path_equalities", path_equalities),
                         ("max_cost", max_cost)):
            if fn is not None and not callable(fn):
                raise ValueError(f"{name} must be callable or None")
        # grid_fallback: free steps chosen by steps="auto" (a failed solve is repeated on uniform ones)
        self.hold, self.steps, self.step_bounds, self.grid_fallback = _grid(
            system, self.theta, hold, steps, step_bounds, node_times is None and step_indexed(
                system, self.N, self.nu, (stage_cost, path_constraints, path_equalities, max_cost,
                                          *[f for pair in check_pairs(complementarity) for f in pair])))
        self.hold_auto = hold == "auto"
        check_spatial(system, self.contact_law, self.hold, self.steps)  # what lcp.ocp.spatial models
        self.node_times = _check_node_times(self, node_times)
        self.stage_cost, self.terminal_cost = stage_cost, terminal_cost
        self.terminal_constraints, self.path_constraints = terminal_constraints, path_constraints
        self.path_equalities = path_equalities
        self.max_cost, self.complementarity = max_cost, check_pairs(complementarity)
        self.control_rate_weight = positive("control_rate_weight", control_rate_weight, allow_zero=True)
        self.replay_tol = None if replay_tol is None else positive("replay_tol", replay_tol)
        self.transcription = None  # the NLP (lcp.ocp.transcription), built on the first solve, then reused
        # IPOPT solvers per (method, options), reused across solves of this problem
        self.nlp_solvers = {}

    @property
    def B(self):
        """The control matrix B(t, q) of the system (CasADi SX, n x nu)."""
        return self.system.control_matrix_expr

    @property
    def build_time(self) -> float:
        return 0.0 if self.transcription is None else self.transcription.build_time

    @staticmethod
    def make_step(k, t0, h, q0, q1, v0, v1, u0, u1, p_N, p_T) -> Step:
        """The Step handed to cost and constraint callables."""
        return Step(k, t0, t0 + h, h, q0, q1, v0, v1, u0, u1, p_N, p_T)

    def schedule(self, t, u) -> ControlSchedule:
        """The ControlSchedule of node times t and control values u under this problem's hold."""
        if self.hold == "affine":
            return AffineSchedule(t, u)
        return ControlSchedule(t, u, hold=self.hold)

    @property
    def control_rows(self) -> int:
        """Rows of the control values: N (constant hold), N + 1 (linear), 2 N (affine: start, end)."""
        return {"constant": self.N, "linear": self.N + 1, "affine": 2 * self.N}[self.hold]

    # ------------------------------------------------------------------ guesses
    def guess(self, u=0.0, T: float | None = None, solver: str = "auto") -> OCPGuess:
        """An initial guess from a simulation: the control ``u`` replayed through :func:`lcp.simulate`.

        Parameters
        ----------
        u : float, array_like or callable
            The control: a constant (nu,), values per interval/node, or a function of t.
        T : float, optional
            Horizon (the problem's T by default).
        solver : str
            One-step contact solver of the simulation.
        """
        return simulate_guess(self, u, self.T if T is None else positive("T", T), solver)

    # ------------------------------------------------------------------ solve
    def solve(self, guess=None, options: HomotopyOptions | None = None, method: str = "auto",
              shooting: bool = True, **option_kw) -> OCPResult:
        """Solve from a guess, then replay the control (:attr:`OCPResult.replay`).

        Parameters
        ----------
        guess : OCPGuess, OCPResult or None
            Initial guess; one on another grid is resampled. By default, the mid-range control's
            simulations (:func:`lcp.ocp.solve.default_starts`), or with ``method="phases"`` :meth:`phase_guess`.
        options : HomotopyOptions, optional
        method : {"auto", "homotopy", "phases"}
            ``"auto"`` (default): ``"phases"`` with free steps, a contact and no guess, else
            ``"homotopy"``. ``"homotopy"``: the Scholtes relaxation homotopy and the polishing solve
            (:mod:`lcp.ocp.complementarity`). ``"phases"``: keep the guess's phase structure (the
            mode of every step) and solve the one smooth NLP that remains, the step lengths free
            with ``steps="free"``: from the right mode sequence, the optimum of that sequence in
            tens of IPOPT iterations. If it fails, the homotopy runs instead, and ``message`` says
            so (:func:`lcp.ocp.complementarity.run_phases`).
        shooting : bool
            When the solve fails (its replay, the homotopy or IPOPT), solve again on the phases of
            the event replay of its control, each integrated exactly (:mod:`lcp.ocp.shooting`);
            kept when its replay is within ``replay_tol``, else ``message`` says what was found.
            False returns the transcription's own result.
        **option_kw
            Fields of :class:`HomotopyOptions` (instead of ``options``).

        Examples
        --------
        Minimum effort from rest to rest over 0.5 m in 1 s (continuous optimum 86.905749 N^2 s): the
        phases (stick, slide, stick) of a first pass, placed exactly by the fixed-phase solve.

        >>> import casadi as ca, lcp
        >>> from lcp.ocp import OptimalControlProblem, effort, tangential_push
        >>> sc = lcp.scenes.jean_pratt(v0=0.0)
        >>> kw = dict(control_matrix=tangential_push(sc.system), u_min=-20, u_max=20, T=1.0,
        ...           stage_cost=effort, terminal_constraints=lambda q, v: ca.vertcat(q[0] - 0.5, v[0]))
        >>> ocp = OptimalControlProblem(sc, 6, steps="free", hold="affine", **kw)
        >>> r = ocp.solve(method="phases")  # first pass: ocp.phase_guess()
        >>> r.success, round(r.cost, 6), r.homotopy[-1].iterations < 200
        (True, 86.905749, True)
        """
        return solve_defaults(self, guess, options, method, option_kw, shooting)

    def phase_guess(self, options: HomotopyOptions | None = None, hold: str = "constant") -> OCPResult:
        """The phase sequence of a first pass: this problem on uniform steps with the constant hold
        (or ``hold``), same N, costs and constraints, solved by the homotopy to a loose tolerance,
        not replayed.

        It is the default guess of ``solve(method="phases")``: uniform steps relax quickly, and
        their modes give the sequence of phases that the free-step solve then places exactly. The
        nodes pinned by ``node_times`` are nodes of its grid: uniform between them (fixed, not
        free, steps), so any pinned window works; with ``free_time`` the grid is uniform.

        Parameters
        ----------
        options : HomotopyOptions, optional
            Default: ``tol=1e-4, factor=1e-2`` (the modes, not the optimum, are wanted).
        hold : {"constant", "affine"}
            The first pass's hold (``solve()`` also tries "affine" for an affine problem).
        """
        return first_pass(self, options, hold)

    def solve_multistart(self, guesses=None, options: HomotopyOptions | None = None, rtol: float = 1e-6,
                         shooting: bool = True, **option_kw) -> OCPResult:
        """Solve from several deterministic starts; return the best, saying whether starts disagree.

        Parameters
        ----------
        guesses : sequence of (label, guess) or (label, guess, option dict), optional
            By default the simulations of u = u_min, 0 (clipped), the mid-range and u_max, each held
            constant (:meth:`guess`). An option dict overrides homotopy options for that start
            (e.g. ``{"sigma0": 1e-4}`` to stay near a guess that is already a solution).
        rtol : float
            Costs within this relative tolerance count as the same optimum.
        shooting : bool
            As for :meth:`solve`, for every start.

        Returns
        -------
        OCPResult
            The successful solve of lowest cost; ``starts`` lists every start (label, cost, status),
            ``message`` how many distinct (local) optima were reached: the best found, not proven.
        """
        return multistart(self, guesses, options, rtol, shooting, **option_kw)

def _check_node_times(self, node_times) -> dict:
    """The checked ``node_times`` of the problem ``self`` (interior nodes, positive times)."""
    if node_times is None:
        return {}
    if not isinstance(node_times, dict):
        raise ValueError("node_times must be a dict {node index: time}")
    out = {}
    for k, t in node_times.items():
        if not isinstance(k, (int, np.integer)) or not 0 < k < self.N:
            raise ValueError(f"node_times keys must be interior node indices in (0, {self.N}), got {k!r}")
        out[int(k)] = positive(f"node_times[{k}]", t)
        if self.steps == "uniform" and not self.free_time and abs(out[k] - k * self.T / self.N) > 1e-12 * self.T:
            raise ValueError(f"node_times[{k}] = {t!r} is not node {k} of the uniform grid; use steps='free'")
    return out


def _refuse_unmodelled(system) -> None:
    """The transcription writes each contact's law with H and g of q only, and moves q by v: a gap or
    tangent that moves with time (dg/dt, ds/dt), or kinematics qdot = T(q) v, would be ignored,
    silently. Refused by name instead."""
    refuse_kinematics(system, "the optimal-control transcription")
    name = moving_contact(system)
    if name is not None:
        raise ValueError(f"contact {name!r} has a time-dependent gap or tangent, which the optimal-control "
                         "transcription does not model; simulate it with method='moreau-jean'")


def _integrator(system, q0, integrator, stages, contact_law) -> tuple[str, int, str]:
    """(integrator, stages, contact law), or ValueError naming what Radau collocation does not model."""
    if integrator not in ("theta", "radau"):
        raise ValueError(f"integrator must be 'theta' or 'radau', got {integrator!r}")
    if not isinstance(stages, (int, np.integer)) or isinstance(stages, bool) or not 1 <= stages <= 4:
        raise ValueError(f"stages must be an integer in 1..4, got {stages!r}")
    if integrator == "theta":
        return integrator, int(stages), _contact_law(system, q0, contact_law)
    for what, bad in (("bilateral constraints", system.n_bilateral), ("spatial contacts", system.is_spatial),
                      ("restitution", system.n_contacts and np.any(system.e > 0))):
        if bad:
            raise ValueError(f"integrator='radau' does not support {what} yet")
    law = _contact_law(system, q0, "auto" if contact_law is None else contact_law)
    if law == "gap":
        raise ValueError("integrator='radau' supports the velocity law only (contacts that start closed) yet, "
                         f"got contact_law={contact_law!r} with the gaps {system.gaps(q0)!r}; use integrator='theta'")
    return integrator, int(stages), law


def _contact_law(system, q0, contact_law: str) -> str:
    """The transcription's contact law: "auto" is the gap law when a contact starts open; None (the
    default) the gap law, or the velocity law for spatial contacts (lcp.ocp.spatial models no other)."""
    if contact_law is None:
        return "velocity" if getattr(system, "is_spatial", False) else "gap"
    if contact_law not in ("auto", "gap", "velocity"):
        raise ValueError(f"contact_law must be 'auto', 'gap' or 'velocity', got {contact_law!r}")
    if contact_law == "auto":
        gaps = system.gaps(q0) if system.n_contacts else np.zeros(0)
        return "gap" if np.any(gaps > 1e-12 * max(1.0, float(np.max(np.abs(q0), initial=0.0)))) else "velocity"
    return contact_law


def _grid(system, theta: float, hold: str, steps: str, step_bounds,
          indexed: bool = False) -> tuple[str, str, tuple[float, float], bool]:
    """The checked control hold, step kind and step-length bounds of the transcription, "auto"
    resolved: free steps for planar contacts unless the user's step terms are indexed by k
    (``indexed``), and with free steps the affine hold where the transcription models it; and
    whether "auto" chose free steps."""
    chose_free = steps == "auto" and bool(system.n_contacts) and not system.is_spatial and not indexed
    if steps == "auto":
        steps = "free" if chose_free else "uniform"
    if hold == "auto":
        affine = steps == "free" and theta == 0.5 and not system.n_bilateral and not system.is_spatial
        hold = "affine" if affine else "constant"
    if hold not in OCP_HOLDS:
        raise ValueError(f"hold must be one of {OCP_HOLDS}, got {hold!r}")
    if hold == "affine" and theta != 0.5:
        raise ValueError(f"theta must be 1/2 with hold='affine' (its position update is the corrected "
                         f"trapezoid), got {theta!r}")
    if hold == "affine" and system.n_bilateral:
        raise ValueError("hold='affine' does not support bilateral constraints (their force rates are not "
                         "modelled)")
    if steps not in ("uniform", "free"):
        raise ValueError(f"steps must be 'uniform' or 'free', got {steps!r}")
    bounds = _pair("step_bounds", step_bounds)
    if not bounds[0] <= 1.0 <= bounds[1]:
        raise ValueError(f"step_bounds must contain 1 (the uniform step), got {step_bounds!r}")
    return hold, steps, bounds, chose_free


def step_indexed(system, N: int, nu: int, callables) -> bool:
    """Whether a user's step callable (cost, constraint, pair member) takes another value at some
    step index k than at k = 0, all else equal: the callable then reads the grid by its index (a
    window ``8 <= s.k < 12``, a reference sampled per step), which free steps would move in time
    unless ``node_times`` pins it. Evaluated at one generic point (fixed pseudo-random values)."""
    fns = [f for f in callables if f is not None]
    if not fns or N < 2:
        return False
    n, m = system.n, system.n_contacts
    sym = [ca.SX.sym(nm, d) for nm, d in (("t0", 1), ("h", 1), ("q0", n), ("q1", n), ("v0", n), ("v1", n),
                                          ("u0", nu), ("u1", nu), ("pN", m), ("pT", m))]
    t0, h = sym[0], sym[1]
    sizes = [s.shape[0] for s in sym]
    point = np.split(np.random.default_rng(7).uniform(0.1, 0.9, sum(sizes)), np.cumsum(sizes)[:-1])
    for fn in fns:
        first = None
        for k in range(N):
            out = ca.SX(fn(Step(k, t0, t0 + h, h, *sym[2:])))
            val = (out.shape, np.array(ca.Function("probe", sym, [out])(*point)) if out.numel() else np.zeros(0))
            if first is None:
                first = val
            elif val[0] != first[0] or not np.allclose(val[1], first[1], rtol=1e-13, atol=0.0, equal_nan=True):
                return True
    return False


def _pair(name, value) -> tuple[float, float]:
    try:
        lo, hi = (float(x) for x in value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a pair of numbers, got {value!r}") from exc
    if not (0 < lo <= hi) or np.isnan(hi):
        raise ValueError(f"{name} must satisfy 0 < lower <= upper, got {value!r}")
    return lo, hi
