"""``lcp.simulate``: one entry point for the contact branch, with methods chosen by name."""
from __future__ import annotations

import math

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from lcp.events import event_driven
from lcp.model.conditioning import EVENT_LIMIT, mass_condition, resolvable
from lcp.result import SimulationResult, flag_unresolvable
from lcp.scenes.scene import Scene
from lcp.model.start import consistent_affine_start
from lcp.model.system import System
from lcp.timestepping.moreau_jean import MoreauJeanOptions, model_condition, moreau_jean, moreau_jean_from_model

if TYPE_CHECKING:  # annotations only: importing these here would load them with every simulate
    from lcp.events import EventResult
    from lcp.model.control import ControlSchedule

__all__ = ["METHODS", "simulate"]


#: integration methods by name
METHODS = {"moreau-jean": moreau_jean, "event": event_driven}


def simulate(scene: Scene | System, t_end: float | None = None, h: float = 1e-3, theta: float = 0.5,
             solver: str = "auto", method: str = "moreau-jean", q0: ArrayLike | None = None,
             v0: ArrayLike | None = None, solver_options: dict | None = None, fallback: bool = True,
             save_every: int = 1, fast: bool = True, allow_large_step: bool = False,
             control: ControlSchedule | None = None, projection: bool | str = "auto",
             projection_tol: float = 1e-12, scheme: str = "moreau-jean",
             **method_options) -> SimulationResult | EventResult:
    """Simulate a scene (or a bare :class:`~lcp.model.system.System` with ``q0`` and ``v0``).

    Parameters
    ----------
    scene : Scene or System
    t_end : float, optional
        Horizon (> 0); the scene's default when omitted.
    h : float
        Step size (> 0). Steps are uniform; the last time is the first multiple of h >= t_end.
    theta : float
        Theta of the Moreau-Jean theta-method, in [1/2, 1]. 1/2 is exact while a block slides
        under constant forces (docs/numerical_methods.md); 1 is the first-order scheme.
    solver : {"auto", "enum", "lemke", "osqp", "nsgs", "newton"}
        One-step contact solver. ``"auto"`` picks the fastest one that meets the tolerance
        (closed-form enumeration for a single contact, NSGS with a semismooth Newton finish for
        several, Lemke retrying a failure); see :mod:`lcp.contact.solvers`.
    method : {"moreau-jean", "event"}
        Integration method: Moreau-Jean time stepping, or event-driven integration with exact
        mode switches (:mod:`lcp.events`; ``h``, ``theta`` and ``solver`` are then ignored).
    q0, v0 : array_like, optional
        Initial state (required for a bare System, overriding the scene's otherwise).
    solver_options : dict, optional
        Keyword arguments of the solver class (e.g. ``eps_abs`` for OSQP).
    fallback : bool
        Retry a step on which the chosen solver failed with an exact one (counted in
        ``stats.fallbacks`` and named in ``message``); with False the run stops there.
    save_every : int
        Keep every ``save_every``-th state only (long runs).
    fast : bool
        Use the compiled path when it applies (constant system, one contact, ``"auto"`` or
        ``"enum"``); the results are the same.
    projection : {"auto", True, False}
        Moreau-Jean only: project the positions onto the constraints after each step
        (:mod:`lcp.timestepping.projection`); ``"auto"`` does it where a constraint is nonlinear in q.
    projection_tol : float
        Relative tolerance of that projection (and of SHAKE under ``scheme="order2"``).
    scheme : {"moreau-jean", "order2"}
        Moreau-Jean only: ``"moreau-jean"`` (the default) takes every step by the theta-method,
        of order one on smooth motion with nonlinear constraints or a q-dependent mass matrix.
        ``"order2"`` takes the steps in which no contact acts by RATTLE (velocity Verlet with
        SHAKE/RATTLE constraints: order two, no secular energy drift on conservative systems with a
        constant mass matrix), the steps in which contacts stay closed (sliding or sticking) by
        RATTLE with those contacts as constraints, checked after the step (lift-off, slip onset),
        and the others (impacts, stick-slip transitions, stops) by the same Moreau-Jean step
        (docs/numerical_methods.md, "The order-two scheme"); ``result.scheme`` says "order2".
        Runs in the Python loop; forces are explicit there (stable for h omega < 2).
    allow_large_step : bool
        Moreau-Jean only: accept a step h larger than the horizon (one step then overshoots
        ``t_end``). Without it such an h is taken for a mistake and raises.
    control : lcp.model.control.ControlSchedule, optional
        The control of a controlled System (``System(..., control=u)``), replayed as
        ``system.with_control(control)``; required for a controlled system.
    **method_options
        Options of the chosen method other than Moreau-Jean's (see :mod:`lcp.events`).

    Returns
    -------
    SimulationResult
        ``t`` (n_points,), ``q`` and ``v`` (n_points, n), impulses ``p_N`` and ``p_T``
        (n_points - 1, m), ``modes``, ``status``, ``message``, ``success`` and ``stats``.

    Examples
    --------
    >>> import lcp
    >>> scene = lcp.scenes.jean_pratt()
    >>> res = lcp.simulate(scene, 0.3, h=1e-3)
    >>> res.success, round(float(res.q[-1, 0]), 6), round(scene.x_stop, 6)
    (True, 0.076453, 0.076453)
    """
    model = None
    if isinstance(scene, Scene):
        q0 = scene.q0 if q0 is None else q0
        v0 = scene.v0 if v0 is None else v0
        t_end = scene.t_end if t_end is None else t_end
        # a scene that knows its numbers takes the paths that need nothing else, whether or not its
        # System was built (so that a result never depends on what was accessed before)
        model = scene.model if control is None else None
        if model is None:
            system = scene.system
    elif isinstance(scene, System):
        system = scene
        if q0 is None or v0 is None or t_end is None:
            raise ValueError("simulating a bare System needs q0, v0 and t_end")
    else:
        raise ValueError(f"scene must be a Scene or a System, got {type(scene).__name__}")
    if model is not None:
        result = _from_constant_model(model, scene, q0, v0, t_end, h, theta, solver, method, solver_options,
                                      fallback, save_every, fast, allow_large_step, projection,
                                      projection_tol, method_options, scheme)
        if result is not None:
            return result
        system = scene.system  # a path the numbers alone do not serve: the CasADi model
    if control is not None:
        if not system.is_controlled:
            raise ValueError("control given for a system without a control input")
        system = system.with_control(control)
    elif system.is_controlled:
        raise ValueError("the system has a control input u: pass control=ControlSchedule(...) "
                         "(lcp.model.control) to simulate it")
    if not isinstance(method, str) or method not in METHODS:
        raise ValueError(f"unknown method {method!r}; known methods: {sorted(METHODS)}")
    if not isinstance(t_end, (int, float, np.floating)) or not np.isfinite(t_end) or t_end <= 0:
        raise ValueError(f"t_end must be finite and > 0, got {t_end!r}")
    # options a method ignores are still validated: a typo must not pass silently
    opts = MoreauJeanOptions(h=h, theta=theta, solver=solver, solver_options=solver_options,
                             fallback=fallback, save_every=save_every, fast=fast, projection=projection,
                             projection_tol=projection_tol, scheme=scheme)
    if method == "moreau-jean":
        if h > t_end and not allow_large_step:
            raise ValueError(f"h = {h!r} is larger than the horizon t_end = {t_end!r}; pass "
                             "allow_large_step=True if one step beyond t_end is what you want")
        if method_options:
            raise ValueError(f"unknown options for method 'moreau-jean': {sorted(method_options)}")
        return moreau_jean(system, q0, v0, float(t_end), opts)
    res = METHODS[method](system, q0, v0, float(t_end), scene=scene if isinstance(scene, Scene) else None,
                          **method_options)
    if method == "event":  # Moreau-Jean flags its own runs (lcp.timestepping.moreau_jean)
        res = flag_unresolvable(res, resolvable(mass_condition(system, np.asarray(q0, dtype=float)), EVENT_LIMIT))
    return res


def _from_constant_model(model, scene, q0, v0, t_end, h, theta, solver, method, solver_options, fallback,
                         save_every, fast, allow_large_step, projection, projection_tol, method_options,
                         scheme="moreau-jean"):
    """The paths that run from a scene's :class:`~lcp.timestepping.constant_model.ConstantModel` alone (no CasADi
    work): the compiled single-contact Moreau-Jean step and the closed-form single-contact event
    path. None when neither applies (the caller then builds the System and takes the general path),
    after the same validation of the options as the general path."""
    if not isinstance(method, str) or method not in METHODS:
        raise ValueError(f"unknown method {method!r}; known methods: {sorted(METHODS)}")
    if not isinstance(t_end, (int, float, np.floating)) or not np.isfinite(t_end) or t_end <= 0:
        raise ValueError(f"t_end must be finite and > 0, got {t_end!r}")
    if method == "event" and scheme == "moreau-jean" and _plain_moreau_jean_options(
            h, theta, solver, solver_options, save_every, projection, projection_tol) \
            and isinstance(fallback, (bool, np.bool_)) and isinstance(fast, (bool, np.bool_)):
        opts = None  # valid, and unused by the event method: no need to build them
    else:
        opts = MoreauJeanOptions(h=h, theta=theta, solver=solver, solver_options=solver_options,
                                 fallback=fallback, save_every=save_every, fast=fast, projection=projection,
                                 projection_tol=projection_tol, scheme=scheme)
    q0, v0 = _check_state(model, q0, v0)
    note = None
    if not model.nb:  # with bilateral constraints no path here applies: the general path checks the start
        q0, v0, note = consistent_affine_start(model.H[:model.m], model.gap0, model.A, q0, v0, model.contact_names)
    if method == "event":
        from lcp.events.single_contact import run_with_options

        res = _noted(run_with_options(model, q0, v0, float(t_end), method_options), note)
        return flag_unresolvable(res, resolvable(model_condition(model), EVENT_LIMIT))
    if method_options:
        raise ValueError(f"unknown options for method 'moreau-jean': {sorted(method_options)}")
    if h > t_end and not allow_large_step:
        raise ValueError(f"h = {h!r} is larger than the horizon t_end = {t_end!r}; pass "
                         "allow_large_step=True if one step beyond t_end is what you want")
    return _noted(moreau_jean_from_model(model, q0, v0, float(t_end), opts), note)  # None where it does not apply


def _noted(result, note):
    """``result`` with the start's projection ``note`` (if any) at the end of its message."""
    if result is not None and note is not None:
        result.message = f"{result.message} {note}"
    return result


def _plain_moreau_jean_options(h, theta, solver, solver_options, save_every, projection, projection_tol) -> bool:
    """Whether the Moreau-Jean options are plain values that :class:`MoreauJeanOptions` accepts (a
    few comparisons; anything else, valid or not, is left to its full validation)."""
    return (type(h) is float and 0.0 < h < math.inf and type(theta) is float and 0.5 <= theta <= 1.0
            and type(solver) is str and solver == "auto" and solver_options is None and type(save_every) is int
            and save_every >= 1 and (projection is True or projection is False
                                     or (type(projection) is str and projection == "auto"))
            and type(projection_tol) is float and 1e-15 <= projection_tol < 1)


def _check_state(model, q0, v0):
    try:
        q0, v0 = np.asarray(q0, dtype=float), np.asarray(v0, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"q0 and v0 must be arrays of numbers, got {q0!r}, {v0!r}") from exc
    for name, x in (("q0", q0), ("v0", v0)):
        if x.shape != (model.n,):
            raise ValueError(f"{name} must have shape ({model.n},), got {x.shape}")
        if not all(map(math.isfinite, x.tolist())):
            raise ValueError(f"{name} must be finite, got {x}")
    return q0, v0
