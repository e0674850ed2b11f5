"""A discontinuous piecewise-affine control: one affine piece per interval (the ``"affine"`` hold).

The optimal controls of contact problems are often smooth within a contact phase and jump at a
switch (minimum effort: a ramp during a slide, zero while the block sticks). A piecewise-constant
control approximates the ramp by a staircase, whose cost exceeds the ramp's by about J / (4 n^2)
over n steps; a continuous piecewise-linear control cannot jump. The affine hold has both: on each
interval [t_k, t_{k+1}) the control goes linearly from a start value to an end value, and the end
of one interval need not equal the start of the next.

:class:`AffineSchedule` is a :class:`lcp.model.control.ControlSchedule` (so ``lcp.simulate(...,
control=...)`` and ``System.with_control`` take it), with the exact integral, the breakpoints
(nodes where the value or the slope jumps) and a CasADi expression of t.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from lcp.model.control import ControlSchedule, set_checked_values

__all__ = ["AffineSchedule"]


@dataclass(frozen=True, eq=False)
class AffineSchedule(ControlSchedule):
    """A control affine on each interval, discontinuous at the nodes.

    Parameters
    ----------
    times : array_like, shape (K,)
        Increasing, finite nodes (K >= 2).
    values : array_like, shape (2 (K - 1), nu)
        Start and end value of each interval, interleaved: u(t_0+), u(t_1-), u(t_1+), u(t_2-), ...
        A 1-D array is one control component.
    hold : str
        Always ``"affine"``.

    Examples
    --------
    >>> from lcp.model.schedule import AffineSchedule
    >>> u = AffineSchedule([0.0, 1.0, 2.0], [4.0, 0.0, 1.0, 1.0])
    >>> u(0.5), u.left(1.0), u(1.0), u.impulse(0.0, 2.0)
    (array([2.]), array([0.]), array([1.]), array([3.]))
    >>> u.breakpoints
    array([1.])
    """

    hold: str = "affine"

    def __post_init__(self):
        t = np.asarray(self.times, dtype=float).ravel()
        if len(t) < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
            raise ValueError("times must be at least two finite, strictly increasing times")
        if self.hold != "affine":
            raise ValueError(f"hold must be 'affine' for an AffineSchedule, got {self.hold!r}")
        rows = 2 * (len(t) - 1)
        u = set_checked_values(self, t, rows, f"(start and end of each of the {len(t) - 1} intervals)")
        dt = np.diff(t)[:, None]
        pieces = 0.5 * (u[0::2] + u[1::2]) * dt
        object.__setattr__(self, "_cum", np.vstack([np.zeros((1, u.shape[1])), np.cumsum(pieces, axis=0)]))

    @property
    def start(self) -> np.ndarray:
        """u(t_k+) per interval, shape (K - 1, nu)."""
        return self.values[0::2]

    @property
    def end(self) -> np.ndarray:
        """u(t_{k+1}-) per interval, shape (K - 1, nu)."""
        return self.values[1::2]

    @property
    def slopes(self) -> np.ndarray:
        return (self.end - self.start) / np.diff(self.times)[:, None]

    @property
    def breakpoints(self) -> np.ndarray:
        """Interior nodes where the control or its slope jumps."""
        s = self.slopes
        jump = np.any(self.end[:-1] != self.start[1:], axis=1) | np.any(s[1:] != s[:-1], axis=1)
        return self.times[1:-1][jump]

    def _eval(self, t, k):
        s = np.clip(t - self.times[k], 0.0, np.diff(self.times)[k])[..., None]
        return self.start[k] + self.slopes[k] * s

    def __call__(self, t) -> np.ndarray:
        """u(t), shape t.shape + (nu,); right-continuous at the nodes, the end values kept outside."""
        t = np.asarray(t, dtype=float)
        return self._eval(t, self._piece(t))

    def left(self, t) -> np.ndarray:
        """The left limit u(t-), shape t.shape + (nu,)."""
        t = np.asarray(t, dtype=float)
        k = np.clip(np.searchsorted(self.times, t, side="left") - 1, 0, len(self.times) - 2)
        return self._eval(t, k)

    def integral(self, t) -> np.ndarray:
        """int_{t_0}^{t} u(s) ds (the end values held outside [t_0, t_K]), shape t.shape + (nu,)."""
        t = np.asarray(t, dtype=float)
        k = self._piece(t)
        s = (t - self.times[k])[..., None]
        h = np.diff(self.times)[k][..., None]
        s_in = np.clip(s, 0.0, h)
        inside = self._cum[k] + self.start[k] * s_in + 0.5 * self.slopes[k] * s_in ** 2
        return inside + self._eval(t, k) * (s - s_in)

    def expression(self, t: ca.SX) -> ca.SX:
        """u(t) as a CasADi expression of t: a + b t with a, b piecewise constant (right-continuous)."""
        tt = ca.DM(self.times)
        s = self.slopes
        out = []
        for j in range(self.nu):
            a = np.concatenate([[self.start[0, j]], self.start[:, j] - s[:, j] * self.times[:-1], [self.end[-1, j]]])
            b = np.concatenate([[0.0], s[:, j], [0.0]])
            out.append(ca.pw_const(t, tt, ca.DM(a)) + ca.pw_const(t, tt, ca.DM(b)) * t)
        return ca.vertcat(*out)

    def __repr__(self) -> str:
        return (f"AffineSchedule(nu={self.nu}, intervals={len(self.times) - 1}, "
                f"t=[{self.t0:.6g}, {self.t_end:.6g}])")
