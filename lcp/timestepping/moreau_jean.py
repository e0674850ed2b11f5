"""Moreau-Jean time stepping (the theta-method with impulses): the options and the choice of path.

Holds :class:`MoreauJeanOptions`, :func:`moreau_jean` (validates, builds the step's assembly and
chooses the path once: compiled closed-form single-contact step, compiled many-contact loop, compiled
loop of independent spatial contacts, or the Python loop) and :func:`moreau_jean_from_model` (the compiled single-contact step from a scene's
numbers alone). The route of a call is written down in docs/architecture.md ("The Moreau-Jean
route"). Imports the modules of :mod:`lcp.timestepping`, :mod:`lcp.contact` and :mod:`lcp.result`;
never the event method, scenes, sweeps, optimal control or :mod:`lcp.simulation`.

Per step of size h:

    W_h (v+ - v-) = h F_theta + G' lambda + H' p,   G v+ + phi_t = 0,
    q+ = q- + h ((1 - theta) v- + theta v+),

with the iteration matrix W_h = A + h theta C + h^2 theta^2 K (K = -dF/dq, C = -dF/dv, so forces
that depend on the state are treated implicitly), and p the contact impulses of the active
contacts, which solve the discrete Coulomb problem :class:`~lcp.contact.problem.ContactProblem`.
Which contacts take part in a step: :mod:`lcp.timestepping.activation`; what counts as an impact:
:mod:`lcp.timestepping.outcome`. A system with Newton-Euler kinematics (qdot = T(q) v) moves its
positions by q+ = q- + h T(q-) v_theta, unit quaternions by the exact exponential map
(:func:`lcp.model.kinematics.advance_positions`), in the Python loop or, with ``fast``, the compiled
general loop (the same update, bit for bit: :mod:`lcp.timestepping.general_loop`).

Position projection
-------------------
Where a constraint is nonlinear in q (or rheonomic), the velocity-level scheme drifts off it by
O(h) over a fixed time; ``projection="auto"`` (the default) then corrects the positions after each
step (:mod:`lcp.timestepping.projection`). Constant systems never pay for it; the compiled paths
run only where there is none.
"""
from __future__ import annotations

import weakref

from dataclasses import dataclass

import numpy as np

from lcp.model.conditioning import MOREAU_JEAN_LIMIT, mass_condition, reduced_condition, resolvable
from lcp.model.kinematics import refuse_kinematics
from lcp.model.start import consistent_start
from lcp.timestepping import compiled_step as compiled
from lcp.timestepping.activation import CLOSE_ULPS, OPEN_ULPS
from lcp.timestepping.assembly import SPARSE_MIN_CONTACT_ROWS, StepAssembly
from lcp.timestepping.outcome import compiled_step_result
from lcp.timestepping.projection import PositionProjection, needs_projection
from lcp.timestepping.python_loop import run_python_loop
from lcp.timestepping.second_order import SCHEMES, run_second_order
from lcp.result import SimulationResult, flag_unresolvable
from lcp.contact.solvers import SOLVERS, OneStepSolver, make_solver

__all__ = ["CLOSE_ULPS", "OPEN_ULPS", "MoreauJeanOptions", "moreau_jean", "moreau_jean_from_model"]


@dataclass(frozen=True)
class MoreauJeanOptions:
    """Validated options of the Moreau-Jean scheme.

    Parameters
    ----------
    h : float
        Step size, > 0.
    theta : float
        Theta of the theta-method, in [1/2, 1].
    solver : str
        One-step solver name (``"auto"``, ``"enum"``, ``"lemke"``, ``"osqp"``).
    solver_options : dict, optional
        Keyword arguments for the solver.
    fallback : bool
        When the chosen one-step solver fails on a step, retry that step with an exact one
        (enumeration for one contact, Lemke otherwise); every such step is counted in
        ``stats.fallbacks`` and named in the message. With False the run stops at the failure.
    save_every : int
        Keep every ``save_every``-th state (and the impulses of the step that reached it), so that
        long runs do not store what nobody asked for.
    fast : bool
        Use the compiled path (:mod:`lcp.timestepping.compiled_step`) when it applies: a constant system with one
        contact and the closed-form solver (``"auto"`` or ``"enum"``). Same results, no Python
        per step. A system that is not constant runs the compiled general loop
        (:mod:`lcp.timestepping.general_loop`: CasADi's C code of the step, a numba loop) where no
        moving contact is projected and a C compiler is found, with or without a control schedule
        (B(t) or B(t, q)); a control schedule on a constant drift with a constant B runs the
        constant compiled loop (:mod:`lcp.timestepping.compiled_loop`, with or without contacts), any
        other schedule on constant matrices (a drift F(t), a B(t), spatial contacts) the compiled
        general loop, to rounding. Where a
        control schedule keeps the Python loop, the message says why; a run of fewer than 50,000 steps (at most one
        contact) takes the Python loop while the general loop's numba kernel is not compiled on the
        machine yet, and has it compiled in the background (short runs also while it is not loaded,
        up to 3,000 steps per process: :mod:`lcp.timestepping.first_compile`; ``LCP_COMPILE=always``
        runs it now).
    projection : {"auto", True, False}
        Project the positions onto the constraints after each step (:mod:`lcp.timestepping.projection`).
        ``"auto"``: only where a constraint is nonlinear in q or time-dependent (where the
        velocity-level scheme drifts); True: always (if there are constraints or contacts);
        False: never.
    projection_tol : float
        Relative tolerance of the projection, in [1e-15, 1) (see :mod:`lcp.timestepping.projection`).
    scheme : {"moreau-jean", "order2"}
        ``"moreau-jean"`` (the default): every step by the theta-method. ``"order2"``: the steps
        without an active contact by RATTLE, of order two on smooth constrained motion, and the
        steps whose contacts stay closed by RATTLE with those contacts as constraints (where the
        system's mass matrix or contact rows depend on q); impacts, stick-slip transitions and
        closing contacts by the same Moreau-Jean step (:mod:`lcp.timestepping.second_order`);
        Python loop only. The result says which: ``result.scheme``.
    """

    h: float
    theta: float = 0.5
    solver: str = "auto"
    solver_options: dict | None = None
    fallback: bool = True
    save_every: int = 1
    fast: bool = True
    projection: bool | str = "auto"
    projection_tol: float = 1e-12
    scheme: str = "moreau-jean"

    def __post_init__(self):
        h = self.h
        if not isinstance(h, (int, float, np.floating)) or not np.isfinite(h) or h <= 0:
            raise ValueError(f"h must be finite and > 0, got {h!r}")
        th = self.theta
        if not isinstance(th, (int, float, np.floating)) or not np.isfinite(th) or not 0.5 <= th <= 1.0:
            raise ValueError(f"theta must lie in [1/2, 1], got {th!r}")
        if not isinstance(self.save_every, (int, np.integer)) or self.save_every < 1:
            raise ValueError(f"save_every must be an integer >= 1, got {self.save_every!r}")
        if isinstance(self.solver, str) and self.solver not in SOLVERS and self.solver not in _cone_solvers():
            raise ValueError(f"unknown solver {self.solver!r}; known solvers: {sorted(SOLVERS)} (planar contacts), "
                             f"{sorted(_cone_solvers())} (spatial contacts)")
        if not isinstance(self.solver, (str, OneStepSolver)):
            raise ValueError(f"solver must be a solver name or a OneStepSolver, got {self.solver!r}")
        if self.solver_options is not None and not isinstance(self.solver_options, dict):
            raise ValueError(f"solver_options must be a dict, got {self.solver_options!r}")
        for name in ("fallback", "fast"):  # "no" is truthy: only a real bool says what the user meant
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"{name} must be True or False, got {getattr(self, name)!r}")
        if not (self.projection is True or self.projection is False or self.projection == "auto"):
            raise ValueError(f"projection must be True, False or 'auto', got {self.projection!r}")
        tol = self.projection_tol
        if not isinstance(tol, (int, float, np.floating)) or not 1e-15 <= tol < 1:
            raise ValueError(f"projection_tol must lie in [1e-15, 1), got {tol!r}")
        if not isinstance(self.scheme, str) or self.scheme not in SCHEMES:
            raise ValueError(f"scheme must be one of {list(SCHEMES)}, got {self.scheme!r}")


def _cone_solvers() -> dict:
    """The registry of the spatial (Coulomb disk) one-step solvers, imported when first needed."""
    from lcp.contact.spatial_solvers import CONE_SOLVERS

    return CONE_SOLVERS


def _spatial_solver(options):
    """The disk-law solver of a system with spatial contacts (ValueError for a planar-only name)."""
    from lcp.contact.spatial_solvers import ConeSolver, make_cone_solver

    name = options.solver
    if isinstance(name, str) and name not in _cone_solvers():
        raise ValueError(f"solver {name!r} handles planar contacts only; the system has spatial contacts: "
                         f"use one of {sorted(_cone_solvers())}")
    if not isinstance(name, (str, ConeSolver)):
        raise ValueError(f"solver {getattr(name, 'name', name)!r} handles planar contacts only; the system "
                         f"has spatial contacts: use one of {sorted(_cone_solvers())}")
    return make_cone_solver(name, **(options.solver_options or {}))


def _projector(system, options):
    """The position projection of this run, or None (see MoreauJeanOptions.projection)."""
    if options.projection is False or system.n_bilateral + system.n_contacts == 0:
        return None
    # constant kinematics: every constraint and gap is affine in q, which is exactly when
    # needs_projection says no (decided here without its symbolic Jacobians)
    if options.projection == "auto" and (system.kinematics_is_constant or not needs_projection(system)):
        return None
    return PositionProjection(system, options.projection_tol)


def moreau_jean(system, q0, v0, t_end: float, options: MoreauJeanOptions) -> SimulationResult:
    """Integrate with Moreau-Jean time stepping; see :func:`lcp.simulate` for the public entry point.

    Validates, builds the step's assembly, and chooses the path once, here: the compiled closed-form
    single-contact step, the compiled many-contact loop, or the Python loop (docs/architecture.md,
    "The Moreau-Jean route").
    """
    if not (isinstance(t_end, (int, float, np.floating)) and np.isfinite(t_end) and t_end > 0):
        raise ValueError(f"t_end must be finite and > 0, got {t_end!r}")
    try:
        asm = _early_assembly(system, options)
    except ValueError:
        system.check_state(q0, v0)  # a bad state or mass matrix is named by its own check first
        raise
    q0, v0 = system.check_state(q0, v0, mass_nonzeros=getattr(asm, "mass_nonzeros", None))
    # the constant assembly's contact rows are the start check's (one evaluation, not two)
    rows = None if asm is None else (asm.H[:system.n_contacts], asm.gap0)
    q0, v0, note = consistent_start(system, q0, v0, rows=rows)  # ValueError beyond the start tolerance
    result = flag_unresolvable(_run(system, q0, v0, t_end, options, asm),
                               resolvable(mass_condition(system, q0), MOREAU_JEAN_LIMIT))
    if note is not None:
        result.message = f"{result.message} {note}"
    return result


def _assembly(system, options) -> StepAssembly:
    """The step's :class:`StepAssembly` (ValueError for a singular iteration matrix)."""
    try:
        return StepAssembly(system, float(options.h), float(options.theta))
    except FloatingPointError as exc:
        raise ValueError(str(exc)) from exc


def _early_assembly(system, options) -> StepAssembly | None:
    """The assembly built before the start check where it is dense and constant with contacts and
    no bilateral constraint (its H and g(0) serve the check), else None (built later, in
    :func:`_run`)."""
    if (system.n_contacts and not system.n_bilateral and system.mass_is_constant
            and system.kinematics_is_constant and system.force_is_affine
            and system.n_contact_rows < SPARSE_MIN_CONTACT_ROWS and not getattr(system, "is_controlled", False)):
        return _assembly(system, options)
    return None


def _run(system, q0, v0, t_end: float, options: MoreauJeanOptions, asm=None) -> SimulationResult:
    """The body of :func:`moreau_jean` from a checked, consistent start (``asm``: the step's
    assembly where :func:`_early_assembly` built it)."""
    h, th = float(options.h), float(options.theta)
    spatial = system.is_spatial
    solver = _spatial_solver(options) if spatial else make_solver(options.solver, **(options.solver_options or {}))
    n_steps = _n_steps(t_end, h)
    every = int(options.save_every)
    if asm is None:
        asm = _assembly(system, options)
    proj = _projector(system, options)
    if options.scheme == "order2":
        refuse_kinematics(system, "scheme='order2'")
        if system.contacts_depend_on_t:
            from lcp.model.system import moving_contact

            raise ValueError(f"contact {moving_contact(system)!r} has a time-dependent gap or tangent: "
                             "scheme='order2' does not support it; use scheme='moreau-jean'")
        return run_second_order(system, asm, q0, v0, h, th, n_steps, every, solver, options.fallback, proj,
                                float(options.projection_tol))
    # the path, chosen once: the compiled paths only where nothing needs Python per step
    if (options.fast and proj is None and solver.name in ("auto", "enum") and asm.schedule is None
            and compiled.applicable(system)):
        return run_compiled_step(asm, q0, v0, n_steps, every, solver.name)
    if options.fast and proj is None and spatial and system.is_constant:
        from lcp.timestepping import compiled_spatial  # independent spatial contacts (numba)

        if compiled_spatial.applicable(asm, solver, options):
            return compiled_spatial.moreau_jean_spatial(asm, q0, v0, n_steps, every, solver, options.fallback)
    controlled = getattr(asm, "control_matrix", None) is not None  # a control on a constant drift, constant B
    if options.fast and proj is None and not spatial and (
            system.is_constant or controlled):
        # imported here: numba loads only where the compiled loop may run
        from lcp.timestepping import compiled_loop

        if compiled_loop.applicable(asm, solver, options):
            return compiled_loop.moreau_jean_loop(asm, q0, v0, n_steps, every, solver, options.fallback)
    note = ""
    if options.fast and (not system.is_constant or spatial):
        # the compiled general loop: generated C step data, a numba loop (lcp.timestepping.general_loop);
        # also constant spatial systems that compiled_spatial does not take (coupled contacts, other solvers)
        from lcp.timestepping import general_loop

        why = general_loop.applicable(system, asm, proj)
        if why is None:
            from lcp.timestepping.first_compile import deferred

            # a short run does not wait for the kernel's first compilation (lcp.timestepping.first_compile),
            # where the Python loop gives the same bits (one contact at most)
            note = deferred(n_steps, exact=system.n_contacts <= 1) or ""
            why = "cold" if note else None
        if why is None:
            from lcp.timestepping.codegen import kinematics_library, projection_library, step_library

            lib = step_library(system)  # None (with a RuntimeWarning) without a C compiler
            plib = None if lib is None or proj is None else projection_library(system, proj)
            kin = getattr(system, "has_kinematics", False)
            klib = kinematics_library(system) if lib is not None and kin else None
            if lib is not None and (proj is None or plib is not None) and (klib is not None or not kin):
                return general_loop.run_general_loop(system, asm, lib, q0, v0, h, th, n_steps, every, solver,
                                                     options.fallback, proj, plib, klib)
        elif why == "projection":
            note = general_loop.PROJECTION_NOTE
        elif why == "large":
            note = general_loop.LARGE_NOTE.format(general_loop.CONSTANT_MATRICES_MAX_N)
        elif why == "control" and asm.schedule is not None:
            note = _control_note(asm, spatial)
    elif options.fast and asm.schedule is not None:  # a control constant in time: a constant system
        note = _control_note(asm, spatial)
    result = run_python_loop(system, asm, q0, v0, h, th, n_steps, every, solver, options.fallback, proj)
    if note:
        result.message += note
    return result


def _control_note(asm, spatial) -> str:
    """Why a scheduled control on a system with constant matrices keeps the Python loop (appended
    to the message of a ``fast`` run)."""
    if asm.control_matrix is None:
        why = ("a control schedule on constant matrices runs compiled only where the drift F0 is constant "
               "and B does not depend on t or q")
    elif spatial:
        why = "the compiled loops do not take a control schedule constant in time on spatial contacts"
    else:
        why = ("the compiled loop of a controlled constant system needs the solver 'auto' or 'nsgs' without "
               "error_tol, and no projection")
    return f" (Python loop: {why})"


def _n_steps(t_end, h) -> int:
    """The number of steps of size h to reach t_end (ValueError past two billion)."""
    n_steps = int(np.ceil(t_end / h * (1 - 1e-12)))
    if n_steps > 2_000_000_000:
        raise ValueError(f"h = {h!r} needs {n_steps} steps to reach t_end = {t_end!r}: too many")
    return n_steps


def model_path_applies(model, options: MoreauJeanOptions) -> bool:
    """Whether :func:`moreau_jean_from_model` serves a run: the compiled single-contact step
    (``fast``, the closed-form solver by name without options, one contact, no bilateral
    constraint, no projection asked for)."""
    return bool(options.fast and options.scheme == "moreau-jean" and options.solver in ("auto", "enum")
                and not options.solver_options
                and model.m == 1 and not model.nb and options.projection in ("auto", False))


def moreau_jean_from_model(model, q0, v0, t_end: float, options: MoreauJeanOptions) -> SimulationResult | None:
    """The compiled single-contact step run from a :class:`~lcp.timestepping.constant_model.ConstantModel`: the
    numbers go straight into the compiled kernel (keyed by the number of coordinates only), so a
    new parameter set costs no CasADi work. Same result as :func:`moreau_jean` on the System.

    None where :func:`model_path_applies` does not hold (the caller then builds the System and
    calls :func:`moreau_jean`)."""
    if not model_path_applies(model, options):
        return None
    from lcp.timestepping.constant_model import NumericAssembly

    h, th = float(options.h), float(options.theta)
    n_steps = _n_steps(t_end, h)
    solver = options.solver if isinstance(options.solver, str) else options.solver.name
    res = run_compiled_step(NumericAssembly(model, h, th), q0, v0, n_steps, int(options.save_every), solver,
                            contact_name=model.contact_names[0], violation=lambda Q, t: model.violation(Q))
    return flag_unresolvable(res, resolvable(model_condition(model), MOREAU_JEAN_LIMIT))


#: constant model -> the condition number of its mass matrix (a sweep's parameter sets build new models)
_MODEL_CONDITION = weakref.WeakKeyDictionary()


def model_condition(model) -> float:
    """:func:`lcp.model.conditioning.reduced_condition` of a constant model, kept per model."""
    kappa = _MODEL_CONDITION.get(model)
    if kappa is None:
        kappa = _MODEL_CONDITION[model] = reduced_condition(model.A, model.G)
    return kappa


def run_compiled_step(asm, q0, v0, n_steps, every, solver_name, contact_name=None, violation=None) -> SimulationResult:
    """The compiled closed-form single-contact path (:mod:`lcp.timestepping.compiled_step`); same result
    contract as the Python loop."""
    raw = compiled.simulate_compiled(asm, q0, v0, n_steps, every)
    return compiled_step_result(asm, raw, every, solver_name, contact_name, violation)
