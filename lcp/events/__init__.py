"""Event-driven integration with exact mode switches (the ``method="event"`` branch of :func:`lcp.simulate`).

Between events every contact keeps one mode (open, stick, slide+, slide-) and the motion is smooth.
Each smooth phase is integrated

- in **closed form** when the phase dynamics is polynomial in t: constant mass matrix, kinematics
  and forces (``System.is_constant`` and no state dependence of the forces). Each mode then has
  constant accelerations, so positions are quadratic in t and every event is the root of a linear
  or quadratic polynomial, computed without cancellation (a stop at ``dt = -u_T / a_T``);
- in **closed form** as well for such a system under a control schedule (``System.with_control``
  with a constant control matrix B and a piecewise-constant, -linear or -affine hold): between two
  breakpoints of the schedule the force is affine in t, so are the accelerations and contact forces
  of a mode, positions are cubic and every event (stop, lift-off, slip, landing) is the first root
  of a polynomial of degree at most 3 (:mod:`~lcp.events.forcing`, :mod:`~lcp.events.cubic_phase`);
- otherwise by SciPy's ``solve_ivp`` (DOP853 by default, rtol 1e-12) with event functions
  (``.terminal``, ``.direction``) located by Brent's method on the dense output.

Which integrator ran is recorded per phase (:attr:`EventResult.phases`).

Events
------
- a sliding velocity reaching zero (stop);
- a normal force reaching zero (lift-off);
- a stick force reaching the friction bound (stick -> slip);
- a gap closing (impact);
- for redundant contacts, the set of admissible forces becoming empty (slip or tipping);
- a breakpoint of the forces (``System.breakpoints``, e.g. the switches of a control schedule):
  phases end exactly there and see the forces' left limit.

Redundant contacts (two corners of a box, the legs of a table, a block in a groove) have a
positive semidefinite Delassus matrix: the motion is unique but the forces are not. Their forces
are the least-norm admissible ones, the phase is flagged (``Phase.forces_unique``,
``EventResult.nonunique_forces`` and the message), and the phase ends when no admissible forces
remain (:mod:`~lcp.events.indeterminate`). With friction on sliding opposed contacts (a slider in
a guide without clearance) the squeeze between them changes the friction, so the motion depends on
the choice too: the least squeeze is taken, and the message says so. A force that the mode decision found consistent on its
bound (a stick exactly at the friction limit) is kept there, not flipped at every rounding error.

Accumulations of impacts (a ball bouncing to rest) are detected and summed up at their limit, in
closed form or by Aitken's extrapolation; the contacts then persist with zero normal velocity
(exactly zero gap on a flat contact). They are listed in ``EventResult.accumulations``, and every
resolved impact in ``EventResult.impacts`` (:mod:`~lcp.events.accumulation`).

Moving contacts (a gap or tangent of t: a moving table, a cam, a conveyor belt) have the local
velocity u = H(t, q) v + b(t, q), b = (dg/dt, ds/dt): the zero tests, Newton's impact law, the
sliding directions and the projections use it, events are located on g(t, q(t)), and the
acceleration-level problem is written on du/dt (its drift by CasADi from u(t, q, v),
:func:`~lcp.events.model.accel_function`). Their phases are never in closed form, and an
accumulation of impacts on a moving contact is resolved impact by impact (the fixed obstacle's
geometric series does not hold), which the message says.

At each event the next mode comes from the **acceleration-level contact problem** of the closed
contacts (:mod:`~lcp.events.modes`): the Coulomb law with forces and accelerations in place of
impulses and velocities, sliding contacts folded in, so that the law itself stays in
:class:`~lcp.contact.problem.ContactProblem`.
The problem is solved by enumerating every branch (open / stick / slide+ / slide- for stick
candidates, open / closed for sliding contacts), which finds *all* solutions, or by Lemke's method
for many contacts. Solutions with the same acceleration are one motion (ties at a mode boundary,
broken by looking a short time ahead). When the problem has **no solution or several** (the
Painlevé cases: kappa >= 1 in the Jean-Pratt scene), the integrator applies the **impulsive
fallback**: the velocity-level impact problem, ContactProblem(W, H_c v, mu), the problem
Moreau-Jean solves in the limit h -> 0+. Its trivial solution (no impulse) is excluded by taking the
branch that Moreau-Jean's problem selects for a vanishing step (free velocity H_c v + delta b with
delta -> 0+) and re-solving that branch at delta = 0. The impulse (a tangential impact) is recorded
with its time in :attr:`EventResult.impulses`.

Cost on constant systems
------------------------
With constant mass matrix, kinematics and forces (``System.is_constant`` and no state dependence
of the forces) the acceleration-level problems, the phases' accelerations and forces, the
projection matrices and the check of the mass matrix depend on the System only: they are built
on first use and kept per System object (``SystemModel``), so that a later call only classifies the
contacts, finds the event times, projects the state at events and evaluates the quadratic phases
at the output times (all at once, with NumPy). The results are those of a fresh System.

Behaviour at the shock limit (Jean-Pratt, v0 > 0): for kappa < 1 the block slides with
N0 = (m+M) g / (1 - kappa) and stops at tau0 = |v0| A (1 - kappa) / (R (m+M) g); as kappa -> 1-,
tau0 -> 0, the stop distance -> 0 and the integral of the contact forces over the slide tends to
(M tan(alpha) v0, -A v0). For kappa >= 1 (kappa = 1 included: its sliding branch has a zero
effective normal mass, detected without letting rounding decide) the block stops by one tangential
impact at t = 0 with exactly those impulses, then sticks. The motion is continuous in kappa.

Modules
-------
- :mod:`~lcp.events.options`: :class:`EventOptions` and the choices of integrator and solver;
- :mod:`~lcp.events.records`: :class:`EventResult` and what it lists (events, impulses, phases);
- :mod:`~lcp.events.model`: the system evaluated at a state, and what is kept per system;
- :mod:`~lcp.events.modes`: mode selection at the acceleration level;
- :mod:`~lcp.events.indeterminate`: redundant contacts (least-norm admissible forces, force margin);
- :mod:`~lcp.events.forcing`: the piecewise-affine force of a scheduled constant system;
- :mod:`~lcp.events.phases`, :mod:`~lcp.events.cubic_phase`, :mod:`~lcp.events.ode_phase`: smooth
  phases (closed form under constant and under piecewise-affine forces, SciPy);
- :mod:`~lcp.events.event_location`: the events that end a phase;
- :mod:`~lcp.events.impacts`: the velocity-level impact law;
- :mod:`~lcp.events.accumulation`: accumulations of impacts and their limit;
- :mod:`~lcp.events.projection`: the projection onto the active constraints at events;
- :mod:`~lcp.events.integrator`, :mod:`~lcp.events.driver`: the event loop and :func:`event_driven`;
- :mod:`~lcp.events.kinematic_ode`: systems with Newton-Euler kinematics (qdot = T(q) v, unit
  quaternions) and no contacts or constraints; with them the planar and spatial integrators run
  on the state (q, v), n_q != n_v, with qdot = T(q) v, Jacobians and impacts in v-space, drift
  terms along T v (:func:`~lcp.events.model.accel_function`), corrections moving q by T dx and the
  quaternions renormalised after every accepted step (docs/rigid_bodies.md).
"""
from lcp.events.driver import event_driven
from lcp.events.options import EVENT_STATUS_MESSAGES, EventOptions, ModeSolver, SmoothIntegrator
from lcp.events.records import Accumulation, Event, EventResult, Impact, Impulse, Phase

__all__ = ["EVENT_STATUS_MESSAGES", "SmoothIntegrator", "ModeSolver", "EventOptions", "Event", "Impulse",
           "Impact", "Accumulation", "Phase", "EventResult", "event_driven"]
