"""Evaluating a CasADi Function straight into NumPy buffers.

Converting arguments and results to CasADi matrices costs more than a small evaluation; the model,
the mass check and the assembly call :func:`evaluate_into` instead. Imports nothing of ``lcp``.
"""
from __future__ import annotations

import casadi as ca

__all__ = ["evaluate_into"]


def evaluate_into(fn: ca.Function, args, results) -> None:
    """Evaluate ``fn`` on NumPy arrays (the nonzeros of each argument and result, column-major):
    converting arguments and results to CasADi matrices would cost more than small evaluations."""
    buf, run = fn.buffer()
    for i, x in enumerate(args):
        buf.set_arg(i, memoryview(x))
    for i, x in enumerate(results):
        buf.set_res(i, memoryview(x))
    run()
