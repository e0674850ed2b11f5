"""Exact solution of the Jean-Pratt system in every regime of docs/exact_solutions.md.

In contact (y = 0) the reduced dynamics is A xdd = phi + f, N = (m + M) g - M t xdd, with
t = tan(alpha), A = m + M t^2 and Coulomb friction |f| <= R N. Each mode has a constant
acceleration, so the motion is piecewise quadratic:

- slide in direction s = sign(xd): xdd = (phi - s R (m+M) g) / (A (1 - s kappa)), f = -s R N;
- stick: xdd = 0, f = -phi, N = (m + M) g, which holds while |phi| <= R (m + M) g;
- s kappa >= 1 with xd != 0 (Painleve): no sliding motion with N > 0 exists; the consistent
  motion is an impulsive stop (tangential impact) with normal impulse M t xd and tangential
  impulse -A xd, after which the block is at rest.

kappa = R M t / A is the shock number.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields
import math

import numpy as np

from lem.jean_pratt import tan_alpha

__all__ = ["Segment", "JeanPrattExact"]


@dataclass(frozen=True)
class Segment:
    """One mode of constant acceleration on [t0, t1): x = x0 + v0 (t - t0) + a (t - t0)^2 / 2."""

    t0: float
    t1: float
    x0: float
    v0: float
    a: float
    mode: str  # "slide+", "slide-" or "stick"
    N: float
    f: float


_SEGMENT_FIELDS = tuple(f.name for f in fields(Segment))


def _segment(*values) -> Segment:
    """``Segment(*values)`` without the frozen dataclass's per-field ``object.__setattr__`` (a scene
    builds its exact solution every time, and a sweep builds a scene per parameter set)."""
    obj = object.__new__(Segment)
    obj.__dict__.update(zip(_SEGMENT_FIELDS, values))
    return obj


@dataclass
class JeanPrattExact:
    """The exact motion of the Jean-Pratt block from x(0) = 0, y(0) = 0, xd(0) = v0.

    Parameters are those of :func:`lcp.scenes.jean_pratt`. Call the object (or :meth:`evaluate`) at
    times t to get x, xd, N and f. Shocks (impulsive stops) are listed in :attr:`shocks`.

    Attributes
    ----------
    kappa : float
        Shock number R M tan(alpha) / A.
    N0, B : float
        Sliding normal force and deceleration for the initial direction of motion,
        N0 = (m+M) g / (1 -+ kappa), B = R N0 / A (inf when that direction is paradoxical).
    tau0 : float
        Time of the first stop (0 for an impulsive stop, inf if the block never stops).
    x_stop : float
        x at tau0.
    shocks : list of (t, P_N, P_T)
        Impulsive stops: time, normal and tangential impulse.
    segments : list of Segment
    consistent : bool
        Always True: a rest state where neither stick nor slip is possible (a load beyond the stick
        bound with s kappa >= 1 in its direction) lifts the block off, which raises ValueError.

    Examples
    --------
    >>> import math
    >>> from lcp.scenes.jean_pratt_exact import JeanPrattExact
    >>> ex = JeanPrattExact(m=1.0, M=1.0, alpha=math.pi / 4, R=0.5, v0=1.0)
    >>> round(ex.kappa, 12), round(ex.N0, 10), round(ex.B, 10), round(ex.tau0, 6)
    (0.25, 26.16, 6.54, 0.152905)
    >>> ex(0.3)["x"]
    array(0.0764526)
    """

    m: float = 1.0
    M: float = 1.0
    alpha: float = math.pi / 4
    R: float = 0.5
    v0: float = 1.0
    g: float = 9.81
    phi: float = 0.0
    segments: list = field(init=False, default_factory=list)
    shocks: list = field(init=False, default_factory=list)

    def __post_init__(self):
        self.tan = tan_alpha(self.alpha)
        t = self.tan
        m, M, R, g, phi = self.m, self.M, self.R, self.g, self.phi
        self.A = A = m + M * t * t
        self.kappa = R * M * t / A
        self.N_stick = (m + M) * g
        s0 = 1.0 if self.v0 > 0 else (-1.0 if self.v0 < 0 else (1.0 if phi >= 0 else -1.0))
        den = A - s0 * R * M * t  # A (1 - s kappa), formed without cancellation
        self.N0 = (m + M) * g * A / den if den > 0 else math.inf
        self.B = R * self.N0 / A
        self.consistent = True
        self._build()
        stops = [sg.t1 for sg in self.segments if sg.mode != "stick"]
        self.tau0 = 0.0 if (self.shocks and self.shocks[0][0] == 0.0) else (stops[0] if stops else
                                                                               (0.0 if self.v0 == 0 else math.inf))
        self.x_stop = self._x_at(self.tau0) if math.isfinite(self.tau0) else math.nan

    def _x_at(self, t: float) -> float:
        """x at one time, in floats: the same operations as :meth:`evaluate`, without its arrays."""
        x = math.nan
        for sg in self.segments:
            if t >= sg.t0 and (t < sg.t1 or not math.isfinite(sg.t1)):
                dt = t - sg.t0
                x = sg.x0 + sg.v0 * dt + 0.5 * sg.a * dt * dt
        return float(x)

    # ------------------------------------------------------------------ construction
    def _slide(self, s: float):
        """(acceleration, N, f) of sliding in direction s, or None if that direction is paradoxical."""
        m, M, R, g, phi, t, A = self.m, self.M, self.R, self.g, self.phi, self.tan, self.A
        den = A - s * R * M * t
        if den <= 0:
            return None
        a = (phi - s * R * (m + M) * g) / den
        N = (m + M) * g - M * t * a
        if N <= 0:
            raise ValueError(f"phi = {phi!r} lifts the block off the line (N = {N:.6g} < 0 while sliding): "
                             "this regime (an open contact) has no exact solution here")
        return a, N, -s * R * N

    def _build(self):
        tc, xc, vc = 0.0, 0.0, float(self.v0)
        A, M, t = self.A, self.M, self.tan
        for _ in range(8):  # at most: shock, slide, reversal, stick
            if vc != 0.0:
                s = math.copysign(1.0, vc)
                sl = self._slide(s)
                if sl is None:
                    self.shocks.append((tc, M * t * vc, -A * vc))
                    vc = 0.0
                    continue
                a, N, f = sl
                if s * a < 0:
                    tau = -vc / a
                    self.segments.append(_segment(tc, tc + tau, xc, vc, a, "slide+" if s > 0 else "slide-", N, f))
                    xc += vc * tau / 2  # exact for constant deceleration to rest
                    tc += tau
                    vc = 0.0
                    continue
                self.segments.append(_segment(tc, math.inf, xc, vc, a, "slide+" if s > 0 else "slide-", N, f))
                return
            if abs(self.phi) <= self.R * self.N_stick:
                self.segments.append(_segment(tc, math.inf, xc, 0.0, 0.0, "stick", self.N_stick, -self.phi))
                return
            s = math.copysign(1.0, self.phi)
            sl = self._slide(s)
            if sl is None:
                # s kappa >= 1 and the load exceeds the stick bound: the free motion then always lifts
                # the block (M t phi > A (m+M) g follows from |phi| > R (m+M) g >= A (m+M) g / (M |t|))
                raise ValueError(f"phi = {self.phi!r} lifts the block off the line from rest at t = {tc:.6g} "
                                 "(kappa >= 1 in the loaded direction): this regime (an open contact) has no "
                                 "exact solution here")
            a, N, f = sl
            self.segments.append(_segment(tc, math.inf, xc, 0.0, a, "slide+" if s > 0 else "slide-", N, f))
            return

    # ------------------------------------------------------------------ evaluation
    def evaluate(self, t) -> dict:
        """x, xd, N, f and the mode at times t (arrays shaped like t).

        At a shock time the values are the right limits (after the impulse). Times past an
        inconsistency (:attr:`consistent` False) give NaN.
        """
        t = np.asarray(t, dtype=float)
        x = np.full(t.shape, np.nan)
        xd = np.full(t.shape, np.nan)
        N = np.full(t.shape, np.nan)
        f = np.full(t.shape, np.nan)
        mode = np.full(t.shape, "", dtype=object)
        for sg in self.segments:
            sel = (t >= sg.t0) & (t < sg.t1) if np.isfinite(sg.t1) else (t >= sg.t0)
            dt = t[sel] - sg.t0
            x[sel] = sg.x0 + sg.v0 * dt + 0.5 * sg.a * dt * dt
            xd[sel] = sg.v0 + sg.a * dt
            N[sel], f[sel], mode[sel] = sg.N, sg.f, sg.mode
        if np.any(t < 0):
            raise ValueError("t must be >= 0")
        return {"x": x, "xdot": xd, "y": np.where(np.isnan(x), np.nan, 0.0), "N": N, "f": f, "mode": mode}

    __call__ = evaluate

    def impulse(self, t0, t1) -> tuple[np.ndarray, np.ndarray]:
        """Exact normal and tangential impulses over [t0, t1) (forces integrated, plus shocks).

        Divided by (t1 - t0) this is the mean force a time stepper's p / h should match.
        """
        t0 = np.atleast_1d(np.asarray(t0, dtype=float))
        t1 = np.atleast_1d(np.asarray(t1, dtype=float))
        PN = np.zeros(np.broadcast(t0, t1).shape)
        PT = np.zeros_like(PN)
        for sg in self.segments:
            lo = np.maximum(t0, sg.t0)
            hi = np.minimum(t1, sg.t1)
            d = np.maximum(hi - lo, 0.0)
            PN += sg.N * d
            PT += sg.f * d
        for ts, pn, pt in self.shocks:
            sel = (t0 <= ts) & (ts < t1)
            PN[sel] += pn
            PT[sel] += pt
        return PN, PT

    def switch_times(self) -> np.ndarray:
        """Times where the mode changes (stops, reversals, shocks)."""
        ts = [sg.t1 for sg in self.segments if np.isfinite(sg.t1)] + [s[0] for s in self.shocks]
        return np.array(sorted(set(ts)))
