"""The order-two scheme (``scheme="order2"``): RATTLE where the motion is smooth, Moreau-Jean elsewhere.

Holds :func:`run_second_order`, a Python loop that takes each step by one of three one-step methods:

- **free steps** (no contact closes in the step, none carried a load in the previous one): a
  RATTLE step (:class:`~lcp.timestepping.rattle.RattleStep`: velocity Verlet with the bilateral
  constraints at the position level by SHAKE and at the velocity level by RATTLE), of order two
  for q-dependent mass matrices, velocity-dependent forces and nonlinear or rheonomic
  constraints, and symplectic for conservative systems with a constant mass matrix (no secular
  energy drift, the period of a pendulum to O(h^2));
- **closed steps** (every contact loaded in the previous step is closed and persistent: loaded
  with p_N > 0 and no impact or bounce in that step): a RATTLE step with those contacts held as
  constraints (:class:`~lcp.timestepping.closed_rattle.ClosedRattle`): a frictionless or sliding
  contact by its gap (the sliding friction -mu lambda_N sign(u_T) coupled to the normal
  multiplier), a sticking one (|p_T| < mu p_N strictly) by its gap and its tangent. After the
  step: every held normal force >= 0 (else lift-off: the step split where the force crosses zero,
  or taken without that contact, see :func:`_held_step`), every stick strictly inside the cone at
  both ends, every slide still sliding its way, no other contact closing; where any of these
  fails, the step is taken again by Moreau-Jean. Only where Moreau-Jean's own step is of order one
  (a q-dependent mass matrix or contact rows): on a constant system Moreau-Jean at theta = 1/2 is
  already of order two (exact under constant forces) and keeps its steps; spatial contacts too;
- **contact steps** (otherwise: a contact closes, an impact, a stick-slip transition, a stop):
  exactly the Moreau-Jean step of :mod:`lcp.timestepping.python_loop` (free velocity, activation,
  the one-step contact problem, impulses at the velocity level, restitution, Kahan sums, position
  projection). Its answer names the contacts to hold in the next step.

The choice: a step with held contacts tries the closed step first; a step after a loaded one
that holds nothing asks Moreau-Jean's rule (its hysteresis keeps a resting contact active), and
where it activates nothing, the step is a free RATTLE step again; a free step whose end point
closes a gap (g_j(q1) <= CLOSE_ULPS eps s_j, the activation rule's tolerance) is discarded and
taken by Moreau-Jean from the same state, with those contacts active besides the ones Moreau-Jean's
own rule activates. So impacts, stick-slip transitions, stops and restitution are Moreau-Jean's,
and a constant system's run (Jean-Pratt, a block on an incline) is Moreau-Jean's run to the last
bit. Imports the step modules of :mod:`lcp.timestepping` (as
:mod:`~lcp.timestepping.python_loop` does), :mod:`lcp.contact` and :mod:`lcp.result`; never the
path choice or anything above :mod:`lcp.timestepping`.
"""
from __future__ import annotations

import math

from dataclasses import dataclass, field

import numpy as np

from lcp.contact.problem import MODE_NAMES, SLIDE_NEG, SLIDE_POS, STICK
from lcp.result import STATUS_MESSAGES, SimulationResult
from lcp.timestepping.activation import CLOSE_ULPS, EPS, Activation
from lcp.timestepping.assembly import kahan_add
from lcp.timestepping.closed_rattle import ClosedRattle, ClosedStep
from lcp.timestepping.contact_step import ContactStep
from lcp.timestepping.outcome import RunNotes, loop_result, projection_failure, record_impacts
from lcp.timestepping.projection import violation_function
from lcp.timestepping.rattle import RattleStep

__all__ = ["SCHEMES", "run_second_order"]

#: the time-stepping schemes of MoreauJeanOptions.scheme
SCHEMES = ("moreau-jean", "order2")


def run_second_order(system, asm, q0, v0, h: float, th: float, n_steps: int, every: int, solver, fallback: bool,
                     proj, tol: float) -> SimulationResult:
    """The order-two scheme (module docstring); arguments as :func:`lcp.timestepping.python_loop.run_python_loop`,
    and ``tol`` the relative tolerance of SHAKE (``projection_tol``).

    The contact steps are theta-method steps with the run's ``theta`` (1/2 by default).
    """
    if getattr(system, "control_schedule", None) is not None:
        raise ValueError("scheme='order2' does not take a control schedule yet: use scheme='moreau-jean'")
    if n_steps // every > 50_000_000:
        raise ValueError(f"{n_steps // every} saved states would not fit in memory: raise save_every")
    m, n = system.n_contacts, system.n
    e = system.e
    names = [c.name for c in system.contacts]
    dims = system.tangent_dims if system.is_spatial else None
    rattle = RattleStep(system, tol)
    # |g_j(0)|: the constant term of a gap, whose rounding the closing test must allow for
    g0 = np.abs(system.gaps(np.zeros(n))) if m else np.zeros(0)

    n_saved = n_steps // every
    Q = np.empty((n_saved + 1, n))
    V = np.empty((n_saved + 1, n))
    PN = np.zeros((n_saved, m))
    PT = np.zeros((n_saved, system.n_tangent))
    modes = np.full((n_saved, m), -1, dtype=np.int8)
    Q[0], V[0] = q0, v0
    notes = RunNotes()
    stats, impacts = notes.stats, notes.impacts
    status, message = 0, STATUS_MESSAGES[0]
    q, v = q0.copy(), v0.copy()
    cq, cv = np.zeros(n), np.zeros(n)
    step = ContactStep(system, asm, solver, fallback, notes)
    activation = Activation(asm, m)
    closed = np.zeros(m, dtype=bool)
    # contacts held closed: j -> (sliding direction, sticks), tried as constraints of the next step
    # where Moreau-Jean's own step is of order one (a q-dependent mass matrix or contact rows)
    holds = bool(m) and not system.is_spatial and not (system.mass_is_constant and system.kinematics_is_constant)
    held, trend = {}, {}  # trend: contact -> its mean force over the previous (held) step
    closed_rattle = ClosedRattle(system, tol) if holds else None
    if proj is not None:
        from lcp.model.start import system_length

        ell = system_length(system, q0)  # the system's length, part of the projection's tolerance
    viol_fn = violation_function(system)
    worst = viol_fn(q0[None, :], np.zeros(1)) if system.n_bilateral else 0.0
    k_done = 0
    for k in range(n_steps):
        tk = k * h
        row = (k + 1) // every - 1 if (k + 1) % every == 0 else -1
        data = None  # Moreau-Jean's step data, once computed
        forced = None  # contacts RATTLE's end point closed, or held ones whose step was refused
        taken = False  # the step taken by a closed-contact RATTLE step
        means, trend = trend, {}
        if held and not _loaded_elsewhere(activation.loaded, held):
            took = _held_step(system, closed_rattle, rattle, held, means, tk, q, v, h, g0)
            stats.projection_iterations += took.iterations
            if took.ok:
                taken = True
                worst = max(worst, took.violation)
                q, v = took.q1, took.v1
                cq, cv = np.zeros(n), np.zeros(n)
                held, trend = took.held, took.means
                if took.pn:
                    stats.closed_steps += 1
                    idx = np.array(sorted(took.pn))
                    pn = np.array([took.pn[j] for j in idx.tolist()])
                    md = np.array([took.modes[j] for j in idx.tolist()], dtype=np.int8)
                    activation.carried(idx[_held_mask(idx, held)], pn[_held_mask(idx, held)])
                    if not held:
                        activation.release()
                    if row >= 0:
                        PN[row, idx] = pn
                        PT[row, system.tangent_offsets[idx]] = [took.pt[j] for j in idx.tolist()]
                        modes[row, idx] = md
                    for code in md.tolist():
                        stats.mode_counts[MODE_NAMES[code]] += 1
                else:
                    stats.free_steps += 1
                    activation.release()
            else:  # a slip, a stop, another contact closing or SHAKE stuck: Moreau-Jean's step
                forced = np.union1d(sorted(held), took.closing).astype(int)
                data = _mj_data(asm, tk, q, v, activation, h, th)
                if isinstance(data, str):
                    status, message = -2, f"{STATUS_MESSAGES[-2]} Step {k} (t = {tk:.10g}): {data}."
                    break
        elif m and activation.loaded.any():
            data = _mj_data(asm, tk, q, v, activation, h, th)
            if isinstance(data, str):
                status, message = -2, f"{STATUS_MESSAGES[-2]} Step {k} (t = {tk:.10g}): {data}."
                break
            if data[-1].size == 0:
                activation.release()
                closed[:] = False
                data = None
        if data is None and not taken:
            q1, v1, gap1, gsize1, ok, iters, viol = rattle(tk, q, v, h)
            stats.projection_iterations += iters
            if not ok:
                status = -5
                message = (f"{STATUS_MESSAGES[-5]} Step {k} (t = {tk + h:.10g}): SHAKE left a constraint "
                           f"violation {viol:.3g} after {iters} Newton iterations (tolerance {tol:g} relative).")
                break
            closing = gap1 <= (CLOSE_ULPS * EPS) * (gsize1 + g0) if m else None
            if m and closing.any():
                forced = np.flatnonzero(closing)
                data = _mj_data(asm, tk, q, v, activation, h, th)
                if isinstance(data, str):
                    status, message = -2, f"{STATUS_MESSAGES[-2]} Step {k} (t = {tk:.10g}): {data}."
                    break
            else:
                stats.free_steps += 1
                worst = max(worst, viol)
                q, v = q1, v1
                cq, cv = np.zeros(n), np.zeros(n)
        if data is not None:  # the Moreau-Jean step, as in the Python loop
            dvf, SHt, W, gap, H, uN_minus, uN_free, active = data
            if forced is not None:
                active = np.union1d(active, forced).astype(int)
            vfree = v + dvf
            dv, p, md, cols, sol = step.solve(k, tk, active, v, vfree, dvf, SHt, W, H, uN_minus)
            if dv is None:
                status = -1
                message = (f"{STATUS_MESSAGES[-1]} Step {k} (t = {tk:.10g}), solver '{solver.name}': "
                           f"{sol.message}")
                break
            pa = p[: active.size]
            n_impacts = len(impacts)
            if not activation.all_loaded:
                record_impacts(impacts, tk, h, active, pa, p[active.size:], activation.loaded, gap, uN_minus,
                               uN_free, names, dims)
            activation.carried(active, pa)
            closed[:] = False
            closed[active] = (pa > 0) & ((e[active] == 0) | (uN_minus[active] >= 0))
            if holds:
                hit = {imp.contact for imp in impacts[n_impacts:]}
                held = _held_after(system, active, pa, p[active.size:], md, closed, hit)
            if row >= 0:
                PN[row, active] = pa
                PT[row, cols] = p[active.size:]
                modes[row, active] = md
            for code in md:
                stats.mode_counts[MODE_NAMES[int(code)]] += 1
            # compensated sums over a run of Moreau-Jean steps, as in the Python loop (a RATTLE step
            # or a projection restarts them)
            v_new, cv = kahan_add(v, dv, cv)
            q, cq = kahan_add(q, h * ((1 - th) * v + th * v_new), cq)
            v = v_new
            if proj is not None and math.isfinite(float(q.sum())):
                # as in the Python loop: a contact separating after the step is opening, neither held
                # nor pushed; closed in this step: loaded and not opening
                HN = H[:m]
                opening = HN @ v > (CLOSE_ULPS * EPS) * (np.abs(HN) @ np.abs(v))
                np.logical_and(closed, ~opening, out=closed)  # closed: loaded, not bounced (above)
                q_proj, ok, iters, viol = proj.project(tk + h, q, closed, opening, ell + h * np.abs(v))
                stats.projections += 1
                stats.projection_iterations += iters
                if not ok or not math.isfinite(viol):
                    status, message = -5, projection_failure(k, tk + h, viol, iters, proj.tol)
                    break
                q, cq = q_proj, np.zeros(n)
                worst = max(worst, viol)
        elif not taken:
            held = {}
        if not math.isfinite(float(q.sum()) + float(v.sum())) and not (np.isfinite(q).all() and np.isfinite(v).all()):
            status = -2
            message = f"{STATUS_MESSAGES[-2]} Step {k} (t = {tk:.10g})."
            break
        if row >= 0:
            Q[row + 1], V[row + 1] = q, v
        k_done = k + 1
    # the violation: measured where every step was projected or SHAKE'n, else from the saved states
    res = loop_result(system, Q, V, PN, PT, modes, k_done, every, h, th, status, message, notes, solver.name,
                      worst, bool(proj is not None or (system.n_bilateral and not m)))
    res.scheme = "order2"
    return res


def _mj_data(asm, tk, q, v, activation, h, th):
    """Moreau-Jean's step data and active set at (tk, q, v): (dv_free, S H', W, gaps, H, u_N-,
    u_N,free, active), or the error message of a singular iteration matrix."""
    try:
        dvf, SHt, W, gap, H = asm.at(tk, q, v)
    except FloatingPointError as exc:
        return str(exc)
    m = activation.m
    uN_minus = H[:m] @ v
    uN_free = H[:m] @ (v + dvf)
    active = activation(q, gap, H, uN_minus, uN_free, h, th)
    return dvf, SHt, W, gap, H, uN_minus, uN_free, active


def _loaded_elsewhere(loaded, held) -> bool:
    """Whether a contact carried a load in the previous step without being held closed (an impact,
    a bounce): then the step is Moreau-Jean's."""
    return bool(loaded.any()) and any(j not in held for j in np.flatnonzero(loaded).tolist())


def _held_after(system, active, pN, pT, md, closed, hit) -> dict:
    """The contacts a Moreau-Jean step leaves closed and persistent, to be held as constraints of
    the next step: loaded (p_N > 0), not bounced (``closed``), no impact in the step (``hit``); a
    frictionless one as such, a sticking one strictly inside the cone (|p_T| < mu p_N), a sliding
    one with its direction."""
    mu = system.mu
    held = {}
    for i, j in enumerate(active.tolist()):
        if not closed[j] or j in hit:
            continue
        if mu[j] == 0:
            held[j] = (0, False)
        elif md[i] == STICK and abs(pT[i]) < mu[j] * pN[i]:
            held[j] = (0, True)
        elif md[i] == SLIDE_POS:
            held[j] = (1, False)
        elif md[i] == SLIDE_NEG:
            held[j] = (-1, False)
    return held


def _verdict(system, key, out, g0):
    """Whether a closed-contact RATTLE step is what it assumed: (the other contacts whose gap closes
    at its end, the held contacts whose normal multiplier is < 0 at either end (lifting off), and
    whether a stick left the cone or a slide stopped)."""
    nb, K = system.n_bilateral, len(key)
    lam, mu_, uT = out.lam, out.mu, out.uT
    lamN, muN = lam[nb:nb + K], mu_[nb:nb + K]
    lifting = [key[c][0] for c in np.flatnonzero((lamN < 0) | (muN < 0)).tolist()]
    bad = False
    i = nb + K
    mu, off = system.mu, system.tangent_offsets
    for c, (j, s, stick) in enumerate(key):
        if stick:
            bad = bad or not (abs(lam[i]) < mu[j] * lamN[c] and abs(mu_[i]) < mu[j] * muN[c])
            i += 1
        elif s:
            bad = bad or not s * uT[off[j]] > 0
    closing = out.gap <= (CLOSE_ULPS * EPS) * (out.gsize + g0)
    closing[[j for j, _, _ in key]] = False
    return np.flatnonzero(closing), lifting, bad


def _held_mask(idx, held):
    """Mask of the contacts of ``idx`` that are held."""
    return np.array([j in held for j in idx.tolist()], dtype=bool)


@dataclass
class _Taken:
    """A step with contacts held closed: whether it was taken (ok), its end state, the contacts
    still held after it, each held contact's impulses and mode over the step, SHAKE's work, the
    violation, and (where refused) the other contacts found closing."""

    ok: bool
    q1: np.ndarray = None
    v1: np.ndarray = None
    held: dict = field(default_factory=dict)
    pn: dict = field(default_factory=dict)
    pt: dict = field(default_factory=dict)
    modes: dict = field(default_factory=dict)
    iterations: int = 0
    violation: float = 0.0
    closing: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    means: dict = field(default_factory=dict)


def _held_step(system, closed_rattle, rattle, held, trend, tk, q, v, h, g0) -> _Taken:
    """One step with the ``held`` contacts as constraints (module docstring).

    Lift-off: RATTLE's two multipliers both approximate the force at the step's midpoint (to O(h);
    their mean to O(h^2)), so the force at the step's ends is taken from the mean of this step and
    of the previous one where that held the contact too (``trend``: contact -> mean force), else
    from the two multipliers. Where the end force is < 0 and the start force >= 0, the step is
    split where the force, linear in time, crosses zero: held up to there, released after, each
    part a RATTLE step. Where the start force is < 0 already, the step is taken again without that
    contact. Both keep order two through the lift-off (the force vanishes at the switch), where
    Moreau-Jean's step, imposing H_N(q_k) v+ >= 0 with the normal of the step's start, misses the
    curvature's h |v|^2 / R in the normal velocity and is of order one after it; and no step's net
    normal impulse pulls. Any other objection (a stick leaving the cone, a slide stopping, another
    contact closing, SHAKE stuck, a second lift-off in the part after a split): ``ok`` False, and
    the step is Moreau-Jean's.
    """
    taken = _Taken(False)
    t, qk, vk, left, attempt = tk, q, v, h, dict(held)
    nb = system.n_bilateral
    for _ in range(3):  # at most: the whole step, the part up to lift-off, the rest
        key = tuple((j,) + attempt[j] for j in sorted(attempt))
        out = closed_rattle(key, t, qk, vk, left) if key else _free_as_closed(rattle, t, qk, vk, left)
        taken.iterations += out.iterations
        if not out.ok:
            return taken
        closing, lifting, bad = _verdict(system, key, out, g0)
        if closing.size or bad:
            taken.closing = closing
            return taken
        K = len(key)
        lam, mu_ = out.lam[nb:nb + K], out.mu[nb:nb + K]
        mean = 0.5 * (lam + mu_)
        split, release = None, ()
        if left == h:
            start, end = lam.copy(), mu_.copy()
            for c, (j, _, _) in enumerate(key):
                if j in trend:  # the force at the ends from the means' trend (O(h^2))
                    half = 0.5 * (mean[c] - trend[j])
                    start[c], end[c] = mean[c] - half, mean[c] + half
            lifting = [key[c][0] for c in np.flatnonzero((start < 0) | (end < 0)).tolist()]
            if lifting:
                c = [i for i, (j, _, _) in enumerate(key) if j in lifting]
                if np.all(start[c] >= 0):  # lift-off inside the step: the crossing
                    tau = float(np.min(start[c] / (start[c] - end[c])))
                    if tau >= 1 - 1e-3:  # at the step's end: held over it, released after
                        split, release = 1.0, lifting
                    elif tau > 1e-3:
                        split = tau
                if split is None:
                    # lift-off at the start: the step without those contacts
                    attempt = {j: attempt[j] for j in attempt if j not in lifting}
                    continue
                if split == 1.0:
                    split = None
            if split is not None:
                out = closed_rattle(key, t, qk, vk, split * h)
                taken.iterations += out.iterations
                if not out.ok:
                    return taken
                closing, _, bad = _verdict(system, key, out, g0)
                if closing.size or bad:
                    taken.closing = closing
                    return taken
        elif lifting:  # a second lift-off in the rest of a split step
            return taken
        _add_impulses(system, key, out, split * h if split else left, taken)
        taken.violation = max(taken.violation, out.violation)
        if split is None:
            taken.ok, taken.q1, taken.v1 = True, out.q1, out.v1
            taken.held = {j: attempt[j] for j in attempt if j not in release}
            if left == h:
                taken.means = {j: float(mean[c]) for c, (j, _, _) in enumerate(key)}
            return taken
        t, qk, vk, left = t + split * h, out.q1, out.v1, (1 - split) * h
        attempt = {j: attempt[j] for j in attempt if j not in lifting}
    return taken


def _add_impulses(system, key, out, hh, taken):
    """Add a (part-)step's impulses and modes of its held contacts to ``taken``."""
    pn, pt, md = _closed_impulses(system, key, out, hh)
    for c, (j, _, _) in enumerate(key):
        taken.pn[j] = taken.pn.get(j, 0.0) + float(pn[c])
        taken.pt[j] = taken.pt.get(j, 0.0) + float(pt[c])
        taken.modes[j] = int(md[c])


def _free_as_closed(rattle, tk, q, v, h) -> ClosedStep:
    """The contact-free RATTLE step as a :class:`ClosedStep` with no contact held."""
    q1, v1, gap, gsize, ok, iters, viol = rattle(tk, q, v, h)
    nb = rattle.nb
    return ClosedStep(q1, v1, np.zeros(nb), np.zeros(nb), gap, gsize, np.zeros(0), ok, iters, viol)


def _closed_impulses(system, key, out, h):
    """Impulses and modes of a closed-contact RATTLE step, per held contact (key order): p_N the
    trapezoidal h (lambda + mu)/2, p_T the sliding friction -mu s p_N or the stick's trapezoidal
    tangent multiplier (0 for a frictionless contact); mode stick, or slide by the sign of u_T."""
    nb, K = system.n_bilateral, len(key)
    pn = 0.5 * h * (out.lam[nb:nb + K] + out.mu[nb:nb + K])
    pt = np.zeros(K)
    md = np.empty(K, dtype=np.int8)
    i = nb + K
    for c, (j, s, stick) in enumerate(key):
        if stick:
            pt[c] = 0.5 * h * (out.lam[i] + out.mu[i])
            md[c] = STICK
            i += 1
            continue
        pt[c] = -system.mu[j] * s * pn[c]
        u = out.uT[system.tangent_offsets[j]]
        md[c] = SLIDE_POS if u > 0 else SLIDE_NEG if u < 0 else STICK
    return pn, pt, md
