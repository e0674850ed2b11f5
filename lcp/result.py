"""Result objects of ``lcp.simulate`` (one table of status codes and messages)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["flag_unresolvable", "STATUS_MESSAGES", "SolverStats", "StepImpulses", "Impact", "SimulationResult"]

#: status code -> meaning; success is ``status >= 0``.
STATUS_MESSAGES = {
    0: "The integration reached t_end.",
    -1: "The one-step contact solver failed.",
    -2: "The state became non-finite.",
    -3: "No consistent contact mode exists (Painleve inconsistency).",
    -4: "Too many events (Zeno behaviour or chattering between contact modes).",
    -5: "The position projection did not converge.",
    -6: "The motion cannot be resolved in double precision (ill-conditioned mass matrix).",
    -7: "A step was rejected: the forces vary faster than the step resolves.",
}


@dataclass
class SolverStats:
    """Counters of a simulation.

    Attributes
    ----------
    steps : int
        Time steps taken.
    free_steps : int
        Steps with no active contact (no solver call).
    solver_calls : int
        One-step contact problems solved.
    iterations : int
        Total solver iterations (pivots, fixed-point iterations, cases).
    max_iterations : int
        Most iterations in one step.
    qp_solves : int
        OSQP solves in total.
    max_residual : float
        Worst Coulomb (complementarity) residual over all steps, impulse units.
    mode_counts : dict
        Contact-steps per mode: ``open``, ``stick``, ``slide+``, ``slide-`` (active contacts only).
    ambiguous_steps : int
        Steps where the one-step problem had more than one solution.
    fallbacks : int
        Steps solved by a fallback solver after the chosen one failed.
    projections : int
        Steps whose positions were projected onto the constraints (Moreau-Jean with position
        projection, :mod:`lcp.timestepping.projection`).
    projection_iterations : int
        Newton iterations of those projections in total.
    closed_steps : int
        Steps of the order-two scheme (``scheme="order2"``) that held closed contacts as
        constraints of a RATTLE step (:mod:`lcp.timestepping.closed_rattle`).
    kernel_multi_steps : int
        Steps with several active contacts (or one under the solver ``"nsgs"``) solved inside the
        compiled general loop's kernel (:mod:`lcp.timestepping.multi_kernels`,
        :mod:`lcp.timestepping.planar_multi_kernels`), or,
        in the constant compiled loop, steps whose NSGS sweeps stopped and that the compiled Newton
        finish of :mod:`lcp.timestepping.planar_multi_kernels` solved instead of the Python solver
        (0 on every other path).
    python_steps : int
        Contact steps the compiled general loop handed to the Python loop's contact step (a solver
        or an active set its kernel does not solve, or a kernel solve that failed its test; 0 on
        every other path).
    """

    steps: int = 0
    free_steps: int = 0
    solver_calls: int = 0
    iterations: int = 0
    max_iterations: int = 0
    qp_solves: int = 0
    max_residual: float = 0.0
    mode_counts: dict = field(default_factory=lambda: {"open": 0, "stick": 0, "slide+": 0, "slide-": 0, "slide": 0})
    ambiguous_steps: int = 0
    fallbacks: int = 0
    projections: int = 0
    projection_iterations: int = 0
    closed_steps: int = 0
    kernel_multi_steps: int = 0
    python_steps: int = 0


class StepImpulses:
    """What every result with impulses ``p_N``, ``p_T`` over steps of size ``h`` and a ``status`` shares."""

    @property
    def success(self) -> bool:
        return self.status >= 0

    @property
    def N(self) -> np.ndarray:
        """Mean normal force over each step, p_N / h, shape (steps, m)."""
        return self.p_N / self.h

    @property
    def f(self) -> np.ndarray:
        """Mean tangential (friction) force over each step, p_T / h, shape (steps, m)."""
        return self.p_T / self.h


@dataclass(frozen=True)
class Impact:
    """One impact: a contact closing with approach velocity at time ``t`` (index ``contact``,
    ``name`` its name), with normal impulse ``p_N`` and tangential impulse ``p_T`` (a float for a
    planar contact, an array of its two components for a spatial one).

    Both methods list them in ``result.impacts``: Moreau-Jean the step in which an open contact
    closes with a normal impulse, the event method each impact it resolves (Newton restitution and
    Coulomb friction at the velocity level)."""

    t: float
    contact: int
    name: str
    p_N: float
    p_T: float | np.ndarray


@dataclass
class SimulationResult(StepImpulses):
    """Trajectory and diagnostics, in the style of ``scipy.integrate.solve_ivp``.

    Attributes
    ----------
    t : ndarray, shape (n_points,)
        Time grid (t[0] = 0).
    q, v : ndarray, shape (n_points, n)
        Coordinates and velocities (v is the right limit v+ at each time).
    p_N, p_T : ndarray, shape (n_points - 1, m)
        Normal and tangential contact impulses over each step (zero for inactive contacts). The
        mean contact forces over a step are ``p_N / h`` and ``p_T / h`` (:attr:`~lcp.result.StepImpulses.N`, :attr:`~lcp.result.StepImpulses.f`).
        With spatial contacts ``p_T`` has one column per tangent row, shape (n_points - 1,
        n_tangent): contact j's components are columns ``system.tangent_offsets[j]`` to
        ``system.tangent_offsets[j + 1]``.
    modes : ndarray of int8, shape (n_points - 1, m)
        Contact mode per step: -1 inactive, 0 open, 1 stick, 2 slide+, 3 slide-, 4 slide (a spatial
        contact sliding in its tangent plane; see :mod:`lcp.contact.problem`).
    status : int
        0 success; negative values are failures (:data:`STATUS_MESSAGES`).
    message : str
        Human-readable reason; on failure it names the step, the time and the cause.
    success : bool
        ``status >= 0``.
    stats : SolverStats
    method, solver : str
    scheme : str
        The time-stepping scheme of a ``"moreau-jean"`` run: ``"moreau-jean"`` (the theta-method
        throughout) or ``"order2"`` (``lcp.simulate(..., scheme="order2")``, RATTLE where the motion
        is smooth: :mod:`lcp.timestepping.second_order`); ``"event"`` for the event method.
    h, theta : float
    t_events : list
        Event times (empty for time stepping).
    impacts : list of Impact, or None
        Moreau-Jean: the steps in which a contact that carried no load in the previous step closes
        with an approach velocity larger than the free motion's velocity change over the step
        (a velocity jump, not a smooth landing); ``t`` is the estimated closing time inside the
        step. None where the steps were not all recorded (the compiled path with save_every > 1).
    max_constraint_violation : float
        Worst violation of the run, in the constraints' own units: max |phi_i(t, q)| over the
        bilateral constraints and max(0, -g_j(q)) over the contacts. With position projection it
        is taken after every step; otherwise over the saved states, computed on first access.
    """

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    p_N: np.ndarray
    p_T: np.ndarray
    modes: np.ndarray
    status: int
    message: str
    stats: SolverStats
    method: str = "moreau-jean"
    solver: str = ""
    h: float = float("nan")
    theta: float = float("nan")
    t_events: list = field(default_factory=list)
    impacts: list | None = field(default_factory=list)
    #: the worst violation, or a callable computing it on first access (see max_constraint_violation)
    violation: object = field(default=float("nan"), repr=False, compare=False)
    scheme: str = "moreau-jean"

    @property
    def max_constraint_violation(self) -> float:
        if callable(self.violation):
            self.violation = float(self.violation())
        return float(self.violation)

    def plot(self, system=None, **kwargs):
        """Draw the result against time: coordinates, velocities, contact forces and modes.

        Parameters
        ----------
        system : System, optional
            Names the coordinates and the contacts in the legends.
        **kwargs
            ``names``, ``exact``, ``fig``: see :func:`lcp.plotting.plot_result`.

        Returns
        -------
        matplotlib.figure.Figure
        """
        from lcp.plotting import plot_result

        return plot_result(self, system, **kwargs)

    def __repr__(self) -> str:
        scheme = f", scheme={self.scheme!r}" if self.scheme != self.method else ""
        return (f"SimulationResult(method={self.method!r}{scheme}, solver={self.solver!r}, h={self.h:g}, "
                f"steps={self.stats.steps}, status={self.status}, message={self.message!r})")


def flag_unresolvable(res: SimulationResult, reason: str) -> SimulationResult:
    """A run whose mass matrix is beyond double precision's reach (``lcp.model.conditioning``)
    ends with status -6 and the reason, the trajectory kept for inspection: never a silent success."""
    if reason and res.status == 0:
        res.status = -6
        res.message = f"{STATUS_MESSAGES[-6]} {reason}"
    return res
