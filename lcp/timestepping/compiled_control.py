"""A scheduled control whose matrix B(t, q) depends on q, in the compiled general loop.

The Python loop (:meth:`StepAssembly._control_correction <lcp.timestepping.assembly.StepAssembly>`)
replaces the theta-weighted control force of the step Function by the control's exact impulse:

    c = B(t, q) int_t^{t+h} u ds - h ((1 - theta) B(t, q) u(t) + theta B(t, q) u(t + h)),

added as S c to the free velocity. Where B does not depend on q every c_k is known before the run
(:func:`lcp.timestepping.general_loop` computes them); where it does, c_k needs the step's q. This
module holds what the compiled general loop needs then: :func:`control_function` (t, q, h) -> (B(t,
q), B u(t), B u(t + h)) of the very Functions the Python loop evaluates (``control_matrix_fn``,
``control_force_fn``), :func:`control_library` (it compiled to C, :mod:`lcp.timestepping.codegen`) and
:func:`step_impulses` (int u ds over every step, the Python loop's elementwise arithmetic on all
steps at once); the kernel's piece, c_k from the compiled function's results, is
:func:`lcp.timestepping.control_kernels.control_vector`.

Imports CasADi, NumPy and the code generator; never the kernels, the loops, the path choice or
anything above :mod:`lcp.timestepping`.
"""
from __future__ import annotations

import weakref

import casadi as ca
import numpy as np

from lcp.timestepping.codegen import CompiledFunction, compile_function

__all__ = ["control_function", "control_library", "depends_on_q", "step_impulses"]

#: system -> its control's CompiledFunction (weak keys: the library lives with its System)
_LIBRARIES = weakref.WeakKeyDictionary()


def depends_on_q(system) -> bool:
    """Whether a scheduled system's control matrix B(t, q) depends on q."""
    fn = getattr(system, "control_matrix_fn", None)
    return fn is not None and fn.sparsity_jac(1, 0).nnz() > 0


def control_function(system) -> ca.Function:
    """``(t, q, h) -> (B, f0, f1)``: B(t, q) (n x nu, dense, column-major), the control forces
    B(t, q) u(t) and B(t, q) u(t + h) of a scheduled system (``with_control``)."""
    n_q = system.control_matrix_fn.size1_in(1)
    t, h, q = ca.MX.sym("t"), ca.MX.sym("h"), ca.MX.sym("q", n_q)
    B = system.control_matrix_fn(t, q)
    cf = system.control_force_fn
    return ca.Function("lcp_control", [t, q, h], [ca.densify(B), ca.densify(cf(t, q)), ca.densify(cf(t + h, q))],
                       ["t", "q", "h"], ["B", "f0", "f1"])


def control_library(system) -> CompiledFunction | None:
    """:func:`control_function` of ``system`` compiled and loaded (once per system; once per
    machine and structure in the compiled-code cache), or None without a C compiler (with a
    :class:`RuntimeWarning`)."""
    found = _LIBRARIES.get(system)
    if found is None:
        found = compile_function(control_function(system), stacklevel=4)
        if found is not None:
            _LIBRARIES[system] = found
    return found


def step_impulses(schedule, h: float, n_steps: int) -> np.ndarray:
    """int_{t_k}^{t_k + h} u ds for t_k = k h, k < n_steps, shape (n_steps, nu): the schedule's
    ``impulse(t, t + h)`` (integral(t + h) - integral(t)), elementwise on all steps at once."""
    t = np.arange(n_steps) * h
    return np.ascontiguousarray(schedule.integral(t + h) - schedule.integral(t), dtype=float)
