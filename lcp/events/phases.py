"""Smooth phases: fixed contact modes between two events, integrated in closed form when possible.

Between events every contact keeps one mode (open, stick, slide+, slide-) and the motion is smooth.
When the phase dynamics is polynomial in t (constant mass matrix, kinematics and forces:
``System.is_constant`` and no state dependence of the forces) each mode has constant accelerations,
so positions are quadratic in t and every event is the root of a linear or quadratic polynomial
(:mod:`lcp.events.event_location`). Under a force affine in t (a control schedule) the phases are
cubic (:mod:`lcp.events.cubic_phase`); other phases are integrated by SciPy
(:mod:`lcp.events.ode_phase`).
"""
from __future__ import annotations

import functools
import math

import numpy as np

from lcp.contact.problem import MODE_NAMES, OPEN, SLIDE_NEG, SLIDE_POS
from lcp.events.event_location import first_landing, first_stop
from lcp.events.indeterminate import branch_forces, force_margin
from lcp.events.model import EPS, coordinate_rows, mass_projection
from lcp.events.modes import AccelProblem, PhaseBranch, null_space_moves

__all__ = ["phase_static", "SmoothPhase", "ClosedFormPhase", "closed_form_output"]


@functools.lru_cache(maxsize=4096)
def phase_static(m: int, idx: tuple, modes: tuple) -> tuple:
    """What a phase needs from its closed contacts and modes alone (shared, read-only arrays):
    (modes, idx, slide signs, open contacts, modes of all contacts, mode names, sliding (j, sign, row of
    H_T,j) triples, idx as a tuple)."""
    idx_a = np.array(idx, dtype=int)
    slide = np.array([1.0 if md == SLIDE_POS else (-1.0 if md == SLIDE_NEG else 0.0) for md in modes])
    closed = set(idx)
    open_idx = np.array([j for j in range(m) if j not in closed], dtype=int)
    full = np.full(m, OPEN, dtype=np.int8)
    full[idx_a] = modes
    names = tuple(MODE_NAMES[int(c)] for c in full)
    sliding = tuple((j, s, m + j) for j, s in zip(idx, slide.tolist()) if s != 0)
    for arr in (idx_a, slide, open_idx, full):
        arr.setflags(write=False)
    return modes, idx_a, slide, open_idx, full, names, sliding, idx


class SmoothPhase:
    """Common part of a smooth phase: fixed closed set, slide signs and stick set."""

    #: the forces of this phase's modes are not unique (redundant contacts): least-norm admissible
    #: forces are reported, and the phase ends when no admissible forces remain
    indeterminate = False
    #: of an indeterminate phase: its motion depends on the choice of forces somewhere (friction
    #: growing with the squeeze between opposed contacts, :func:`~lcp.events.modes.null_space_moves`)
    choice_moves = False

    def __init__(self, model, t0, q0, v0, P0, idx, modes, mu, static=None):
        self.model = model
        self.t0, self.q0, self.v0, self.P0 = t0, q0, v0, P0
        self.mu = mu
        if static is None:  # modes: per closed contact, never OPEN
            static = phase_static(model.m, tuple(np.asarray(idx, dtype=int).tolist()), tuple(map(int, modes)))
        self.static = static
        (self.modes, self.idx, self.slide, self.open_idx, self.full_modes, self._names, self._sliding,
         self.idx_t) = static

    def end_at(self, best, t_stop):
        """End the phase at its first event ``best`` = (dt, kind, contact) if that comes before
        t_stop (returns (t_event, kind, contact)), else at t_stop (returns None)."""
        dt, kind, j = best
        if not self.t0 + dt < t_stop:
            self.t1 = t_stop
            return None
        self.t1 = self.t0 + dt
        return self.t1, kind, j

    def names(self) -> tuple:
        return self._names

    #: the phase's branch, set up on the first determinate evaluation (:class:`~lcp.events.modes.PhaseBranch`)
    _branch = None

    def accel(self, data):
        """(qdd, N, f) of the phase's modes at a state (its data)."""
        if not self.indeterminate:
            if self._branch is None:
                self._branch = PhaseBranch(self.model.m, self.idx, self.slide, self.mu)
            out = self._branch(data)
            if out is None:
                raise FloatingPointError("singular contact branch in a smooth phase")
            return out
        acc = AccelProblem(data, self.idx, self.slide, self.mu)
        bf = branch_forces(acc.pb, acc.check_modes(self.modes), acc.branch_modes(self.modes))
        p = None if bf is None else bf.p  # not admissible past the phase's end: its event
        if bf is not None and not self.choice_moves:
            self.choice_moves = null_space_moves(acc, bf.Z)
        if p is None:
            raise FloatingPointError("singular contact branch in a smooth phase")
        N, f = acc.forces(p)
        return acc.qdd(p), N, f

    def margin(self, data) -> tuple[float, np.ndarray, list]:
        """Force margin of the phase's modes at a state (see
        :func:`~lcp.events.indeterminate.force_margin`): zero where the phase must end."""
        acc = AccelProblem(data, self.idx, self.slide, self.mu)
        return force_margin(acc.pb, acc.check_modes(self.modes), acc.branch_modes(self.modes))


class ClosedFormPhase(SmoothPhase):
    """Constant accelerations: q = q0 + v0 dt + qdd dt^2/2; events are polynomial roots."""

    integrator = "closed-form"
    nfev = 0

    def __init__(self, *args, start=None):
        super().__init__(*args)
        self.H = self.model.H
        if start is None:
            data = self.model.data(self.t0, self.q0, self.v0)
            self.qdd, N, f = self.accel(data)
        else:  # the accelerations and forces the mode decision already solved for
            self.qdd, N, f = start
        # The constraints of this mode hold at the acceleration level up to rounding (1e-16 |qdd|),
        # which dt^2/2 amplifies over long phases; one mass-metric projection makes it eps^2.
        rows = [self.model.G, self.model.H[self.idx], self.model.H[self.model.m + self.idx[self.slide == 0]]]
        J = np.vstack(rows)
        if J.shape[0]:
            self.qdd = self.qdd - mass_projection(self.model.A, J, J @ self.qdd)
            for i, val in coordinate_rows(J, np.zeros(J.shape[0])):
                self.qdd[i] = val  # a flat contact at rest stays exactly at rest
        m = self.model.m
        self.N = np.zeros(m)
        self.f = np.zeros(m)
        self.N[self.idx], self.f[self.idx] = N, f
        self.NF = np.concatenate([self.N, self.f])
        # per sliding contact: (j, sign, H_T,j, tangential acceleration H_T,j qdd)
        self._slide_rows = tuple((j, s, self.H[row], self.H[row] @ self.qdd) for j, s, row in self._sliding)

    def ready(self) -> tuple:
        """What a later phase of the same modes and accelerations reuses (:meth:`from_ready`)."""
        for arr in (self.qdd, self.N, self.f, self.NF):
            arr.setflags(write=False)
        return self.static, (self.H, self.qdd, self.N, self.f, self.NF, self._slide_rows)

    @classmethod
    def from_ready(cls, model, t0, q0, v0, P0, mu, ready):
        """The phase of the same modes and accelerations as the one ``ready`` came from."""
        ph = cls.__new__(cls)
        ph.model, ph.t0, ph.q0, ph.v0, ph.P0, ph.mu = model, t0, q0, v0, P0, mu
        ph.static, (ph.H, ph.qdd, ph.N, ph.f, ph.NF, ph._slide_rows) = ready
        (ph.modes, ph.idx, ph.slide, ph.open_idx, ph.full_modes, ph._names, ph._sliding, ph.idx_t) = ph.static
        return ph

    def run(self, t_stop, breakpoint=False):
        """First event before t_stop: (t_event, kind, contact) or None (the forces are constant:
        a breakpoint changes nothing before it)."""
        H = self.H
        best = (math.inf, None, -1)
        for j, s, Hrow, a in self._slide_rows:
            dt = first_stop(Hrow @ self.v0, a, s)
            if dt < best[0]:
                best = (dt, "stop", int(j))
        if len(self.open_idx):
            model = self.model
            gap = model.gaps(self.q0)
            # a gap at the rounding level of its own evaluation is zero (a contact just left):
            # divided by a small departure speed it would shift the landing time
            noise = 8 * EPS * (np.abs(model.gap0) + np.abs(model.HN) @ np.abs(self.q0))
            for j in self.open_idx:
                g0 = gap[j] if abs(gap[j]) > noise[j] else 0.0
                dt = first_landing(g0, H[j] @ self.v0, H[j] @ self.qdd)
                if dt < best[0]:
                    best = (dt, "impact", int(j))
        return self.end_at(best, t_stop)

    def end_acceleration(self):
        """Acceleration at the end of the phase (constant here)."""
        return self.qdd

    def end_state(self):
        dt = self.t1 - self.t0
        v1 = self.v0 + dt * self.qdd
        q1 = self.q0 + dt * 0.5 * (self.v0 + v1)  # exact for constant acceleration, no cancellation
        return q1, v1, self.P0 + dt * self.NF

    def output(self, t, out):
        """Write (q, v, cumulative impulses) at the times t into the columns of ``out``
        (shape (2n + 2m, t.size)); return the forces (N, f), the same at every time."""
        closed_form_output([self], t, [t.size], out)
        return self.N, self.f


def closed_form_output(phases, t, counts, out):
    """Closed-form phases, consecutive, on consecutive output times t (``counts[i]`` of them in
    phase i): write the rows (q, v, cumulative impulses) of ``out`` (shape (2n + 2m, t.size)).

    Elementwise q0 + dt v0 + dt^2/2 qdd, v0 + dt qdd and P0 + dt (N, f), evaluated in that order
    (dt = t - t0), with each phase's constants repeated over its columns: long contiguous rows
    for every phase at once, rather than NumPy's slow broadcasting of short ones.
    """
    n, r = phases[0].q0.size, out.shape[0]
    Y0 = np.concatenate([x for ph in phases for x in (ph.q0, ph.v0, ph.P0)]).reshape(len(phases), r).T
    Y1 = np.concatenate([x for ph in phases for x in (ph.v0, ph.qdd, ph.NF)]).reshape(len(phases), r).T
    if len(phases) == 1:
        dt = t - phases[0].t0
    else:
        dt = t - np.array([ph.t0 for ph in phases]).repeat(counts)
        Y0, Y1 = Y0.repeat(counts, axis=1), Y1.repeat(counts, axis=1)
    h = 0.5 * dt
    h *= dt
    quad = h * Y1[n:2 * n]  # dt^2/2 qdd
    np.multiply(dt, Y1, out=out)
    np.add(Y0, out, out=out)
    np.add(out[:n], quad, out=out[:n])
