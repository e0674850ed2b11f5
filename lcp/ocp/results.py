"""What an optimal control solve returns: the steps, the guess, the homotopy record and the result."""
from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from lcp.model.control import ControlSchedule
from lcp.result import StepImpulses

__all__ = ["HomotopyStage", "OCPGuess", "OCPResult", "ReplayCheck", "ReplayResult", "Step", "effort"]


@dataclass
class Step:
    """One transcription step, as given to the user's cost and constraint callables.

    Every attribute is a CasADi expression (numbers where a replay evaluates a constraint).

    Attributes
    ----------
    k : int
        Step index, 0..N-1.
    t0, t1, h : casadi.SX
        Start and end time, and step size.
    q0, q1, v0, v1 : casadi.SX, shape (n, 1)
        State at the start and at the end of the step.
    u0, u1 : casadi.SX, shape (nu, 1)
        Control at the start and at the end of the step: equal for the piecewise-constant hold,
        linear in between for the linear hold.
    p_N, p_T : casadi.SX, shape (m, 1)
        Contact impulses over the step.
    N : casadi.SX, shape (m, 1)
        Mean normal force over the step, p_N / h.
    f : casadi.SX, shape (m, 1)
        Mean friction force over the step, p_T / h.
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
    """Mean of |u|^2 over a step: (u0^2 + u0 u1 + u1^2) / 3 summed (u0^2 for a constant hold).

    Use as ``stage_cost=effort`` for the exact integral of |u|^2 dt under either hold.
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
        Largest complementarity product a w over all pairs (cross pairs included).
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
    u : ndarray, shape (N, nu) (constant hold) or (N + 1, nu) (linear hold)
    p_N, p_T : ndarray, shape (N, m)
    source : str
    steps : ndarray, shape (N,), optional
        Step lengths (uniform T / N when omitted).
    """

    T: float
    q: np.ndarray
    v: np.ndarray
    u: np.ndarray
    p_N: np.ndarray
    p_T: np.ndarray
    source: str = "user"
    steps: np.ndarray | None = None


@dataclass
class ReplayCheck:
    """How well the solution's control, replayed open loop, reproduces the optimizer's trajectory.

    Attributes
    ----------
    method : str
        ``"event"``: the event-driven integrator over the control's schedule (its breakpoints
        end phases; exact for piecewise-polynomial phases), or
        ``"moreau-jean h=..."``: Moreau-Jean at a fine step (when the event replay is unavailable).
    final_miss : float
        max |state_opt(T) - state_replay(T)| over q and v.
    node_miss : float
        The same, maximum over all nodes.
    path_violation : float
        Largest path-constraint value (<= 0 wanted) or path-equality magnitude on the replayed
        states at the nodes (0 without either).
    tol : float
        The tolerance ``success`` requires of ``final_miss`` and ``path_violation``.
    where : str
        Where the replay leaves the optimizer's trajectory: the first node whose position misses by
        more than ``tol``, the node of the largest miss, and the contacts whose mode differs in the
        step before that first node ("" when every node is within ``tol``).
    amplification : float
        Where the event replay misses: how far its final state moves per unit change of the start
        state (:func:`lcp.ocp.replay.amplification`); nan otherwise.
    integration_error : float
        The event integrator's error in the final state, estimated by a second replay at a looser
        tolerance (their difference; nan where not estimated). ``ok`` counts it with the miss.
    """

    method: str
    final_miss: float
    node_miss: float
    path_violation: float
    tol: float
    where: str = ""
    #: the event replay's per-interval results (None for a Moreau-Jean replay): their phases give
    #: the exact-phase shooting its phase sequence (:mod:`lcp.ocp.shooting`)
    pieces: list | None = field(default=None, repr=False, compare=False)
    amplification: float = float("nan")
    integration_error: float = float("nan")

    @property
    def ok(self) -> bool:
        err = self.integration_error if np.isfinite(self.integration_error) else 0.0
        return bool(self.final_miss + err <= self.tol and self.path_violation <= self.tol)


@dataclass
class OCPResult(StepImpulses):
    """The solution of an :class:`OptimalControlProblem`.

    Attributes
    ----------
    t : ndarray, shape (N + 1,)
        Nodes (uniform t_k = k T / N, or placed by the optimizer with ``steps="free"``).
    q, v : ndarray, shape (N + 1, n)
        States at the nodes.
    u : ndarray, shape (N, nu) for the constant hold, (N + 1, nu) for the linear hold
        The control values (per interval, or per node).
    control : lcp.model.control.ControlSchedule
        The control as a function of time (``control(t)``, ``control.impulse(t0, t1)``,
        ``control.breakpoints``); :attr:`hold` says how it is held.
    hold : str
        ``"constant"`` or ``"linear"``.
    steps : ndarray, shape (N,)
        Step lengths.
    p_N, p_T : ndarray, shape (N, m)
        Contact impulses per step; :attr:`~lcp.ocp.results.OCPResult.N` and :attr:`~lcp.ocp.results.OCPResult.f` are the mean forces p / h.
    modes : ndarray of int8, shape (N, m)
        Contact mode per step (:data:`lcp.contact.problem.MODE_NAMES`).
    T, h : float
        Final time and (mean) step size T / N.
    cost : float
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
    replay : ReplayCheck or None
        The open-loop replay miss (None when the check was switched off, ``replay_tol=None``).
    status : int
        See :data:`OCP_STATUS_MESSAGES`; ``success = status >= 0`` (it requires the replay miss
        within ``replay.tol``).
    message : str
    homotopy : list of HomotopyStage
    iterations : int
        IPOPT iterations over all solves.
    solve_time, build_time : float
        Wall time of the solves and of building the NLP (s).
    starts : list of dict
        With :meth:`OptimalControlProblem.solve_multistart`: one entry per start (label, cost,
        success); empty otherwise.
    problem : OptimalControlProblem
    """

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    u: np.ndarray
    control: ControlSchedule
    hold: str
    steps: np.ndarray
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
    replay: ReplayCheck | None = None
    starts: list = field(default_factory=list)
    problem: object = field(repr=False, default=None)

    @property
    def N(self) -> np.ndarray:
        """Mean normal force over each step, p_N / h_k, shape (N, m)."""
        return self.p_N / self.steps[:, None]

    @property
    def f(self) -> np.ndarray:
        """Mean friction force over each step, p_T / h_k, shape (N, m)."""
        return self.p_T / self.steps[:, None]

    @property
    def homotopy_steps(self) -> int:
        """Relaxation stages solved (the polishing solve not counted)."""
        return sum(1 for s in self.homotopy if s.sigma > 0)

    def __repr__(self) -> str:
        miss = f"{self.replay.final_miss:.1e} ({self.replay.method})" if self.replay is not None else "n/a"
        return (f"OCPResult(N={len(self.t) - 1}, hold={self.hold!r}, T={self.T:.6g}, cost={self.cost:.6g}, "
                f"residual={self.complementarity_residual:.2e}, replay_miss={miss}, "
                f"iterations={self.iterations}, status={self.status}, message={self.message!r})")


@dataclass
class ReplayResult:
    """An open-loop replay of an optimal control through :func:`lcp.simulate`.

    Attributes
    ----------
    sim : SimulationResult or EventResult
        The replay (for the event replay, the last interval's piece; :attr:`pieces` holds them
        all).
    method : str
    h : float
        Replay step (nan for the event integrator).
    t : ndarray, shape (N + 1,)
        The optimizer's nodes.
    q, v : ndarray, shape (N + 1, n)
        The replay at those nodes.
    error_q, error_v : ndarray, shape (n,)
        max over the nodes of |q_opt - q_replay| and |v_opt - v_replay|, per coordinate.
    pieces : list
        The event replay's results per control interval (empty for Moreau-Jean).
    """

    sim: object
    method: str
    h: float
    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    error_q: np.ndarray
    error_v: np.ndarray
    pieces: list = field(default_factory=list)

    @property
    def max_error_q(self) -> float:
        return float(np.max(self.error_q))

    @property
    def max_error_v(self) -> float:
        return float(np.max(self.error_v))
