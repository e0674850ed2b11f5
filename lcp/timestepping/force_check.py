"""Checks of a Moreau-Jean step's forces: a step across a singularity of the force is rejected,
and forces that are not finite are named as the cause.

:class:`ForceStepCheck` is called by :class:`~lcp.timestepping.assembly.StepAssembly` at the start
of each step for forces that are not affine in (q, v); :func:`nonfinite_cause` says what made a
step's data non-finite. Imports nothing of ``lcp`` (the System is passed in).
"""
from __future__ import annotations

import numpy as np

__all__ = ["ForceStepCheck", "StepRejected", "nonfinite_cause"]


class StepRejected(FloatingPointError):
    """A step whose forces varied faster than the step resolves (see :class:`ForceStepCheck`)."""


class ForceStepCheck:
    """Step acceptance for the forces of one run (the linearisation of the previous step, kept)."""

    def __init__(self, system, h: float):
        self.sys, self.h = system, h
        self._linearised = None

    def __call__(self, t, q, v):
        """Step acceptance for forces that are not affine: the step that ended at (t, q, v) used
        the forces linearised at its start, F(t, q_k, v_k) - K dq - C dv (K = -dF/dq, C = -dF/dv).
        Where a force here differs from that by more than half the sizes the linearisation moved
        through, the step did not resolve the force's variation: a singularity crossed within the
        step (a force 1e-3 / (x - 0.5) that the block cannot pass) or a step far longer than a
        nonlinearity's scale. Raises :class:`StepRejected`; a smooth force's miss is O(dq) smaller
        than its change, and passes. Costs two force evaluations per step, on such systems only."""
        sys_, h, n = self.sys, self.h, self.sys.n
        prev = self._linearised
        out = sys_.step_data_fn(t + h, q, v)
        self._linearised = (t + h, q.copy(), v.copy(), np.array(out[1], dtype=float).ravel(),
                            np.array(out[2], dtype=float).reshape(n, n), np.array(out[3], dtype=float).reshape(n, n))
        if prev is None or prev[0] != t:  # a new run, or not the end of the previous step
            return
        _, q0, v0, F0, K0, C0 = prev
        F = np.array(sys_.force_fn(t, q, v), dtype=float).ravel()
        dq = q - q0
        if getattr(sys_, "has_kinematics", False):  # K is per unit of v: dq in v-space, T dx = dq
            dq = np.linalg.lstsq(np.array(sys_.kinematics_fn(t - h, q0), dtype=float), dq, rcond=None)[0]
        dFq, dFv = K0 @ dq, C0 @ (v - v0)
        F_lin = F0 - dFq - dFv
        miss = np.abs(F - F_lin)
        # coordinate by coordinate, against the sizes that the linearisation itself moved through;
        # a floor at 1e-8 of the largest keeps rounding in forces that vanish from counting
        size = np.maximum.reduce([np.abs(F0), np.abs(F), np.abs(F_lin), np.abs(dFq), np.abs(dFv)])
        size = np.maximum(size, 1e-8 * float(np.max(size, initial=0.0)) + 1e-300)
        worst = int(np.argmax(miss / size))
        if miss[worst] > 0.5 * size[worst] or not np.all(np.isfinite(miss)):
            raise StepRejected(f"the force on {_names(sys_)[worst]} changed faster than the step resolves between "
                               f"t = {t - h:.10g} and t = {t:.10g}: {F[worst]:.4g} against {F_lin[worst]:.4g} "
                               "from its linearisation at the step's start (a singularity of the force crossed "
                               "within the step?); reduce h")


def nonfinite_cause(system, h, t, q, v, S) -> str:
    """What made a step's data non-finite, named: the forces (at t or t + h), their Jacobians,
    or the iteration matrix (a mass matrix singular on the constraint manifold)."""
    sys_ = system
    for tt in (t, t + h):
        F = np.array(sys_.force_fn(tt, q, v), dtype=float).ravel()
        if not np.all(np.isfinite(F)):
            bad = [_names(sys_)[i] for i in np.flatnonzero(~np.isfinite(F))]
            return f"the force F(t, q, v) is not finite at t = {tt:.10g} (coordinates {bad})"
    if np.all(np.isfinite(S)):
        return "the force's Jacobians dF/dq, dF/dv or the constraints' time derivative are not finite"
    return "singular iteration matrix: the mass matrix is singular on the constraint manifold"


def _names(system) -> tuple:
    """The names of the forces' components: the velocities' (the coordinates' without kinematics)."""
    return getattr(system, "velocity_names", system.names)
