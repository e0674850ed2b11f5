"""Compiled output of closed-form phases (numba when installed; the same loops in Python otherwise).

A sweep of single-contact scenes spends more time writing 1000 output rows of quadratic pieces with
NumPy's small-array operations than computing the pieces themselves. This loop writes them directly:
per output time t in piece k, the rows c0 + c1 dt + c2 (dt/2) dt with dt = t - t0_k, in exactly
the floating-point operations of the NumPy version (no fused multiply-add: numba does not contract
without ``fastmath``), so that the two give the same bits.
"""
from __future__ import annotations

import numpy as np

from ..nsgs import HAVE_NUMBA, njit

__all__ = ["HAVE_NUMBA", "fill_pieces"]


@njit(cache=True)
def fill_pieces(t_out, bounds_lo, bounds_hi, t0, C0, C1, C2, Y):
    """Y[:, lo:hi] = C0[k] + C1[k] * dt + C2[k] * ((0.5 * dt) * dt), dt = t_out[lo:hi] - t0[k], per piece k."""
    rows = Y.shape[0]
    for k in range(t0.size):
        for j in range(bounds_lo[k], bounds_hi[k]):
            dt = t_out[j] - t0[k]
            h = 0.5 * dt
            h = h * dt
            for r in range(rows):
                Y[r, j] = (C0[k, r] + C1[k, r] * dt) + C2[k, r] * h
    return Y


def warm() -> None:
    """Compile (or load from numba's cache) once, on a tiny input."""
    fill_pieces(np.zeros(1), np.zeros(1, dtype=np.int64), np.ones(1, dtype=np.int64), np.zeros(1),
                np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1)))
