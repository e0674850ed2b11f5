"""Options, counters, results and statuses of the LEM engine (:func:`lem.solve`)."""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from .jets import RADIUS_TRUST
from .validation import check_float, check_int, finite_vector

__all__ = ["STATUS_MESSAGES", "LEMOptions", "LEMResult", "LEMStats", "LEMWarning"]

#: status code -> meaning; ``success`` is ``status >= 0``.
STATUS_MESSAGES = {
    0: "Converged: the a-posteriori error estimate meets atol + rtol*|y| at every output point.",
    1: ("Successive truncations converge, but the error estimate exceeds atol + rtol*|y| at some "
        "output point: raise the degree or restart more often."),
    2: "Computed without an error estimate (check=False): the result is not verified.",
    -1: ("Successive truncations diverge, or the state leaves the disc where the Taylor series of "
         "f converges (radius_ratio >= 0.9): the result cannot be trusted; restart more often "
         "(restart=...) or shorten the interval."),
    -2: "The truncated moment system produced non-finite values (blow-up).",
    -3: "The restart step fell below min_step: the solution may have a singularity ahead.",
    -4: "The maximum number of restart segments was reached.",
    -5: "The integrator of the time-varying moment system failed.",
}


class LEMWarning(RuntimeWarning):
    """Raised (as a warning) whenever a LEM result is not to be trusted (``status < 0``)."""


@dataclass(frozen=True)
class LEMOptions:
    """Options of :func:`solve` (validated on construction).

    Attributes
    ----------
    degree : int
        Truncation degree N >= 1 of the moment system (default 20).
    restart : None, float or "auto"
        None: one expansion over the whole interval (the paper's plain LEM). A positive float h:
        re-centre on the current state every h. "auto": choose each segment from the error
        estimate (like a step-size controller).
    centre : "origin", "initial" or array
        Expansion centre of the plain (un-restarted) engine. "origin" is the paper's choice (then
        the degree-N truncation is the degree-N Taylor polynomial of the flow in the initial data).
    check : bool
        Compute the a-posteriori estimate from degrees N - 2k, N - k, N + k (default True).
    check_step : int
        k (default 2, so that odd fields such as tanh always gain a new non-zero degree).
    rtol, atol : float
        Tolerance of the trust test ``error <= atol + rtol*|y|`` (and of the auto restart).
    taylor_degree : int or None
        Degree of the Taylor polynomial of an analytic f (default: the truncation degree, beyond
        which terms cannot enter the truncated system).
    prune : bool
        Keep only the moments the outputs depend on (default True).
    max_dimension : int
        Refuse to build larger moment systems (ValueError).
    max_segments : int
        Give up (status -4) after this many restart segments.
    radius_fraction : float
        With restart="auto", a segment may carry f's singular arguments at most this fraction of
        the way to the nearest singularity of f (0 < radius_fraction < 0.9; default 0.5).
    first_step, min_step, max_step : float or None
        Segment lengths of the auto restart (defaults: 1/(1 + |Jacobian of f|), 1e-12 of the
        interval, the whole interval).
    step_hint : sequence of float or None
        With restart="auto", segment lengths to try first, one per accepted segment (e.g. the
        restart steps ``numpy.diff(res.restart_points)`` of a solve of a nearby problem, as in
        shooting): each is accepted or rejected by the same error control as the controller's own
        proposal, and after a rejection the controller takes over for that segment.
    ivp_method, ivp_rtol, ivp_atol
        ``solve_ivp`` settings for time-varying coefficients (DOP853, 1e-12, 1e-14).
    warn : bool
        Issue a :class:`LEMWarning` when the result is not to be trusted (status < 0).
    """

    degree: int = 20
    restart: object = None
    centre: object = "origin"
    check: bool = True
    check_step: int = 2
    rtol: float = 1e-10
    atol: float = 1e-12
    taylor_degree: int | None = None
    prune: bool = True
    max_dimension: int = 200_000
    max_segments: int = 10_000
    radius_fraction: float = 0.5
    first_step: float | None = None
    step_hint: tuple | None = None
    min_step: float | None = None
    max_step: float | None = None
    ivp_method: str = "DOP853"
    ivp_rtol: float = 1e-12
    ivp_atol: float = 1e-14
    warn: bool = True

    def __post_init__(self):
        check_int("degree", self.degree, 1)
        check_int("check_step", self.check_step, 1)
        check_int("max_dimension", self.max_dimension, 1)
        check_int("max_segments", self.max_segments, 1)
        if self.taylor_degree is not None:
            check_int("taylor_degree", self.taylor_degree, 1)
        r = self.restart
        if isinstance(r, str):
            if r != "auto":
                raise ValueError(f"restart must be None, a positive step or 'auto', got {r!r}")
        elif r is not None:
            check_float("restart", r, 0.0, strict=True)
        for name in ("rtol", "atol", "ivp_rtol", "ivp_atol"):
            check_float(name, getattr(self, name), 0.0)
        if self.rtol == 0 and self.atol == 0:
            raise ValueError("rtol and atol cannot both be 0")
        for name in ("first_step", "min_step", "max_step"):
            check_float(name, getattr(self, name), 0.0, strict=True, allow_none=True)
        if self.step_hint is not None:
            try:
                hint = tuple(float(v) for v in self.step_hint)
            except (TypeError, ValueError) as exc:
                raise ValueError("step_hint must be a sequence of positive segment lengths") from exc
            if not all(np.isfinite(v) and v > 0 for v in hint):
                raise ValueError(f"step_hint must hold finite positive lengths, got {self.step_hint!r}")
            object.__setattr__(self, "step_hint", hint)
        if isinstance(self.centre, str):
            if self.centre not in ("origin", "initial"):
                raise ValueError(f"centre must be 'origin', 'initial' or an array, got {self.centre!r}")
        else:
            finite_vector("centre", self.centre, allow_exact=True)
        if self.ivp_method not in ("DOP853", "RK45", "Radau", "BDF", "LSODA"):
            raise ValueError(f"ivp_method must be one of DOP853, RK45, Radau, BDF, LSODA, "
                             f"got {self.ivp_method!r}")
        check_float("radius_fraction", self.radius_fraction, 0.0, strict=True)
        if not self.radius_fraction < RADIUS_TRUST:
            raise ValueError(f"radius_fraction must be < {RADIUS_TRUST}, got {self.radius_fraction!r}")
        if self.restart == "auto" and not self.check:
            raise ValueError("restart='auto' needs check=True (segments are chosen from the estimate)")
        for name in ("check", "prune", "warn"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")

    @classmethod
    def from_kwargs(cls, **kwargs) -> LEMOptions:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(kwargs) - known)
        if unknown:
            raise ValueError(f"unknown option(s) {unknown}; known options: {sorted(known)}")
        return cls(**kwargs)


@dataclass
class LEMStats:
    """Counters of a LEM solve.

    Attributes
    ----------
    n_segments : int
        Accepted expansion segments (1 for the plain engine).
    n_rejected : int
        Segments rejected by the auto restart.
    n_systems : int
        Moment systems built (all degrees, all segments, rejected ones included).
    n_propagations : int
        Propagator calls (lem.expmv.expmv, expm_multiply, a dense exponential or solve_ivp).
    build_time, solve_time : float
        Seconds spent building moment systems (Taylor expansion + sparse assembly) and solving them.
    max_nnz : int
        Largest number of non-zeros of a degree-N moment matrix.
    taylor_degree : int
        Degree of f's Taylor polynomial used at degree N.
    time_varying : bool
        Coefficients depended on t through callables (solve_ivp path).
    time_augmented : bool
        An analytic f depended on t, which became a state variable.
    """

    n_segments: int = 0
    n_rejected: int = 0
    n_systems: int = 0
    n_propagations: int = 0
    build_time: float = 0.0
    solve_time: float = 0.0
    max_nnz: int = 0
    taylor_degree: int = 0
    time_varying: bool = False
    time_augmented: bool = False


@dataclass
class LEMResult:
    """Result of :func:`solve`, in the style of ``scipy.integrate.solve_ivp``.

    Attributes
    ----------
    t : ndarray, shape (m,)
        Output points.
    y : ndarray, shape (n_out, m)
        Degree-N LEM solution of the output components at ``t``.
    status : int
        See :data:`STATUS_MESSAGES`; ``success = status >= 0``.
    message : str
        Why the solve stopped or how far it can be trusted (names the first failing point).
    error_estimate : ndarray, shape (n_out, m)
        A-posteriori error estimate of ``y`` (differences of truncations, propagated across
        restarts with the LEM sensitivity); NaN where not computed.
    diverging_points : ndarray of bool, shape (m,)
        Points where successive truncations grow (the series diverges there).
    convergence_ratio : ndarray, shape (m,)
        Largest ratio of successive truncation differences (< 1 converging); NaN if unknown.
    sensitivity : ndarray, shape (n_out, n, m)
        d y(t) / d y0, from the same propagators (used e.g. for shooting).
    degree : int
        Truncation degree N.
    check_degrees : tuple of int
        Degrees compared for the estimate.
    moment_dimension : int
        Largest number of moments of a degree-N system.
    n_restarts : int
        Number of re-centrings (segments - 1).
    restart_points : ndarray
        Centres' times (segment starts) and the final time.
    stats : LEMStats
    radius_ratio : ndarray, shape (m,)
        How far the state has moved towards the nearest singularity of f seen from the expansion
        centre (the displacement of each singular argument of f, such as v/eps in tanh(v/eps),
        over its distance to the singularity); from :data:`RADIUS_TRUST` = 0.9 on, f's Taylor
        series no longer represents f and the point counts as diverging. 0 for polynomial and
        entire f.
    """

    t: np.ndarray
    y: np.ndarray
    status: int
    message: str
    error_estimate: np.ndarray
    diverging_points: np.ndarray
    convergence_ratio: np.ndarray
    sensitivity: np.ndarray
    degree: int
    check_degrees: tuple
    moment_dimension: int
    n_restarts: int
    restart_points: np.ndarray
    stats: LEMStats
    radius_ratio: np.ndarray | None = None

    @property
    def success(self) -> bool:
        return self.status >= 0

    @property
    def diverging(self) -> bool:
        """True when successive truncations diverge at some output point."""
        return bool(np.any(self.diverging_points))

    def __repr__(self) -> str:
        return (f"LEMResult(status={self.status}, degree={self.degree}, "
                f"moment_dimension={self.moment_dimension}, n_restarts={self.n_restarts}, "
                f"max_error_estimate={np.nanmax(self.error_estimate, initial=0.0):.3g}, "
                f"message={self.message!r})")
