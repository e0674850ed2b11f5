"""Control schedules: a control input u(t) known on a time grid, held piecewise constant or linear.

A :class:`ControlSchedule` is what an optimal control solution hands to a simulation: the nodes,
the values, and how the control is held in between. It evaluates u(t), its exact integral over any
interval (the impulse a time step must see), its discontinuities (``breakpoints``, where an event
integrator must end a phase) and a CasADi expression of the time symbol.

Holds
-----
``"constant"`` (zero-order hold): u(t) = u_k on [t_k, t_{k+1}); ``values`` has one row per
interval (K - 1 rows for K nodes). The control is discontinuous at every interior node.

``"linear"`` (first-order hold): u(t) interpolates the node values linearly; ``values`` has one row
per node. The control is continuous; its derivative jumps at the interior nodes.

Outside [t_0, t_K] the control keeps its end value (the first, or the last piece).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

__all__ = ["HOLDS", "ControlSchedule", "set_checked_values"]


def set_checked_values(schedule, t: np.ndarray, rows: int, layout: str) -> np.ndarray:
    """Check a schedule's values against its ``rows`` (``layout`` says what a row is, for the error),
    then store its times ``t`` and the values as read-only arrays; returns the values, (rows, nu)."""
    u = np.asarray(schedule.values, dtype=float)
    if u.ndim == 1 and u.size == rows:
        u = u.reshape(rows, 1)
    if u.ndim != 2 or u.shape[0] != rows or u.shape[1] < 1:
        raise ValueError(f"values must have {rows} rows {layout}, got shape {np.shape(schedule.values)}")
    if not np.all(np.isfinite(u)):
        raise ValueError("values must be finite")
    t.flags.writeable = False
    u = u.copy()
    u.flags.writeable = False
    object.__setattr__(schedule, "times", t)
    object.__setattr__(schedule, "values", u)
    return u

#: the holds a schedule knows
HOLDS = ("constant", "linear")


@dataclass(frozen=True, eq=False)
class ControlSchedule:
    """A control u(t) on a time grid, held piecewise constant or piecewise linear.

    Parameters
    ----------
    times : array_like, shape (K,)
        Increasing, finite nodes t_0 < ... < t_{K-1} (K >= 2).
    values : array_like, shape (K - 1, nu) for ``"constant"``, (K, nu) for ``"linear"``
        The control on each interval (constant hold) or at each node (linear hold). A 1-D array is
        one control component.
    hold : {"constant", "linear"}
        How the control is held between the nodes.

    Examples
    --------
    >>> from lcp.model.control import ControlSchedule
    >>> u = ControlSchedule([0.0, 1.0, 2.0], [10.0, -5.0])
    >>> u(0.5), u(1.0), u.impulse(0.5, 1.5)
    (array([10.]), array([-5.]), array([2.5]))
    >>> ControlSchedule([0.0, 1.0], [0.0, 4.0], hold="linear").impulse(0.0, 1.0)
    array([2.])
    """

    times: np.ndarray
    values: np.ndarray
    hold: str = "constant"

    def __post_init__(self):
        t = np.asarray(self.times, dtype=float).ravel()
        if len(t) < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
            raise ValueError("times must be at least two finite, strictly increasing times")
        if self.hold not in HOLDS:
            raise ValueError(f"hold must be one of {HOLDS}, got {self.hold!r}")
        rows = len(t) - 1 if self.hold == "constant" else len(t)
        u = set_checked_values(self, t, rows, f"for the {self.hold} hold on {len(t)} times (one per "
                                               f"{'interval' if self.hold == 'constant' else 'node'})")
        # cumulative integral at the nodes, for exact impulses over any interval
        dt = np.diff(t)[:, None]
        pieces = u * dt if self.hold == "constant" else 0.5 * (u[:-1] + u[1:]) * dt
        object.__setattr__(self, "_cum", np.vstack([np.zeros((1, u.shape[1])), np.cumsum(pieces, axis=0)]))

    @property
    def nu(self) -> int:
        """Number of control components."""
        return self.values.shape[1]

    @property
    def t0(self) -> float:
        return float(self.times[0])

    @property
    def t_end(self) -> float:
        return float(self.times[-1])

    @property
    def breakpoints(self) -> np.ndarray:
        """Interior nodes where the control (constant hold) or its slope (linear hold) jumps."""
        inner = self.times[1:-1]
        if self.hold == "constant":
            return inner[np.any(self.values[1:] != self.values[:-1], axis=1)]
        slope = np.diff(self.values, axis=0) / np.diff(self.times)[:, None]
        return inner[np.any(slope[1:] != slope[:-1], axis=1)]

    def _piece(self, t):
        """Index of the interval holding t (right-continuous: a node starts the next interval)."""
        return np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, len(self.times) - 2)

    def __call__(self, t) -> np.ndarray:
        """u(t), shape t.shape + (nu,); right-continuous at the nodes."""
        t = np.asarray(t, dtype=float)
        if self.hold == "constant":
            return self.values[self._piece(t)]
        return np.stack([np.interp(t, self.times, self.values[:, j]) for j in range(self.nu)], axis=-1)

    def left(self, t) -> np.ndarray:
        """The left limit u(t-), shape t.shape + (nu,)."""
        t = np.asarray(t, dtype=float)
        if self.hold == "linear":
            return self(t)
        k = np.clip(np.searchsorted(self.times, t, side="left") - 1, 0, len(self.times) - 2)
        return self.values[k]

    def integral(self, t) -> np.ndarray:
        """int_{t_0}^{t} u(s) ds (negative before t_0), shape t.shape + (nu,)."""
        t = np.asarray(t, dtype=float)
        k = self._piece(t)
        s = (t - self.times[k])[..., None]
        if self.hold == "constant":
            return self._cum[k] + self.values[k] * s
        h = np.diff(self.times)[k]
        slope = (self.values[k + 1] - self.values[k]) / h[..., None]
        # beyond the ends the linear hold keeps the end value, not the extrapolated line
        s_in = np.clip(s, 0.0, h[..., None])
        inside = self._cum[k] + self.values[k] * s_in + 0.5 * slope * s_in ** 2
        end = self.values[k] + slope * s_in
        return inside + end * (s - s_in)

    def impulse(self, t0, t1) -> np.ndarray:
        """int_{t0}^{t1} u(s) ds, exactly (shape (nu,) for scalar t0, t1)."""
        return self.integral(t1) - self.integral(t0)

    def expression(self, t: ca.SX) -> ca.SX:
        """u(t) as a CasADi expression of the time symbol t (right-continuous at the nodes)."""
        tt = ca.DM(self.times)
        if self.hold == "constant":
            # pw_const(t, breakpoints b, values y): y_0 for t < b_0, y_i for b_{i-1} <= t < b_i
            return ca.vertcat(*[ca.pw_const(t, ca.DM(self.times[1:-1]), ca.DM(self.values[:, j]))
                                for j in range(self.nu)])
        return ca.vertcat(*[ca.pw_lin(t, tt, ca.DM(self.values[:, j])) for j in range(self.nu)])

    def __repr__(self) -> str:
        return (f"ControlSchedule(hold={self.hold!r}, nu={self.nu}, intervals={len(self.times) - 1}, "
                f"t=[{self.t0:.6g}, {self.t_end:.6g}])")


@dataclass(frozen=True)
class ControlInput:
    """A system's control input: u (nu x 1 symbols), its bounds, and F = free_force + matrix u."""

    symbol: ca.SX | None
    nu: int
    bounds: tuple
    matrix: ca.SX
    free_force: ca.SX


def split_control(force, mass, control, control_bounds, q, v, t) -> ControlInput:
    """Split a force F(t, q, v, u) into F0(t, q, v) + B(t, q) u, checking that u enters affinely.

    Raises a ValueError naming ``control`` or ``control_bounds`` when the input is not a column of
    symbols distinct from t, q and v, when B depends on u or v, when the mass matrix depends on u,
    or when the bounds are not a pair lo <= hi.
    """
    n = force.shape[0]
    if control is None:
        if control_bounds is not None:
            raise ValueError("control_bounds given without a control")
        return ControlInput(None, 0, (np.zeros(0), np.zeros(0)), ca.SX.zeros(n, 0), force)
    if not isinstance(control, ca.SX) or not control.is_symbolic() or control.shape[1] != 1:
        raise ValueError("control must be a column of CasADi SX symbols (casadi.SX.sym('u', nu))")
    nu = control.shape[0]
    if ca.depends_on(control, ca.vertcat(q, v, t)):
        raise ValueError("control symbols must differ from t, q and v")
    B = ca.jacobian(force, control)
    if ca.depends_on(B, ca.vertcat(control, v)):
        raise ValueError("the force must be affine in the control: F = F0(t, q, v) + B(t, q) u with B "
                         "independent of u and v")
    if ca.depends_on(mass, control):
        raise ValueError("mass may not depend on the control")
    if control_bounds is None:
        lo, hi = -np.inf, np.inf
    else:
        try:
            lo, hi = control_bounds
        except (TypeError, ValueError) as exc:
            raise ValueError(f"control_bounds must be a pair (lo, hi), got {control_bounds!r}") from exc
    lo = np.broadcast_to(np.asarray(lo, dtype=float), (nu,)).copy()
    hi = np.broadcast_to(np.asarray(hi, dtype=float), (nu,)).copy()
    if np.any(np.isnan(lo)) or np.any(np.isnan(hi)) or np.any(lo > hi):
        raise ValueError(f"control_bounds must satisfy lo <= hi, got {control_bounds!r}")
    return ControlInput(control, nu, (lo, hi), B, ca.substitute(force, control, ca.SX.zeros(nu, 1)))


def check_schedule(schedule, nu: int, bounds) -> None:
    """ValueError naming ``control`` unless ``schedule`` fits a control input of nu components within bounds."""
    if not nu:
        raise ValueError("with_control needs a system with a control input (System(..., control=u))")
    if not isinstance(schedule, ControlSchedule):
        raise ValueError(f"control must be a lcp.model.control.ControlSchedule, got {type(schedule).__name__}")
    if schedule.nu != nu:
        raise ValueError(f"control must have {nu} components, got {schedule.nu}")
    lo, hi = bounds
    tol = 1e-9 * np.maximum(1.0, np.abs(schedule.values).max())
    if np.any(schedule.values < lo - tol) or np.any(schedule.values > hi + tol):
        raise ValueError(f"control values leave control_bounds [{lo}, {hi}]")
