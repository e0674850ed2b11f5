"""A force that is piecewise affine in t: the control force B u(t) of a scheduled constant system.

``System.with_control(schedule)`` gives a system whose force is F0(q, v) + B u(t). When the mass
matrix, the contact kinematics and B are constant and F0 is affine in (q, v) and independent of t,
the only time dependence is the schedule's: affine in t between its nodes for the constant, linear
and affine holds. :func:`time_forcing` recognizes such a system and returns its
:class:`TimeForcing`: per interval k of the schedule, F(t, 0, 0) = a_k + b_k (t - t_k).

The test is conservative: structural checks on the System (constant mass matrix, kinematics and
B = dF/du, forces affine in (q, v) with constant K and C, no breakpoints other than the schedule's
nodes), then F(t, 0, 0) evaluated by the System itself (one CasADi call) at five times in every
interval, both ends included, must equal a_k + b_k (t - t_k) to rounding; anything else (a force
that depends on t by itself, a state-dependent B, an unknown schedule) gives None, and the event
integrator keeps its general path.
"""
from __future__ import annotations

import math
import weakref

import casadi as ca
import numpy as np

from lcp.model.control import ControlSchedule

__all__ = ["TimeForcing", "time_forcing"]

#: interior sample points of the check, as fractions of an interval (ends included separately)
_FRACTIONS = (0.1234567891, 0.5, 0.8765432109)


class TimeForcing:
    """F(t, 0, 0) = a_k + b_k (t - t_k) on [t_k, t_{k+1}), right-continuous at the nodes.

    Parameters
    ----------
    times : ndarray (K,)
        The schedule's nodes; the forcing is valid on [times[0], times[-1]].
    a, b : ndarray (K - 1, n)
        Value at the start of each interval and slope.

    Examples
    --------
    >>> import numpy as np
    >>> f = TimeForcing(np.array([0.0, 1.0, 2.0]), np.array([[1.0], [5.0]]), np.array([[2.0], [0.0]]))
    >>> f.at(0.5).tolist(), f.at(1.0).tolist(), f.left_piece(1.0)
    ([2.0], [5.0], 0)
    >>> [x.tolist() for x in f.affine(0.5)]
    [[2.0], [2.0]]
    """

    def __init__(self, times, a, b):
        self.times, self.a, self.b = times, a, b
        self.t_lo, self.t_hi = float(times[0]), float(times[-1])
        self._nodes = times.tolist()

    def piece(self, t: float) -> int:
        """Index of the interval holding t (a node starts the next interval), clipped."""
        k = int(np.searchsorted(self.times, t, side="right")) - 1
        return min(max(k, 0), len(self._nodes) - 2)

    def left_piece(self, t: float) -> int:
        """Index of the interval whose closure ends at t or holds t (the left limit at a node)."""
        k = int(np.searchsorted(self.times, t, side="left")) - 1
        return min(max(k, 0), len(self._nodes) - 2)

    def at(self, t: float, k: int | None = None) -> np.ndarray:
        """F(t, 0, 0), from interval k (by default the one holding t)."""
        if k is None:
            k = self.piece(t)
        return self.a[k] + self.b[k] * (t - self._nodes[k])

    def affine(self, t0: float, k: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(F(t0), dF/dt) of interval k (by default the one holding t0): F(t) = F(t0) + dF/dt (t - t0)
        until the interval's end."""
        if k is None:
            k = self.piece(t0)
        return self.at(t0, k), self.b[k]

    def covers(self, t0: float, t1: float) -> bool:
        """Whether [t0, t1] lies within the checked range of the schedule."""
        return self.t_lo <= t0 and t1 <= self.t_hi


def _pieces(schedule) -> tuple[np.ndarray, np.ndarray] | None:
    """(start values, slopes) per interval, shape (K - 1, nu) each, of a known hold; None otherwise."""
    if not isinstance(schedule, ControlSchedule):
        return None
    t, u = schedule.times, schedule.values
    h = np.diff(t)[:, None]
    if schedule.hold == "constant":
        return u, np.zeros_like(u)
    if schedule.hold == "linear":
        return u[:-1], (u[1:] - u[:-1]) / h
    if schedule.hold == "affine" and u.shape[0] == 2 * (t.size - 1):
        start, end = u[0::2], u[1::2]
        return start, (end - start) / h
    return None


FORCINGS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def time_forcing(system) -> TimeForcing | None:
    """The piecewise-affine forcing of a scheduled constant system (see the module), or None.

    Kept per System object (the check costs one CasADi call).
    """
    try:
        return FORCINGS[system]
    except KeyError:
        pass
    except TypeError:  # not weak-referenceable: no cache
        return _build(system)
    out = FORCINGS[system] = _build(system)
    return out


def _build(system) -> TimeForcing | None:
    schedule = getattr(system, "control_schedule", None)
    B_fn = getattr(system, "control_matrix_fn", None)
    if schedule is None or B_fn is None or getattr(system, "is_spatial", False):
        return None
    if not (system.mass_is_constant and system.kinematics_is_constant and system.force_is_affine):
        return None
    pieces = _pieces(schedule)
    if pieces is None:
        return None
    t_sym, q_sym = system.t_sym, system.q_sym
    n = system.n
    try:
        B_expr = B_fn(t_sym, q_sym)
    except Exception:  # noqa: BLE001 - an unexpected signature: not the structure this path knows
        return None
    if ca.depends_on(B_expr, ca.vertcat(t_sym, q_sym)):
        return None
    B = np.array(ca.evalf(B_expr), dtype=float).reshape(n, -1)
    start, slope = pieces
    if B.shape[1] != start.shape[1]:
        return None
    times = np.array(schedule.times, dtype=float)
    # the System's breakpoints must be nodes of the schedule (else the force has jumps of its own)
    bp = np.asarray(getattr(system, "breakpoints", ()), dtype=float).ravel()
    if bp.size and not np.all(np.isin(bp, times)):
        return None
    # samples: every interval's start, interior points and left end (the last before the node)
    K = times.size - 1
    ts, ks = [], []
    for k in range(K):
        t0, t1 = float(times[k]), float(times[k + 1])
        h = t1 - t0
        for x in (t0, *(t0 + f * h for f in _FRACTIONS), math.nextafter(t1, -math.inf)):
            ts.append(x)
            ks.append(k)
    ts_a, ks_a = np.array(ts), np.array(ks)
    z = np.zeros(n)
    fn = system.force_fn.map(ts_a.size)
    F = np.array(fn(ts_a[None, :], np.tile(z[:, None], ts_a.size), np.tile(z[:, None], ts_a.size)),
                 dtype=float).reshape(n, ts_a.size).T
    U = start[ks_a] + slope[ks_a] * (ts_a - times[ks_a])[:, None]
    BU = U @ B.T
    base = F - BU  # the force without the control: one constant vector if the structure is as assumed
    F0 = base[0]
    scale = max(1.0, float(np.max(np.abs(F))), float(np.max(np.abs(BU))))
    if not np.all(np.isfinite(base)) or float(np.max(np.abs(base - F0))) > 1e-12 * scale:
        return None
    a = F0 + start @ B.T
    b = slope @ B.T
    for x in (times, a, b):
        x.setflags(write=False)
    return TimeForcing(times, a, b)
