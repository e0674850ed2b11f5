"""Evaluating a CasADi Function straight into NumPy buffers.

Converting arguments and results to CasADi matrices costs more than a small evaluation; the model,
the mass check and the assembly call :func:`evaluate_into` instead. Imports nothing of ``lcp``.
"""
from __future__ import annotations

import threading

import casadi as ca

__all__ = ["evaluate_into", "evaluate_kept"]

#: per thread: Function -> its kept evaluation buffer (see evaluate_kept)
_KEPT = threading.local()
#: buffers kept per thread at most (the functions they belong to are kept alive with them)
KEPT_MAX = 64


def evaluate_into(fn: ca.Function, args, results) -> None:
    """Evaluate ``fn`` on NumPy arrays (the nonzeros of each argument and result, column-major):
    converting arguments and results to CasADi matrices would cost more than small evaluations.
    An argument given as None is zero (CasADi reads a missing input as zeros), which saves its
    conversion where a function is evaluated at the origin."""
    buf, run = fn.buffer()
    for i, x in enumerate(args):
        if x is not None:
            buf.set_arg(i, memoryview(x))
    for i, x in enumerate(results):
        buf.set_res(i, memoryview(x))
    run()


def evaluate_kept(fn: ca.Function, args, results) -> None:
    """:func:`evaluate_into` with the evaluation buffer of ``fn`` kept for the next call (per
    thread, since a buffer holds the pointers of one evaluation). Creating a CasADi buffer costs
    several microseconds, more than evaluating a small function: for functions that are shared and
    long-lived (one per structure of system, not one per system)."""
    kept = _KEPT.__dict__.setdefault("buffers", {})
    entry = kept.get(id(fn))
    if entry is None or entry[0] is not fn:
        if len(kept) >= KEPT_MAX:
            kept.clear()
        buf, run = fn.buffer()
        entry = kept[id(fn)] = (fn, buf, run)
    _, buf, run = entry
    for i, x in enumerate(args):
        buf.set_arg(i, memoryview(x))
    for i, x in enumerate(results):
        buf.set_res(i, memoryview(x))
    run()
