"""The event loop: decide the modes, integrate a smooth phase to its first event, project, repeat."""
from __future__ import annotations

import numpy as np

from lcp.contact.problem import OPEN, STICK
from lcp.result import SolverStats
from lcp.events.accumulation import BounceSequence, kinematic_accumulation, sum_up
from lcp.events.cubic_phase import CubicPhase
from lcp.events.event_location import too_many_events
from lcp.events.impacts import ImpactLaw
from lcp.events.model import EPS, all_finite, system_model, zero_test_scales
from lcp.events.modes import ModeSelector
from lcp.events.ode_phase import OdePhase
from lcp.events.options import CASCADE_ROUNDS, EVENT_STATUS_MESSAGES, EventOptions, SmoothIntegrator, cascade_round
from lcp.events.phases import ClosedFormPhase
from lcp.events.projection import StateProjector
from lcp.events.records import Event, Impact, Impulse, Phase, make_record

__all__ = ["CASCADE_ROUNDS", "Inconsistent", "Integrator"]



class Inconsistent(Exception):
    """No motion can be continued from the current state (reported as status -3)."""


class Integrator:
    """One event-driven integration of a System from (q0, v0) over [0, t_end]."""

    def __init__(self, system, q0, v0, t_end, options: EventOptions):
        self.sys = system
        self.model = system_model(system)
        if self.model.forcing is not None and not self.model.forcing.covers(0.0, t_end):
            # beyond the schedule's checked range: the System's own force, evaluated
            self.model = system_model(system, general=True)
        self.o = options
        self.t_end = t_end
        self.mu, self.e = system.mu, system.e
        n, m = system.n, system.n_contacts
        self.n, self.m = n, m
        if options.smooth is SmoothIntegrator.CLOSED_FORM and not (self.model.polynomial or self.model.cubic):
            raise ValueError("smooth='closed-form' needs constant mass, kinematics and forces "
                             "(System.is_constant and forces independent of q and v), or such a system "
                             "under a piecewise-constant or piecewise-affine control schedule")
        self.closed_form = self.model.polynomial and options.smooth is not SmoothIntegrator.SCIPY
        #: cubic closed-form phases (a force affine in t between breakpoints, lcp.events.cubic_phase)
        self.cubic = self.model.cubic and options.smooth is not SmoothIntegrator.SCIPY
        self.stats = SolverStats()
        self.events, self.impulses, self.phases = [], [], []
        model = self.model
        self.scales = zero_test_scales(model, q0, v0, t_end)
        V = self.scales["V"]
        self.vel_tol = options.tol * V
        self.gap_tol = options.tol * self.scales["L"]
        self.selector = ModeSelector(model, options, self.mu, self.stats, self.scales, t_end,
                                     self.gap_tol, self.vel_tol)
        self.impacts = ImpactLaw(model, self.mu, self.e, self.stats, options.impact_solver, t_end)
        self.projector = StateProjector(system, model)
        self.accumulations, self.impact_list = [], []
        self.nonunique = 0
        self.choice_moves = 0  # of them, phases whose motion depends on the choice (friction)
        self.penetrated = False  # a missed impact was said in the message
        self.notes = []  # said in the result's message
        self.bounces = BounceSequence()
        bp = getattr(system, "breakpoints", None)
        if bp is None or not len(bp):
            self.breakpoints = []
        else:
            bp = np.asarray(bp, dtype=float).ravel()
            self.breakpoints = np.unique(bp[(bp > 0) & (bp < t_end)]).tolist()
        self.selector.breakpoints = tuple(self.breakpoints)

    # --- the acceleration-level problem and the next mode
    def classify(self, t, q, v):
        """Contacts at the surface: (closed candidates, approaching ones, separating ones) as tuples
        of contact indices, and the local velocities u = H v + b (a list; b = 0 unless a contact moves)."""
        m = self.m
        if not m:
            return (), (), (), []
        gap = self.model.gaps(q, t).tolist()
        ul = self.model.local_velocity(t, q, v).tolist()
        gtol, vtol = self.gap_tol, self.vel_tol
        closed, approaching, separating = [], [], []
        for j in range(m):
            if gap[j] <= gtol:
                if abs(ul[j]) <= vtol:
                    closed.append(j)
                elif ul[j] < -vtol:
                    approaching.append(j)
                else:
                    separating.append(j)
        return tuple(closed), tuple(approaching), tuple(separating), ul

    def record_impulse(self, t, contacts, p, kind, reason):
        k = len(contacts)
        names = self.sys.contacts
        for jj, j in enumerate(contacts):
            if p[jj] != 0.0 or p[k + jj] != 0.0:
                self.impulses.append(Impulse(float(t), int(j), float(p[jj]), float(p[k + jj]), kind, reason))
                if kind == "impact":
                    self.impact_list.append(Impact(float(t), int(j), names[j].name, float(p[jj]), float(p[k + jj])))
        if not (self.events and self.events[-1].t == t and self.events[-1].kind == kind):
            self.events.append(Event(float(t), kind, int(contacts[0]) if k == 1 else -1))

    def decide(self, t, q, v):
        """Apply impulses where needed, then find the modes of the next phase.

        Returns (q, v, closed, solution, problem): the contacts at the surface (a tuple), the chosen
        solution of their acceleration-level problem (None if there are none) and that problem;
        raises Inconsistent when no motion can be continued.
        """
        if self.model.polynomial:
            out = self.selector.memo_decision(q, v)
            if out is not None:
                return out
        rounds = tangential = 0
        while True:
            data = self.model.data(t, q, v)
            closed, approaching, separating, ul = self.classify(t, q, v)
            if approaching:
                rounds += 1
                at, why = cascade_round(rounds, CASCADE_ROUNDS, t, closed, approaching, separating, self.notes)
                if at is None:
                    raise Inconsistent(why)
                at = np.array(at, dtype=int)
                out = self.impacts.solve(t, q, v, at, data)
                if out is None:
                    raise Inconsistent(f"the impact problem at t = {t:.17g} has no solution")
                dv, p, _ = out
                v = v + dv
                self.record_impulse(t, at, p, "impact", why)
                continue
            if not closed:
                return q, v, closed, None, None
            m, vtol = self.m, self.vel_tol  # slide_signs, inline
            slide = tuple([0.0 if abs(x) <= vtol else (1.0 if x > 0 else -1.0) for x in [ul[m + j] for j in closed]])
            groups, acc = self.selector.solve_modes(data, closed, slide)
            if len(groups) == 1:
                group = groups[0]
                sol = group[0] if len(group) == 1 else self.selector.lookahead(t, q, v, closed, slide, group)
                return q, v, closed, self.selector.leaving(t, q, v, closed, slide, sol, acc), acc
            self.stats.ambiguous_steps += int(len(groups) > 1)
            why = ("no consistent contact mode (Painleve: no solution)" if not groups else
                   f"{len(groups)} consistent contact modes (Painleve: non-uniqueness)")
            out = self.impacts.solve(t, q, v, closed, data)
            if out is None:
                raise Inconsistent(f"at t = {t:.17g}: {why}, and the impact problem has no solution")
            dv, p, imodes = out
            if np.max(np.abs(p)) > 1e-12 * self.scales["P"]:
                tangential += 1
                if tangential > 8:
                    raise Inconsistent(f"at t = {t:.17g}: impulses did not lead to a consistent contact mode")
                self.stats.fallbacks += 1
                v = v + dv
                self.record_impulse(t, closed, p, "tangential impact", why)
                continue
            if groups:
                # several motions and no impulse: follow the one Moreau-Jean's vanishing step picks
                if not any("motions were consistent" in note for note in self.notes):  # the first only
                    self.notes.append(f"At t = {t:.10g} {len(groups)} motions were consistent (non-unique "
                                      "solution); the integration followed the one a vanishing "
                                      "Moreau-Jean step selects.")
                for g in groups:
                    for s in g:
                        if all((im == OPEN) == (sm == OPEN) for im, sm in zip(imodes, s.modes)):
                            return q, v, closed, s, acc
                return q, v, closed, groups[0][0], acc
            raise Inconsistent(f"at t = {t:.17g}: {why}; the impulsive fallback gives no impulse")

    def new_phase(self, t, q, v, P, closed, sol, acc):
        """The smooth phase that starts at (t, q, v) with the closed contacts and modes of ``sol``
        (None: no closed contact); P holds the cumulative contact impulses."""
        m = self.m
        if self.closed_form:
            # The phase's modes, accelerations and forces depend on the solution only (a
            # polynomial system's mode problems are the same at every state): kept with it.
            cache = sol.ready if sol is not None else self.model.free_ready
            ready = cache.get(closed)
            if ready is None:
                closed_a = np.array(closed, dtype=int)
                modes = sol.modes if sol is not None else ()
                keep = [i for i, md in enumerate(modes) if md != OPEN]
                args = (self.model, t, q, v, P, closed_a[keep], tuple(modes[i] for i in keep), self.mu)
                Nm, fm = np.zeros(m), np.zeros(m)
                if sol is not None:
                    Nm[closed_a], fm[closed_a] = acc.forces(sol.p)  # zero for the contacts that open
                    start = (sol.qdd, Nm[closed_a[keep]], fm[closed_a[keep]])
                else:
                    start = (self.model.data(t, q, v).qdd_free, Nm[:0], fm[:0])
                ph = ClosedFormPhase(*args, start=start)
                cache[closed] = ph.ready()
            else:
                ph = ClosedFormPhase.from_ready(self.model, t, q, v, P, self.mu, ready)
        else:
            closed_a = np.array(closed, dtype=int)
            modes = sol.modes if sol is not None else ()
            keep = [i for i, md in enumerate(modes) if md != OPEN]
            args = (self.model, t, q, v, P, closed_a[keep], tuple(modes[i] for i in keep), self.mu)
            indeterminate = sol is not None and sol.nullity > 0
            if self.cubic and not indeterminate:
                # the accelerations and forces at t are solved again for the chosen modes: a tie
                # broken by looking ahead gives the solution at a later time, where the forces differ
                ph = CubicPhase(*args, force_tol=self.o.tol * self.scales.get("F", 0.0))
            else:
                ph = OdePhase(*args, options=self.o, scales=self.scales, indeterminate=indeterminate)
        return ph

    def run(self, q0, v0):
        o, m = self.o, self.m
        t, q, v = 0.0, q0.copy(), v0.copy()
        P = np.zeros(2 * m)
        status, message = 0, EVENT_STATUS_MESSAGES[0]
        run_phases = []
        short = 0
        breakpoints = list(self.breakpoints)
        last = None  # the last phase and the event that ended it
        while True:
            try:
                q, v, closed, sol, acc = self.decide(t, q, v)
            except Inconsistent as exc:
                status, message = -3, f"{EVENT_STATUS_MESSAGES[-3]} {exc}"
                break
            except FloatingPointError as exc:  # a force that is not finite at this state, named
                status, message = -2, f"{EVENT_STATUS_MESSAGES[-2]} At t = {t:.10g}: {exc}."
                break
            if last is not None and last[1] == "impact":
                jump = self.watch_bounces(t, q, v, P, closed, sol, last[0])
                if jump is not None:
                    t, q, v, tail = jump
                    run_phases.append(tail)
                    self.phases.append(make_record(Phase, float(tail.t0), float(tail.t1), tail.names(),
                                                   tail.integrator, 0))
                    last = None
                    continue
                if closed:
                    # contacts closed by the zero tests after the impact (a bounce below the velocity
                    # tolerance, or e = 0): the phase starts on them, as after an event; else their
                    # residual normal velocity carries the body off the contact through the phase
                    stick = tuple(c for c, md in zip(closed, sol.modes) if md == STICK)
                    q, v = self.projector.project(t, q, v, closed, closed, stick)
            elif last is not None:
                self.bounces.reset()
            while breakpoints and breakpoints[0] <= t:
                breakpoints.pop(0)
            t_stop = breakpoints[0] if breakpoints else self.t_end
            ph = self.new_phase(t, q, v, P, closed, sol, acc)
            closed, modes = ph.idx_t, ph.modes
            try:
                ev = ph.run(t_stop, t_stop < self.t_end)
            except FloatingPointError as exc:
                status, message = -2, f"{EVENT_STATUS_MESSAGES[-2]} Phase from t = {t:.10g}: {exc}"
                break
            run_phases.append(ph)
            unique = sol is None or sol.nullity == 0
            self.nonunique += not unique
            self.choice_moves += bool(sol is not None and (sol.motion_depends or ph.choice_moves))
            self.phases.append(make_record(Phase, float(ph.t0), float(ph.t1), ph.names(), ph.integrator,
                                           int(ph.nfev), unique))
            counts = self.stats.mode_counts
            for name in ph.names():
                counts[name] += 1
            if ev is None:
                if t_stop >= self.t_end:
                    break
                ev = (t_stop, "breakpoint", -1)  # the forces jump: decide again
            te, kind, j = ev
            last = (ph, kind)
            q, v, P = ph.end_state()
            stick = tuple(c for c, md in zip(closed, modes) if md == STICK)
            if kind == "stop":
                stick += (j,)
            gap_rows = closed if kind != "impact" else closed + (j,)
            q, v = self.projector.project(te, q, v, gap_rows, closed, stick)
            if m and not self.penetrated and min(self.model.gaps(q, te).tolist()) < -self.gap_tol:
                # no silent success: an open contact found penetrated was never landed on
                gap = self.model.gaps(q, te)
                j_p = int(np.argmin(gap))
                self.penetrated = True
                self.notes.append(f"At t = {te:.10g} contact {self.sys.contacts[j_p].name!r} penetrates by "
                                  f"{-gap[j_p]:.3g} (an impact was missed): the motion after it is not reliable.")
            if not (all_finite(q) and all_finite(v)):
                status, message = -2, f"{EVENT_STATUS_MESSAGES[-2]} At t = {te:.10g}."
                break
            self.events.append(make_record(Event, float(te), kind, int(j)))
            short = short + 1 if te - t <= 64 * EPS * max(1.0, abs(te)) else 0
            t = te
            stop_message = too_many_events(len(self.events), short, t, o.max_events, EVENT_STATUS_MESSAGES[-4])
            if stop_message:
                status, message = -4, stop_message
                break
        self.stats.steps = len(run_phases)
        self.stats.free_steps = sum(1 for ph in run_phases if not ph.idx_t)
        return run_phases, status, message, t

    def watch_bounces(self, t, q, v, P, closed, sol, flight):
        """After an impact at t (state (q, v) its right limit, ``flight`` the phase that ended
        with it): record it, and when the impacts form an accumulation whose bounces are below
        the length tolerance, jump to its limit. Returns (t_inf, q_inf, v_inf, tail phase) or None."""
        at = set()
        for imp in reversed(self.impulses):  # the impulses of this instant are the last ones
            if imp.t != t:
                break
            if imp.kind == "impact":
                at.add(imp.contact)
        at = tuple(sorted(at))
        if not at:
            self.bounces.reset()
            return None
        self.bounces.push(t, at, q, v, (closed, sol.modes if sol is not None else ()))
        if not self.bounces.geometric():
            return None
        if self.model.kinematic:
            return kinematic_accumulation(self.notes, t)
        if self.model.moving:
            # The jump to the limit is the geometric series of a fixed obstacle (constant relative
            # acceleration between bounces); under a moving one (a table's acceleration varies
            # between bounces) it is not exact: the bounces are resolved one by one, down to the
            # velocity tolerance where the zero tests close the contact.
            if not any("moving contact" in note for note in self.notes):
                names = ", ".join(repr(self.sys.contacts[j].name) for j in at)
                self.notes.append(f"From t = {t:.10g} the impacts on the moving contact(s) {names} accumulate: "
                                  "resolved impact by impact (no extrapolation to their limit).")
            return None
        return sum_up(self, t, q, v, P, at, closed, sol, flight)

