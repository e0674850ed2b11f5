"""Validation of the LEM engine's arguments: bad input raises ``ValueError`` naming the parameter."""
from __future__ import annotations

import numbers

import numpy as np

__all__ = ["check_float", "check_int", "check_outputs", "finite_vector", "is_exact_number"]


def is_exact_number(x) -> bool:
    """True for int and Fraction (rational numbers that keep exact arithmetic), not bool."""
    return isinstance(x, (numbers.Rational,)) and not isinstance(x, bool)


def check_int(name, v, lo):
    if isinstance(v, bool) or not isinstance(v, (numbers.Integral, np.integer)) or v < lo:
        raise ValueError(f"{name} must be an integer >= {lo}, got {v!r}")


def check_float(name, v, lo=None, strict=False, allow_none=False):
    if v is None and allow_none:
        return
    if isinstance(v, bool) or not isinstance(v, (numbers.Real, np.number)) or not np.isfinite(v):
        raise ValueError(f"{name} must be a finite number, got {v!r}")
    if lo is not None and (v <= lo if strict else v < lo):
        raise ValueError(f"{name} must be {'>' if strict else '>='} {lo}, got {v!r}")


def finite_vector(name, v, n=None, allow_exact=False):
    if allow_exact and isinstance(v, (list, tuple)) and all(is_exact_number(x) for x in v):
        arr = list(v)
        if n is not None and len(arr) != n:
            raise ValueError(f"{name} must have {n} components, got {len(arr)}")
        return arr
    try:
        arr = np.asarray(v, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a 1-D array of finite numbers") from exc
    if arr.ndim != 1 or (n is not None and arr.size != n):
        raise ValueError(f"{name} must be a 1-D array of {n if n is not None else 'some'} numbers, "
                         f"got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {v!r}")
    return arr


def check_outputs(outputs, n):
    if outputs is None:
        return tuple(range(n))
    outs = tuple(outputs)
    if not outs or any(isinstance(i, bool) or not isinstance(i, (numbers.Integral, np.integer))
                       or not 0 <= i < n for i in outs) or len(set(outs)) != len(outs):
        raise ValueError(f"outputs must be distinct component indices in [0, {n}), got {outputs!r}")
    return tuple(int(i) for i in outs)
