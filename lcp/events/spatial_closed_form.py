"""Straight slides of the spatial event method in closed form.

A phase of :class:`~lcp.events.spatial.SpatialPhase` is a **straight slide** when the system is
constant (constant mass matrix and contact kinematics, a force that depends on neither time nor
state), one contact is closed and slides, and the tangential acceleration a_T of the phase (the
applied load plus the friction force -mu N d, for the sliding direction d = U / |U| of the
sliding velocity U) is parallel to U: |U x a_T| at most :data:`STRAIGHT_TOL` |U| |a_T|, rounding
relative to their sizes. The direction then stays d, the friction force -mu N d and the normal
force N are constant, every coordinate is quadratic in time, and the signed sliding speed
s = |U| + (d . a_T) (t - t0) vanishes at the stop t0 + |U| / (-d . a_T), exactly.
:func:`straight_slide` detects it and returns the phase's quadratic; where it does not apply
(a curved slide, several closed contacts, a gap that may close, a state- or time-dependent
force, ...) it returns None and the phase stays numerical.

This module holds the test and the quadratic only; it imports NumPy and nothing of ``lcp``
above :mod:`lcp.events.model` (no scenes, sweeps, simulation or optimal control).
"""
from __future__ import annotations

import math

import numpy as np

from lcp.events.model import EPS

__all__ = ["STRAIGHT_TOL", "Quadratic", "StraightSlide", "straight_slide"]

#: |U x a_T| <= STRAIGHT_TOL |U| |a_T| counts as parallel (rounding of U / |U| and of the solve)
STRAIGHT_TOL = 16 * EPS


class Quadratic:
    """y(t) = y0 + (t - t0) (y1 + (t - t0) y2 / 2), called like a ``solve_ivp`` dense output."""

    def __init__(self, t0, y0, y1, y2):
        self.t0, self.y0, self.y1, self.y2 = float(t0), y0, y1, y2

    def __call__(self, t):
        tau = np.asarray(t, dtype=float) - self.t0
        if tau.ndim == 0:
            return self.y0 + tau * (self.y1 + (0.5 * tau) * self.y2)
        return self.y0[:, None] + tau * (self.y1[:, None] + (0.5 * tau) * self.y2[:, None])


class StraightSlide:
    """The closed form of one straight slide: the quadratic ``sol`` of y = (q, v, cumulative
    forces, s), the constant forces ``N`` (m) and ``f`` (tangent rows), and the stop time
    ``t_stop`` (inf if the slide accelerates or keeps its speed)."""

    def __init__(self, sol, N, f, t_stop):
        self.sol, self.N, self.f, self.t_stop = sol, N, f, t_stop


def _may_close(ph, fr, qdd):
    """An open gap that may close (its impact event is left to the numerical phase)."""
    return any(float(fr.H[k] @ ph.v0) < 0.0 or float(fr.H[k] @ qdd) < 0.0 for k in ph.open_idx)


def _resting(ph):
    """Closed contacts that all stick, under constant forces: the phase's normal and friction
    forces are constant (so neither a lift-off nor a slip can occur, as in the numerical phase,
    whose event functions are then constant), the motion quadratic."""
    model = ph.model
    n, m = model.n, model.m
    fr = model.frame(ph.t0, ph.q0, ph.v0)
    qdd, N, f_st, singular = model.phase_accel(fr, ph.idx, ph.stick, [None] * len(ph.idx))
    if singular or not np.all(N > 0.0) or _may_close(ph, fr, qdd):
        return None
    Nm = np.zeros(m)
    fm = np.zeros(model.H_rows - m)
    fi = 0
    for i, j in enumerate(ph.idx):
        Nm[j] = N[i]
        tr = model.trows[j]
        fm[tr - m] = f_st[fi:fi + tr.size]
        fi += tr.size
    y0 = np.concatenate([ph.q0, ph.v0, ph.P0])
    y1 = np.concatenate([ph.v0, qdd, Nm, fm])
    y2 = np.concatenate([qdd, np.zeros(n + Nm.size + fm.size)])
    return StraightSlide(Quadratic(ph.t0, y0, y1, y2), Nm, fm, math.inf)


def straight_slide(ph, force_tol, painleve_margin):
    """The :class:`StraightSlide` of phase ``ph`` (also of a phase whose closed contacts all
    stick: a rest under constant forces) (a :class:`~lcp.events.spatial.SpatialPhase`),
    or None where the phase is not a straight slide with constant forces and no other event
    (a normal force at or below ``force_tol``, an effective normal mass at or below
    ``painleve_margin``, an open gap that may close: the numerical phase decides those)."""
    model = ph.model
    if not (model.constant and getattr(model, "affine_force", False)) or model.state_force:
        return None
    if ph.idx and not ph.slide:
        return _resting(ph)
    if len(ph.idx) != 1 or len(ph.slide) != 1:
        return None
    j = ph.idx[0]
    tr = model.trows[j]
    if tr.size != 2:
        return None
    n, m = model.n, model.m
    q0, v0 = ph.q0, ph.v0
    fr = model.frame(ph.t0, q0, v0)
    U = fr.H[tr] @ v0
    nU = math.hypot(*U.tolist())
    d = U / nU if nU != 0.0 else np.asarray(ph.d0[0], dtype=float)
    qdd, N, _, singular = model.phase_accel(fr, ph.idx, ph.stick, [d])
    if singular or not (N.size == 1 and N[0] > force_tol):
        return None
    aT = fr.H[tr] @ qdd + fr.Hdv[tr]
    ref = U if nU != 0.0 else d
    cross = float(ref[0] * aT[1] - ref[1] * aT[0])
    if abs(cross) > STRAIGHT_TOL * math.hypot(*ref.tolist()) * math.hypot(*aT.tolist()):
        return None
    sdot = float(d @ aT)
    if nU == 0.0 and not sdot > 0.0:
        return None
    # Painleve: the effective normal mass is constant along a straight slide
    a = float(fr.H[j] @ fr.SH[:, j])
    c = model.mu[j] * float(fr.H[j] @ (fr.SH[:, tr] @ d))
    ref_m = abs(a) + abs(c)
    if ref_m > 0 and (a - c) / ref_m <= painleve_margin:
        return None
    if _may_close(ph, fr, qdd):
        return None
    Nm = np.zeros(m)
    Nm[j] = N[0]
    fm = np.zeros(model.H_rows - m)
    fm[tr - m] = -model.mu[j] * N[0] * d
    y0 = np.concatenate([q0, v0, ph.P0, [nU]])
    y1 = np.concatenate([v0, qdd, Nm, fm, [sdot]])
    y2 = np.concatenate([qdd, np.zeros(n + Nm.size + fm.size + 1)])
    t_stop = ph.t0 + nU / -sdot if (sdot < 0.0 and nU > 0.0) else math.inf
    return StraightSlide(Quadratic(ph.t0, y0, y1, y2), Nm, fm, t_stop)
