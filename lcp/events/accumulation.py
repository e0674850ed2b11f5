"""Accumulations of impacts (Zeno behaviour): detecting them and jumping to their limit.

A ball dropped on a floor with restitution 0 < e < 1 bounces infinitely often before a finite time:
after an impact with normal velocity u_k it flies Delta_k = 2 u_k / g, lands with velocity -u_k and
leaves with e u_k, so the flight times shrink geometrically and add up to

    t_inf = t_k + Delta_k / (1 - e).

Resolving the impacts one by one never reaches t_inf (and leaves a residual bounce at the
resolution of the zero tests). Here the impacts on one set of contacts are watched: when the
intervals between them shrink geometrically with a steady ratio and the bounces have become
smaller than the length tolerance, the remaining impacts are summed up at once:

- **closed form** when the flight between impacts has constant accelerations (a polynomial
  system in a closed-form phase) and one contact bounces: t_inf as above with Delta_k and the
  normal acceleration of that contact;
- otherwise **Aitken's delta-squared extrapolation** of the impact times.

The state at t_inf is extrapolated (Aitken, per component, from the states after the last three
impacts: exact for geometric sequences), then projected onto the contacts with zero gap and zero
normal velocity; the contacts persist from there. The unresolved impacts' total impulse follows
from the momentum balance over the tail and is recorded as one impulse at t_inf.
"""
from __future__ import annotations

import math

import numpy as np

from lcp.contact.problem import STICK
from lcp.events.model import EPS
from lcp.events.records import Accumulation, Event, Impulse

__all__ = ["BounceSequence", "TailPhase", "aitken", "kinematic_accumulation", "tail_impulse", "sum_up"]


def aitken(x0, x1, x2):
    """Aitken's delta-squared limit of the sequences x0, x1, x2 (arrays, componentwise); where the
    second difference vanishes (a constant or linear component) the last value is kept."""
    x0, x1, x2 = (np.asarray(x, dtype=float) for x in (x0, x1, x2))
    d1, d2 = x1 - x0, x2 - x1
    den = d2 - d1
    scale = np.maximum(np.maximum(np.abs(x0), np.abs(x1)), np.abs(x2))
    ok = (np.abs(den) > 64 * EPS * np.maximum(scale, 1e-300)) & (np.abs(d2) < np.abs(d1))
    out = x2.copy()
    out[ok] = x2[ok] - d2[ok] * d2[ok] / den[ok]
    return out


class BounceSequence:
    """Impacts on the same contacts, each followed by the same kind of smooth phase.

    ``push`` records the state just after an impact (right limit); ``limit`` says whether they
    form an accumulation ready to be summed up, and where it ends.
    """

    def __init__(self, min_ratios: int = 3, ratio_rtol: float = 1e-2):
        self.min_ratios, self.ratio_rtol = min_ratios, ratio_rtol
        self.items = []
        self.first = None
        self.count = 0

    def reset(self):
        self.items = []
        self.first = None
        self.count = 0

    def push(self, t, contacts, q, v, signature):
        """The state (q, v) right after an impact at t on ``contacts``; ``signature`` identifies
        the modes of the phase that follows (a change starts a new sequence)."""
        if self.items and (self.items[-1][1] != contacts or self.items[-1][4] != signature):
            self.reset()
        if not self.items:
            self.first = t
        self.count += 1
        self.items.append((t, contacts, q.copy(), v.copy(), signature))
        del self.items[:-(self.min_ratios + 2)]

    def __len__(self):
        return len(self.items)

    def geometric(self) -> bool:
        """The last intervals shrink with one steady ratio in (0, 1)."""
        if len(self.items) < self.min_ratios + 2:
            return False
        t = [it[0] for it in self.items]
        dt = np.diff(t)
        if np.any(dt <= 0):
            return False
        r = dt[1:] / dt[:-1]
        return bool(np.all((r > 0) & (r < 1)) and (r.max() - r.min()) <= self.ratio_rtol * r.max())

    def limit(self, closed_form=None):
        """(t_inf, q_inf, v_inf, method): the accumulation point and the extrapolated state.

        ``closed_form`` = (Delta, e): the next flight time and the restitution coefficient, when
        the flight has constant accelerations; otherwise Aitken on the impact times.
        """
        (t0, _, q0, v0, _), (t1, _, q1, v1, _), (t2, _, q2, v2, _) = self.items[-3:]
        if closed_form is not None:
            delta, e = closed_form
            t_inf, method = t2 + delta / (1.0 - e), "closed-form"
        else:
            d1, d2 = t1 - t0, t2 - t1
            t_inf, method = t2 + d2 * d2 / (d1 - d2), "aitken"
        q_inf = aitken(q0, q1, q2)
        v_inf = aitken(v0, v1, v2)
        if not (math.isfinite(t_inf) and t_inf > t2):
            return None
        return t_inf, q_inf, v_inf, method


def kinematic_accumulation(notes: list, t: float) -> None:
    """An accumulation of impacts on a system with Newton-Euler kinematics is not extrapolated:
    Aitken's limit of q would leave the unit quaternions' sphere, and the tail's velocity
    (q_inf - q) / dt is not a v of qdot = T(q) v. Says so once in ``notes``; returns None (the
    impacts are resolved one by one, down to the velocity zero test)."""
    if not any("Newton-Euler kinematics" in note for note in notes):
        notes.append(f"From t = {t:.10g} impacts accumulate on a system with Newton-Euler kinematics: resolved "
                     "impact by impact (no extrapolation to their limit).")


def tail_impulse(A, Hc, G, dv, qdd, T):
    """Contact impulses (normal rows then tangent rows of Hc) of the unresolved impacts over a
    tail of duration T: the least-squares solution of Hc' P + G' L = A (dv - qdd T)."""
    r = A @ (dv - qdd * T)
    J = np.vstack([Hc, G]) if G.shape[0] else Hc
    P = np.linalg.lstsq(J.T, r, rcond=None)[0]
    return P[:Hc.shape[0]]


class TailPhase:
    """The unresolved tail [t0, t1) of an accumulation, for output: positions interpolated
    linearly between the last resolved impact and the limit (the bounces there are below the
    length tolerance), velocity their mean, no contact force (the impulses are at t1)."""

    integrator = "accumulation"
    nfev = 0

    def __init__(self, t0, t1, q0, q1, P0, names, full_modes, idx_t, m=None):
        self.t0, self.t1 = t0, t1
        self.q0, self.P0 = q0, P0
        self.v0 = (q1 - q0) / (t1 - t0)
        self.qdd = np.zeros_like(q0)
        m = P0.size // 2 if m is None else m  # m contacts: m normal rows, the rest tangent rows
        self.N, self.f = np.zeros(m), np.zeros(P0.size - m)
        self.NF = np.zeros(P0.size)
        self._names, self.full_modes, self.idx_t = names, full_modes, idx_t
        self.idx = idx_t
        self.modes = ()

    def names(self):
        return self._names

    def output(self, t, out):
        n = self.q0.size
        dt = t - self.t0
        out[:n] = self.q0[:, None] + self.v0[:, None] * dt
        out[n:2 * n] = self.v0[:, None]
        out[2 * n:] = self.P0[:, None]
        return self.N, self.f


def sum_up(integ, t, q, v, P, at, closed, sol, flight):
    """Jump over the rest of an accumulation of impacts on the contacts ``at`` (an
    :class:`~lcp.events.integrator.Integrator` whose bounce sequence is geometric; (q, v) the
    state right after the impact at t, ``flight`` the phase before it). Records the accumulation,
    its impulse and event; returns (t_inf, q_inf, v_inf, tail phase), or None while the bounces
    are still above the length tolerance (or the limit lies past the horizon)."""
    seq, model = integ.bounces, integ.model
    H = model.jac(q)
    at_a = np.array(at, dtype=int)
    uN = H[at_a] @ v
    times = [it[0] for it in seq.items]
    delta_next = (times[-1] - times[-2]) ** 2 / (times[-2] - times[-3])
    if float(np.max(np.abs(uN))) * delta_next / 4 > integ.gap_tol:
        return None  # bounces still visible: resolve them
    closed_form = None
    if integ.closed_form and at_a.size == 1:
        j = int(at_a[0])
        a = float(H[j] @ flight.qdd)
        if a < 0 < uN[0] and integ.e[j] < 1:
            closed_form = (2.0 * float(uN[0]) / -a, float(integ.e[j]))
    lim = seq.limit(closed_form)
    if lim is None or not lim[0] < integ.t_end:
        return None
    t_inf, q_inf, v_inf, method = lim
    contacts = tuple(sorted(set(at) | set(closed)))
    modes = sol.modes if sol is not None else ()
    stick = tuple(c for c, md in zip(closed, modes) if md == STICK)
    q_inf, v_inf = integ.projector.project(t_inf, q_inf, v_inf, contacts, contacts, stick)
    if min(model.gaps(q_inf).tolist()) < -integ.gap_tol:
        # the extrapolation moved another body into a contact (a bead flying just above the
        # column): no jump, the bounces are resolved one by one
        return None
    data = model.data(t, q, v)
    m, k = integ.m, at_a.size
    Hc = H[np.concatenate([at_a, m + at_a])]
    Pt = tail_impulse(data.A, Hc, data.G, v_inf - v, flight.end_acceleration(), t_inf - t)
    for jj, j in enumerate(at):
        integ.impulses.append(Impulse(float(t_inf), int(j), float(Pt[jj]), float(Pt[k + jj]), "accumulation",
                                      "limit of an accumulation of impacts"))
    integ.events.append(Event(float(t_inf), "accumulation", int(at[0]) if k == 1 else -1))
    integ.accumulations.append(Accumulation(float(t_inf), tuple(int(j) for j in at), int(seq.count),
                                            float(seq.first), method, tuple(float(x) for x in Pt[:k]),
                                            tuple(float(x) for x in Pt[k:])))
    tail = TailPhase(t, t_inf, q, q_inf, P, flight.names(), flight.full_modes, flight.idx_t)
    seq.reset()
    return t_inf, q_inf, v_inf, tail
