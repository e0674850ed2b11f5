"""Routes of ``lcp.simulate`` (Moreau-Jean, ``fast``) that the compiled loops took over from the
Python loop, against the Python loop (fast=False); the route asserted by the call of the compiled
loop and the solver's name.

- Controlled constant systems without a contact (a constant drift, a constant B): the constant
  compiled loop's free steps with S B int u added (lcp.timestepping.control_kernels), the same
  NumPy products as the Python loop's ``StepAssembly.at``: bit for bit. A pushed point, two masses
  with springs and dampers (a dense mass matrix, a state-dependent drift), and a bilateral
  constraint.
- Constant systems without contact or control: the constant compiled loop, its free velocity by
  the same dense products (no control column): bit for bit. A constant system with one contact
  under the solver "nsgs" by name: the constant compiled loop, to rounding (as with several).
- The constant compiled loop's steps whose NSGS sweeps stop (the bead column: many frictionless
  contacts closing at once): finished by the compiled NSGS-then-Newton of
  lcp.timestepping.planar_multi_kernels (counted in ``stats.kernel_multi_steps``) instead of the
  Python solver. It starts from zero where the Python solver warm-starts, so the two solves differ
  within the solver's tolerance; the branch refinement (the Python loop's, on the same modes) then
  makes both exact on the branch, and the runs agree to rounding (measured: 3.5e-16 of the largest
  impulse). Modes differ only where an impulse is a rounding zero (1e-17).
- Control schedules on constant matrices that are not a constant planar drift with a constant B (a
  drift F(t), a B(t), a spatial contact): the compiled general loop. The Python loop computes those
  steps by the assembly's S products, the general loop by the step Function's generated C code
  plus S c_k: the same equations, another rounding (as for an uncontrolled F(t) on constant
  matrices); equal to 1e-12 of each array's largest entry, the same modes and message.
- One active planar contact under the solver "nsgs" by name: the general loop's kernel
  (planar_multi_step), bit for bit; with a bilateral constraint still the Python contact step.
"""
import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import lcp
from lcp.model.control import ControlSchedule
from lcp.model.schedule import AffineSchedule
from lcp.model.system import Contact, System
from lcp.numerics.jit import HAVE_NUMBA
from lcp.scenes.bead_column import bead_column
from lcp.timestepping import codegen, compiled_loop, general_loop, planar_multi_kernels
from lcp.timestepping.assembly import StepAssembly
from tests.helpers import counting

pytestmark = pytest.mark.skipif(not HAVE_NUMBA, reason="needs numba")

TIMES = [0.0, 0.2, 0.45, 0.6]


def pushed_point():
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    return System(q, v, ca.SX.eye(2), ca.vertcat(u[0], -9.81), control=u, control_bounds=(-50, 50))


def springs():
    """Two coupled masses (dense mass matrix) with springs and dampers, both pushed."""
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 2)
    M = ca.SX(np.array([[2.0, -1.0], [-1.0, 2.0]]))
    F = ca.vertcat(-30 * q[0] + 5 * q[1] - 0.3 * v[0] + u[0], 5 * q[0] - 20 * q[1] - 0.1 * v[1] - 9.81 + u[1])
    return System(q, v, M, F, control=u, control_bounds=(-50, 50))


def slide():
    """Jean-Pratt's block and wedge with the slide as a bilateral constraint, no floor contact."""
    q, v, u = ca.SX.sym("q", 3), ca.SX.sym("v", 3), ca.SX.sym("u", 2)
    return System(q, v, ca.SX(np.eye(3)), ca.vertcat(-9.81 + u[0], -9.81 + u[1], -9.81),
                  constraints=q[2] - q[1] + q[0], control=u, control_bounds=(-100, 100))


NO_CONTACT = {"pushed_point": (pushed_point, [0.0, 0.0], [0.5, 1.0]),
              "springs": (springs, [0.1, -0.2], [0.0, 1.0]),
              "slide": (slide, [0.0, 0.0, 0.0], [1.0, 0.0, -1.0])}


def schedule(hold, values, nu):
    """A schedule on TIMES of the given hold from 6 nu numbers."""
    values = np.asarray(values, dtype=float).reshape(3, 2, nu)
    if hold == "constant":
        return ControlSchedule(TIMES, values[:, 0])
    if hold == "linear":
        return ControlSchedule(TIMES, np.vstack([values[:, 0], values[-1:, 1]]), hold="linear")
    return AffineSchedule(TIMES, values.reshape(-1, nu))


def same(a, b):
    assert a.status == b.status and a.message == b.message
    for name in ("t", "q", "v", "p_N", "p_T"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape and np.array_equal(x, y), name
    assert a.stats.steps == b.stats.steps and a.stats.free_steps == b.stats.free_steps == a.stats.steps


@pytest.mark.parametrize("theta", [0.5, 1.0])
@pytest.mark.parametrize("hold", ["constant", "linear", "affine"])
@pytest.mark.parametrize("name", sorted(NO_CONTACT))
def test_controlled_without_contact_bit_for_bit(name, hold, theta, monkeypatch):
    build, q0, v0 = NO_CONTACT[name]
    system = build()
    nu = 1 if name == "pushed_point" else 2
    sched = schedule(hold, np.linspace(-7.0, 11.0, 6 * nu) * (-1) ** np.arange(6 * nu), nu)
    calls = counting(monkeypatch, compiled_loop, "moreau_jean_loop")
    fast = lcp.simulate(system, 0.6, h=1e-3, q0=q0, v0=v0, control=sched, theta=theta)
    slow = lcp.simulate(system, 0.6, h=1e-3, q0=q0, v0=v0, control=sched, theta=theta, fast=False)
    assert len(calls) == 1 and fast.solver == "auto (compiled)" and slow.solver == "auto"
    assert "Python loop" not in fast.message
    same(fast, slow)


@pytest.mark.parametrize("hold", ["constant", "linear", "affine"])
def test_pushed_point_exact(hold):
    """v(t_k) = v0 + (int_0^{t_k} u, -9.81 t_k): the impulse of every hold over each step, by the
    compiled loop without contact."""
    sched = schedule(hold, [3.0, -1.0, -8.0, 2.0, 5.0, 5.0], 1)
    h = 0.6 / 700
    res = lcp.simulate(pushed_point(), 0.6, h=h, q0=[0.0, 0.0], v0=[0.5, 0.0], control=sched)
    assert res.solver == "auto (compiled)"
    assert np.max(np.abs(res.v[:, 0] - (0.5 + sched.integral(res.t)[:, 0]))) < 1e-13
    assert np.max(np.abs(res.v[:, 1] + 9.81 * res.t)) < 1e-12


@settings(max_examples=8, deadline=None)
@given(hold=st.sampled_from(["constant", "linear", "affine"]),
       values=st.lists(st.floats(-40.0, 40.0, allow_nan=False, allow_infinity=False), min_size=12, max_size=12))
def test_drawn_schedules_springs(hold, values):
    sched = schedule(hold, values, 2)
    fast = lcp.simulate(springs(), 0.6, h=2e-3, q0=[0.1, -0.2], v0=[0.0, 1.0], control=sched)
    slow = lcp.simulate(springs(), 0.6, h=2e-3, q0=[0.1, -0.2], v0=[0.0, 1.0], control=sched, fast=False)
    assert fast.solver == "auto (compiled)"
    same(fast, slow)


def test_lemke_keeps_the_python_loop_with_its_note():
    """A solver the compiled loop does not run: the Python loop, the message says why (no longer
    "needs a contact")."""
    sched = schedule("constant", np.arange(6.0), 1)
    fast = lcp.simulate(pushed_point(), 0.2, h=1e-3, q0=[0.0, 0.0], v0=[0.0, 0.0], control=sched, solver="lemke")
    slow = lcp.simulate(pushed_point(), 0.2, h=1e-3, q0=[0.0, 0.0], v0=[0.0, 0.0], control=sched, solver="lemke",
                        fast=False)
    assert fast.message == slow.message + (" (Python loop: the compiled loop of a controlled constant system needs "
                                           "the solver 'auto' or 'nsgs' without error_tol, and no projection)")
    assert np.array_equal(fast.q, slow.q) and np.array_equal(fast.v, slow.v)


def python_finished(monkeypatch):
    """The constant compiled loop as before the compiled Newton: the Python solver takes every step
    whose sweeps stop."""
    monkeypatch.setattr(compiled_loop, "newton_params", lambda solver: None)


@pytest.mark.parametrize("K, e", [(10, 0.5), (10, 0.9), (15, 0.7)])
def test_bead_column_stopped_sweeps_finished_compiled(K, e, monkeypatch):
    sc = bead_column(K, e=e)
    new = lcp.simulate(sc, 1.5, h=1e-3)
    python_finished(monkeypatch)
    old = lcp.simulate(sc, 1.5, h=1e-3)
    assert new.success and old.success
    assert old.stats.fallbacks > 0 and "solved by the Python solver 'auto'" in old.message
    assert new.stats.kernel_multi_steps == old.stats.fallbacks and new.stats.fallbacks == 0
    assert new.message == "The integration reached t_end."
    for name in ("q", "v", "p_N"):
        x, y = getattr(new, name), getattr(old, name)
        assert np.max(np.abs(x - y)) <= 1e-14 * np.max(np.abs(y)), name
    F, O = np.asarray(new.modes), np.asarray(old.modes)
    assert np.all((F == O) | (np.maximum(new.p_N, old.p_N) < 1e-14 * np.max(old.p_N)))


def test_bead_column_against_the_python_loop():
    """The whole run against the Python loop (fast=False): the solver's tolerance (the compiled
    loop's NSGS sums are not BLAS's, as before)."""
    sc = bead_column(10, e=0.7)
    fast = lcp.simulate(sc, 1.0, h=1e-3)
    slow = lcp.simulate(sc, 1.0, h=1e-3, fast=False)
    assert fast.stats.kernel_multi_steps > 0 and fast.stats.fallbacks == 0 and fast.solver == "auto (compiled)"
    for name in ("q", "v", "p_N"):
        x, y = getattr(fast, name), getattr(slow, name)
        assert np.max(np.abs(x - y)) <= 1e-8 * np.max(np.abs(y)), name
    assert np.array_equal(np.asarray(fast.modes)[:400], np.asarray(slow.modes)[:400])  # before the first stopped sweeps


def test_failed_compiled_newton_goes_to_the_python_solver(monkeypatch):
    """Where the compiled finish fails its test, the Python solver takes the step, counted in
    stats.fallbacks and named in the message, as before."""
    sc = bead_column(10, e=0.5)
    monkeypatch.setattr(planar_multi_kernels, "solve_planar",
                        lambda Wl, qa, mus, tol, pm: (False, np.zeros(qa.size), 0, np.nan))
    res = lcp.simulate(sc, 1.0, h=1e-3)
    python_finished(monkeypatch)
    old = lcp.simulate(sc, 1.0, h=1e-3)
    assert res.stats.kernel_multi_steps == 0 and res.stats.fallbacks == old.stats.fallbacks > 0
    assert res.message == old.message and "compiled NSGS stopped after 500 sweeps" in res.message
    assert np.array_equal(res.q, old.q) and np.array_equal(res.p_N, old.p_N)


def test_sliding_stack_finished_by_compiled_newton(monkeypatch):
    """Four stacked blocks with friction (each contact carries the blocks above it), sliding over
    each other, the kernel's NSGS limited to one sweep: the steps it cannot finish (where the warm
    start does not suffice) are finished by the compiled Newton, with stick and slip, and the run
    is the Python loop's to 1e-11 (the solver's tolerance, as the Python-finished run)."""
    from lcp.classical import stacked_blocks

    sc = stacked_blocks(4)
    v0 = np.zeros(8)
    v0[0::2] = np.linspace(0.5, -0.5, 4)  # x0 .. x3
    monkeypatch.setattr(compiled_loop, "AUTO_MAX_SWEEPS", 1)
    fast = lcp.simulate(sc.system, 0.3, h=1e-3, q0=sc.q0, v0=v0)
    slow = lcp.simulate(sc.system, 0.3, h=1e-3, q0=sc.q0, v0=v0, fast=False)
    assert fast.success and fast.stats.fallbacks == 0 and fast.message == slow.message
    assert fast.stats.kernel_multi_steps >= 3 and np.any(slow.p_T != 0)
    assert np.array_equal(np.asarray(fast.modes), np.asarray(slow.modes))
    for name in ("q", "v", "p_N", "p_T"):
        x, y = getattr(fast, name), getattr(slow, name)
        assert np.max(np.abs(x - y)) <= 1e-11 * max(1.0, np.max(np.abs(y))), name


def t_drift():
    """Jean-Pratt's dense mass matrix, a block pushed by u on a floor with a drift of t."""
    q, v, u, t = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1), ca.SX.sym("t")
    M = ca.SX(np.array([[2.0, -1.0], [-1.0, 2.0]]))
    return System(q, v, M, ca.vertcat(u[0] + ca.sin(5 * t), -9.81 + 2 * ca.cos(3 * t)), t=t, control=u,
                  control_bounds=(-50, 50), contacts=[Contact(gap=q[1], tangent=q[0], mu=0.3, name="floor")])


def t_matrix():
    """The same block pushed along a direction turning with t: B(t) = (cos 2t, sin 2t)."""
    q, v, u, t = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1), ca.SX.sym("t")
    M = ca.SX(np.array([[2.0, -1.0], [-1.0, 2.0]]))
    return System(q, v, M, ca.vertcat(u[0] * ca.cos(2 * t), -9.81 + u[0] * ca.sin(2 * t)), t=t, control=u,
                  control_bounds=(-50, 50), contacts=[Contact(gap=q[1], tangent=q[0], mu=0.3, name="floor")])


def puck():
    """A puck on a spatial floor pushed along x (constant drift and B, a spatial contact)."""
    q, v, u = ca.SX.sym("q", 3), ca.SX.sym("v", 3), ca.SX.sym("u", 1)
    return System(q, v, ca.SX.eye(3), ca.vertcat(u[0], 0, -9.81), control=u, control_bounds=(-50, 50),
                  contacts=[Contact(gap=q[2], tangent=ca.vertcat(q[0], q[1]), mu=0.3, name="floor")])


CONSTANT_MATRICES = {"t_drift": (t_drift, [0.0, 0.0], [0.5, 0.0]), "t_matrix": (t_matrix, [0.0, 0.0], [0.5, 0.0]),
                     "puck": (puck, [0.0, 0.0, 0.0], [1.0, 0.0, 0.0])}


def close(a, b, rtol=1e-12):
    assert a.status == b.status and a.message == b.message
    assert np.array_equal(np.asarray(a.modes), np.asarray(b.modes))
    for name in ("t", "q", "v", "p_N", "p_T"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape and np.max(np.abs(x - y), initial=0.0) <= rtol * np.max(np.abs(y), initial=0.0), name
    assert [(i.contact, i.t) for i in a.impacts] == [(i.contact, i.t) for i in b.impacts]


@pytest.mark.skipif(codegen.c_compiler() is None, reason="needs a C compiler")
@pytest.mark.parametrize("hold", ["constant", "linear", "affine"])
@pytest.mark.parametrize("name", sorted(CONSTANT_MATRICES))
def test_schedule_on_constant_matrices_general_loop(name, hold, monkeypatch):
    build, q0, v0 = CONSTANT_MATRICES[name]
    system = build()
    # the last piece lifts the block (or presses the puck) by more than its weight
    sched = schedule(hold, [3.0, -2.0, -8.0, 5.0, 30.0, 0.0], 1)
    scheduled = system.with_control(sched)
    asm = StepAssembly(scheduled, 1e-3, 0.5)
    assert asm.matrices_constant and general_loop.applicable(scheduled, asm, None) is None
    calls = counting(monkeypatch, general_loop, "run_general_loop")
    fast = lcp.simulate(system, 0.6, h=1e-3, q0=q0, v0=v0, control=sched)
    slow = lcp.simulate(system, 0.6, h=1e-3, q0=q0, v0=v0, control=sched, fast=False)
    assert len(calls) == 1 and fast.success and "Python loop" not in fast.message
    assert fast.stats.python_steps == 0
    close(fast, slow)
    assert np.any(slow.p_N > 0) and np.any(slow.p_T != 0)
    if name != "puck":
        assert slow.stats.free_steps > 0  # lifted off by the last piece


def tipping_rod(e=0.2):
    """A planar rod (x, y, theta) of length 1 with its lower tip on the floor (curved gap)."""
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    tip = Contact(gap=q[1] - 0.5 * ca.sin(q[2]), tangent=q[0] - 0.5 * ca.cos(q[2]), mu=0.4, e=e, name="tip")
    return System(q, v, ca.diag(ca.SX([1.0, 1.0, 1.0 / 12])), ca.vertcat(0, -9.81, 0), contacts=[tip])


def walled_pendulum(e=0.3):
    """A point on a circle of radius 1 (a bilateral constraint) striking a wall at x = 0.3."""
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    return System(q, v, ca.SX.eye(2), ca.vertcat(0, -9.81), constraints=q[0] ** 2 + q[1] ** 2 - 1.0,
                  contacts=[Contact(gap=0.3 - q[0], tangent=q[1], mu=0.2, e=e, name="wall")])


ONE_CONTACT = {"rod": (tipping_rod, [0.0, 0.5 * np.sin(0.5) + 0.2, 0.5], [0.5, 0.0, 0.0]),
               "pendulum": (walled_pendulum, [0.0, -1.0], [2.0, 0.0])}


@pytest.mark.skipif(codegen.c_compiler() is None, reason="needs a C compiler")
@pytest.mark.parametrize("e", [0.0, 0.5])
@pytest.mark.parametrize("name", sorted(ONE_CONTACT))
def test_one_contact_nsgs_by_name_in_the_kernel(name, e, monkeypatch):
    """One active planar contact under the solver "nsgs" by name (no closed form: the Python loop
    runs its NSGS): the general loop's kernel solves it as it solves several
    (planar_multi_kernels.planar_multi_step: the same sweeps, tests, modes and branch refinement),
    where every such step went to the Python contact step before; bit for bit. Not with a bilateral
    constraint (the pendulum)."""
    build, q0, v0 = ONE_CONTACT[name]
    system = build(e)
    calls = counting(monkeypatch, general_loop, "run_general_loop")
    fast = lcp.simulate(system, 1.0, h=1e-3, q0=q0, v0=v0, solver="nsgs")
    slow = lcp.simulate(system, 1.0, h=1e-3, q0=q0, v0=v0, solver="nsgs", fast=False)
    assert len(calls) == 1 and fast.success
    contact_steps = fast.stats.steps - fast.stats.free_steps
    if name == "pendulum":
        # a bilateral constraint: the one-contact problem may be redundant (the point sticking on
        # the wall: three constraints on two velocities), its impulses' split the solver's; these
        # steps stay with the Python contact step, counted
        assert fast.stats.kernel_multi_steps == 0 and fast.stats.python_steps == contact_steps > 0
    else:
        assert fast.stats.python_steps == 0 and fast.stats.kernel_multi_steps == contact_steps > 0
    assert fast.message == slow.message and fast.status == slow.status
    for a in ("t", "q", "v", "p_N", "p_T"):
        assert np.array_equal(getattr(fast, a), getattr(slow, a)), a
    assert np.array_equal(np.asarray(fast.modes), np.asarray(slow.modes))
    assert [(i.t, i.contact, i.p_N) for i in fast.impacts] == [(i.t, i.contact, i.p_N) for i in slow.impacts]
    assert fast.stats.mode_counts == slow.stats.mode_counts
    if e:
        assert len(slow.impacts) >= 1


def free_systems():
    """Constant systems without contact or control: a falling point (a constant increment), two
    masses with springs and dampers (a dense mass matrix, a state-dependent force), Jean-Pratt's
    slide as a bilateral constraint."""
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    M = ca.SX(np.array([[2.0, -1.0], [-1.0, 2.0]]))
    fall = System(q, v, ca.SX.eye(2), ca.vertcat(0.0, -9.81))
    spr = System(q, v, M, ca.vertcat(-30 * q[0] + 5 * q[1] - 0.3 * v[0], 5 * q[0] - 20 * q[1] - 0.1 * v[1] - 9.81))
    q3, v3 = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    slide = System(q3, v3, ca.SX(np.eye(3)), ca.vertcat(-9.81, -9.81, -9.81), constraints=q3[2] - q3[1] + q3[0])
    return {"fall": (fall, [0.1, -0.2], [0.0, 1.0]), "springs": (spr, [0.1, -0.2], [0.0, 1.0]),
            "slide": (slide, [0.0, 0.0, 0.0], [1.0, 0.0, -1.0])}


@pytest.mark.parametrize("theta", [0.5, 0.75, 1.0])
@pytest.mark.parametrize("name", ["fall", "springs", "slide"])
def test_constant_system_without_contact_bit_for_bit(name, theta, monkeypatch):
    """A constant system without contact: the constant compiled loop (the Python loop before), its
    free velocity by the Python loop's dense products (control_kernels.constant_control_dv with
    no control column): bit for bit."""
    system, q0, v0 = free_systems()[name]
    calls = counting(monkeypatch, compiled_loop, "moreau_jean_loop")
    fast = lcp.simulate(system, 0.6, h=1e-3, q0=q0, v0=v0, theta=theta)
    slow = lcp.simulate(system, 0.6, h=1e-3, q0=q0, v0=v0, theta=theta, fast=False)
    assert len(calls) == 1 and fast.solver == "auto (compiled)" and slow.solver == "auto"
    same(fast, slow)


def test_free_fall_exact():
    """The falling point by the compiled loop: v(t_k) = v0 - g t_k and y(t_k) = y0 + v0 t - g t^2 / 2
    (theta = 1/2 is exact on a constant force)."""
    system, q0, v0 = free_systems()["fall"]
    res = lcp.simulate(system, 0.6, h=1e-3, q0=q0, v0=v0)
    assert res.solver == "auto (compiled)"
    t = res.t
    assert np.max(np.abs(res.v[:, 1] - (1.0 - 9.81 * t))) < 1e-12
    assert np.max(np.abs(res.q[:, 1] - (-0.2 + t - 4.905 * t * t))) < 1e-12


@pytest.mark.skipif(codegen.c_compiler() is None, reason="needs a C compiler")
def test_scheduled_redundant_spatial_pair_general_loop(monkeypatch):
    """Two pucks joined by a bar along x (a bilateral constraint) on a spatial floor, the first one
    pushed by a schedule: redundant contacts (both stick along x: only the sum of their x
    impulses is determined). The compiled general loop agrees with the Python loop to rounding in
    q, v, the normal impulses and that sum; the split between the two contacts is the solver's
    (here it differs by up to 40 % of the largest tangential impulse), as for redundant contacts
    of the non-constant systems of that loop."""
    q, v, u = ca.SX.sym("q", 6), ca.SX.sym("v", 6), ca.SX.sym("u", 1)
    pair = System(q, v, ca.SX.eye(6), ca.vertcat(u[0], 0, -9.81, 0, 0, -9.81), constraints=q[3] - q[0] - 1.0,
                  control=u, control_bounds=(-50, 50),
                  contacts=[Contact(gap=q[2], tangent=ca.vertcat(q[0], q[1]), mu=0.3, name="a"),
                            Contact(gap=q[5], tangent=ca.vertcat(q[3], q[4]), mu=0.5, name="b")])
    sched = schedule("affine", [3.0, -2.0, -8.0, 5.0, 1.0, 0.0], 1)
    calls = counting(monkeypatch, general_loop, "run_general_loop")
    kw = dict(q0=[0.0, 0.0, 0.0, 1.0, 0.0, 0.0], v0=[1.0, 0.3, 0.0, 1.0, 0.3, 0.0], control=sched)
    fast = lcp.simulate(pair, 0.6, h=1e-3, **kw)
    slow = lcp.simulate(pair, 0.6, h=1e-3, fast=False, **kw)
    assert len(calls) == 1 and fast.success and fast.message == slow.message
    assert np.array_equal(np.asarray(fast.modes), np.asarray(slow.modes))
    for name in ("q", "v", "p_N"):
        x, y = getattr(fast, name), getattr(slow, name)
        assert np.max(np.abs(x - y)) <= 1e-12 * np.max(np.abs(y)), name
    pt = np.max(np.abs(slow.p_T))
    sum_x = lambda r: r.p_T[:, 0] + r.p_T[:, 2]  # noqa: E731
    assert np.max(np.abs(sum_x(fast) - sum_x(slow))) <= 1e-12 * pt
    # Coulomb's disk at every step, in both loops: the all-stick correction of a singular W used
    # to move puck a's friction impulse to 2.5 mu p_N (contact_step.in_cones)
    for res in (fast, slow):
        for j, mu in enumerate((0.3, 0.5)):
            tang = np.linalg.norm(res.p_T[:, 2 * j:2 * j + 2], axis=1)
            assert np.all(tang <= mu * res.p_N[:, j] * (1 + 1e-12) + 1e-300), (j, np.max(tang / (mu * res.p_N[:, j])))


@pytest.mark.parametrize("theta", [0.5, 1.0])
@pytest.mark.parametrize("kw", [{"R": 0.3}, {"R": 0.5}, {"R": 0.9}, {"coordinates": "full"}])
def test_one_contact_constant_nsgs_compiled(kw, theta, monkeypatch):
    """Jean-Pratt's block (one contact, a constant system) under the solver "nsgs" by name: the
    constant compiled loop (the Python loop before: the compiled step is the closed form of
    "auto"/"enum" only), its NSGS sweeps on the one contact; the Python loop's to rounding (the
    kernel's sums are not BLAS's, as with several contacts): the same modes, message and impacts."""
    sc = lcp.scenes.jean_pratt(**kw)
    calls = counting(monkeypatch, compiled_loop, "moreau_jean_loop")
    fast = lcp.simulate(sc, 0.5, h=1e-3, solver="nsgs", theta=theta)
    slow = lcp.simulate(sc, 0.5, h=1e-3, solver="nsgs", theta=theta, fast=False)
    assert len(calls) == 1 and fast.solver == "nsgs (compiled)" and slow.solver == "nsgs"
    assert fast.stats.fallbacks == 0 and np.any(slow.p_N > 0)
    close(fast, slow)


def pushed_chain(K, amp=3.0):
    """lcp.scenes.block_chain(K) with every block pushed along x by amp sin 3t: constant matrices,
    a force of t (the general loop)."""
    sc = lcp.scenes.block_chain(K)
    s = sc.system
    t = ca.SX.sym("t")
    force = s.force_expr + ca.vertcat(*([amp * ca.sin(3 * t), 0] * K))
    return System(s.q_sym, s.v_sym, s.mass_expr, force, t=t, contacts=s.contacts, names=s.names), sc.q0, sc.v0


@pytest.mark.skipif(codegen.c_compiler() is None, reason="needs a C compiler")
@pytest.mark.parametrize("K", [3, 10])
def test_constant_matrices_several_contacts_in_the_kernel(K, monkeypatch):
    """Several active planar contacts on constant matrices with a force of t: the general loop's
    kernel (planar_multi_step) instead of the Python contact step; from zero where the Python solver
    warm-starts, so to rounding after the branch refinement: the same modes, message and impacts,
    q, v, p_N and p_T within 1e-12 of their largest entries."""
    system, q0, v0 = pushed_chain(K)
    calls = counting(monkeypatch, general_loop, "run_general_loop")
    fast = lcp.simulate(system, 1.0, h=1e-3, q0=q0, v0=v0)
    slow = lcp.simulate(system, 1.0, h=1e-3, q0=q0, v0=v0, fast=False)
    assert len(calls) == 1 and fast.stats.python_steps == 0 and fast.stats.kernel_multi_steps == 1000
    close(fast, slow)
    assert slow.stats.mode_counts["stick"] > 0 and slow.stats.mode_counts["slide+"] > 0


@pytest.mark.skipif(codegen.c_compiler() is None, reason="needs a C compiler")
def test_large_constant_matrices_keep_the_python_loop(monkeypatch):
    """Above CONSTANT_MATRICES_MAX_N velocities a system with constant matrices and a force of t
    keeps the Python loop (its constant S is reused; the general loop would rebuild dense n x n
    data each step, slower there): the same bits as fast=False, and the message says why."""
    K = general_loop.CONSTANT_MATRICES_MAX_N // 2 + 1
    system, q0, v0 = pushed_chain(K)
    assert system.n > general_loop.CONSTANT_MATRICES_MAX_N
    calls = counting(monkeypatch, general_loop, "run_general_loop")
    fast = lcp.simulate(system, 0.05, h=1e-3, q0=q0, v0=v0)
    slow = lcp.simulate(system, 0.05, h=1e-3, q0=q0, v0=v0, fast=False)
    assert not calls and "constant matrices with more than" in fast.message
    assert np.array_equal(fast.q, slow.q) and np.array_equal(fast.v, slow.v)


@pytest.mark.skipif(codegen.c_compiler() is None, reason="needs a C compiler")
def test_coupled_constant_spatial_contacts_general_loop(monkeypatch):
    """A constant system whose spatial contacts are coupled (two pucks joined by a bar: W has
    off-diagonal blocks, which compiled_spatial refuses) runs the compiled general loop, not the
    Python loop: q, v, p_N and the determined sum of the x impulses to rounding, the disk at every
    step in both loops, the slide's closed form while both pucks slide."""
    q, v = ca.SX.sym("q", 6), ca.SX.sym("v", 6)
    pair = System(q, v, ca.SX.eye(6), ca.vertcat(2.0, 0, -9.81, 0, 0, -9.81), constraints=q[3] - q[0] - 1.0,
                  contacts=[Contact(gap=q[2], tangent=ca.vertcat(q[0], q[1]), mu=0.3, name="a"),
                            Contact(gap=q[5], tangent=ca.vertcat(q[3], q[4]), mu=0.5, name="b")])
    assert pair.is_constant
    calls = counting(monkeypatch, general_loop, "run_general_loop")
    kw = dict(q0=[0.0, 0.0, 0.0, 1.0, 0.0, 0.0], v0=[1.0, 0.3, 0.0, 1.0, 0.3, 0.0])
    fast = lcp.simulate(pair, 1.0, h=1e-3, **kw)
    slow = lcp.simulate(pair, 1.0, h=1e-3, fast=False, **kw)
    assert len(calls) == 1 and fast.stats.python_steps == 0 and fast.message == slow.message
    for name in ("q", "v", "p_N"):
        x, y = getattr(fast, name), getattr(slow, name)
        assert np.max(np.abs(x - y)) <= 1e-12 * np.max(np.abs(y)), name
    sum_x = lambda r: r.p_T[:, 0] + r.p_T[:, 2]  # noqa: E731
    # the solvers' tolerance: the kernel's NSGS starts from zero, the Python solver warm-starts
    assert np.max(np.abs(sum_x(fast) - sum_x(slow))) <= 1e-11 * np.max(np.abs(sum_x(slow)))
    for res in (fast, slow):
        for j, mu in enumerate((0.3, 0.5)):
            tang = np.linalg.norm(res.p_T[:, 2 * j:2 * j + 2], axis=1)
            assert np.all(tang <= mu * res.p_N[:, j] * (1 + 1e-12) + 1e-300)
    # both slide at first, friction against the motion: the speed falls
    speed = np.hypot(fast.v[:, 0], fast.v[:, 1])
    assert np.all(np.diff(speed[:50]) < 0)
