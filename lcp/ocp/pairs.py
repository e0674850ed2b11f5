"""User complementarity path constraints of an optimal control problem: 0 <= a(step) perp b(step) >= 0.

``OptimalControlProblem(..., complementarity=[(a, b), ...])`` adds, at every step, pairs given by
the user as callables of the :class:`~lcp.ocp.results.Step` (a no-slip foot: the foot's height
against its horizontal speed; a latch that may engage only at rest). Each pair is lifted into two
nonnegative NLP variables ``ca >= 0``, ``cb >= 0`` with ``ca = a(step)``, ``cb = b(step)`` and
relaxed with the contacts' Scholtes homotopy (``ca cb <= sigma``); the polishing and fixed-phase
solves fix the smaller member at zero, as for the contact pairs. The diagnosis counts
``max |min(a, b)|`` with the cross pairs (the homotopy stops only once it is within ``tol``), and the
replay check evaluates the pairs on the replayed states (:func:`pair_violation`).

Holds the checks of the option, the NLP pieces and the measures. Imports CasADi and NumPy only: it
must not import the transcription or the solve (they call it).
"""
from __future__ import annotations

import casadi as ca
import numpy as np

__all__ = ["add_pairs", "check_pairs", "fix_pairs", "pair_residual", "pair_values", "pair_violation"]


def check_pairs(pairs) -> list:
    """The option ``complementarity`` as a list of (a, b) callables, or ValueError naming it.

    Examples
    --------
    >>> from lcp.ocp.pairs import check_pairs
    >>> len(check_pairs([(lambda s: s.q1[1], lambda s: s.v1[0])]))
    1
    >>> check_pairs([(1.0, 2.0)])
    Traceback (most recent call last):
    ...
    ValueError: complementarity[0] must be a pair (a, b) of callables of the Step, got (1.0, 2.0)
    """
    if pairs is None:
        return []
    try:
        items = list(pairs)
    except TypeError:
        raise ValueError(f"complementarity must be a list of (a, b) pairs of callables, got {pairs!r}") from None
    for i, pair in enumerate(items):
        if not (isinstance(pair, (tuple, list)) and len(pair) == 2 and all(callable(f) for f in pair)):
            raise ValueError(f"complementarity[{i}] must be a pair (a, b) of callables of the Step, got {pair!r}")
    return [tuple(p) for p in items]


def add_pairs(pairs, k, st, sigma, var, constrain, sizes: dict) -> None:
    """The NLP pieces of the user pairs at step k: variables ``ca{i}``, ``cb{i}`` (keys of ``ix``),
    their defining equalities and the Scholtes inequality ``ca cb <= sigma``.

    ``var(name, size, lb, ub, key)`` and ``constrain(expr, lo, hi)`` are the transcription's;
    ``sizes`` (pair index -> length at step 0) is filled at step 0 and checked after it.
    """
    for i, (fa, fb) in enumerate(pairs):
        a, b = ca.vec(ca.SX(fa(st))), ca.vec(ca.SX(fb(st)))
        if a.shape[0] != b.shape[0]:
            raise ValueError(f"complementarity[{i}]: a and b must have the same length at step {k}, got "
                             f"{a.shape[0]} and {b.shape[0]}")
        size = a.shape[0]
        if k and size != sizes[i]:
            # one length at every step keeps the variables a regular (N, size) block; a window is
            # written with a factor that vanishes outside it
            raise ValueError(f"complementarity[{i}] must have the same length at every step: {sizes[i]} at "
                             f"step 0, {size} at step {k}")
        sizes[i] = size
        va = var(f"ca{i}_{k}", size, 0.0, np.inf, f"ca{i}")
        vb = var(f"cb{i}_{k}", size, 0.0, np.inf, f"cb{i}")
        if size:
            constrain(va - a, 0.0, 0.0)
            constrain(vb - b, 0.0, 0.0)
            constrain(va * vb - sigma, -np.inf, 0.0)


def _indices(tr, i):
    ix = tr.ix
    return (np.concatenate([np.ravel(j) for j in ix[f"ca{i}"]]).astype(int),
            np.concatenate([np.ravel(j) for j in ix[f"cb{i}"]]).astype(int))


def pair_residual(tr, x) -> tuple[float, float]:
    """(max |min(a, b)|, max a b) over the user pairs at the NLP point x ((0, 0) without pairs)."""
    res = prod = 0.0
    for i in range(len(getattr(tr.pb, "complementarity", []))):
        ia, ib = _indices(tr, i)
        if ia.size:
            res = max(res, float(np.max(np.abs(np.minimum(x[ia], x[ib])))))
            prod = max(prod, float(np.max(x[ia] * x[ib])))
    return res, prod


def fix_pairs(tr, x, ubx) -> None:
    """Fix the smaller member of every user pair at x at zero (in ``ubx``, in place)."""
    for i in range(len(getattr(tr.pb, "complementarity", []))):
        ia, ib = _indices(tr, i)
        small = x[ia] <= x[ib]
        ubx[ia[small]] = 0.0
        ubx[ib[~small]] = 0.0


def pair_values(pairs, st) -> list:
    """(a, b) of every user pair on one (numeric) step, as float arrays."""
    out = []
    for fa, fb in pairs:
        vals = []
        for f in (fa, fb):
            val = f(st)
            if isinstance(val, (ca.SX, ca.DM)):
                val = ca.evalf(ca.SX(val))
            vals.append(np.array(val, dtype=float).ravel())
        out.append(tuple(vals))
    return out


def pair_violation(pairs, st) -> float:
    """max(|min(a, b)|, -a, -b) of the user pairs on one (numeric) step: 0 when they hold."""
    worst = 0.0
    for a, b in pair_values(pairs, st):
        if a.size:
            worst = max(worst, float(np.max(np.abs(np.minimum(a, b)))), float(np.max(-a)), float(np.max(-b)))
    return worst
