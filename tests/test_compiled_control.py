"""Control schedules in the compiled loops, against the Python loop (fast=False).

- B(t, q) depending on q: the compiled general loop evaluates the control's C function
  (lcp.timestepping.compiled_control) each step; a pendulum pushed along its tangent (a bilateral
  constraint, a wall with restitution), a planar rod with a thrust along its axis (lift-off and
  landings), a rigid body with a unit quaternion and a body-fixed thruster (a spatial contact).
- Controlled constant systems (constant drift, constant B): the constant compiled loop with the
  control's impulse S B int u added per step; Jean-Pratt's block (dense mass matrix, reduced and
  with the slide as a bilateral constraint) and a block chain with springs.

Every hold (constant, linear, affine); the results equal the Python loop's bit for bit (the chain's
to rounding, as without a control: its NSGS sums are not BLAS's).
"""
import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import lcp
from lcp.model.control import ControlSchedule
from lcp.model.rigid_body import bodies_system, free_body
from lcp.model.schedule import AffineSchedule
from lcp.model.system import Contact, System
from lcp.numerics.jit import HAVE_NUMBA
from lcp.timestepping import codegen, compiled_loop, general_loop
from lcp.timestepping.assembly import StepAssembly
from tests.helpers import counting

pytestmark = pytest.mark.skipif(not HAVE_NUMBA or codegen.c_compiler() is None,
                                reason="needs numba and a C compiler")

TIMES = [0.0, 0.2, 0.45, 0.6]


def schedule(hold, rows):
    """A schedule on TIMES of the given hold from per-interval (start, end) rows ``rows`` (3 x 2 x nu)."""
    rows = np.asarray(rows, dtype=float)
    if hold == "constant":
        return ControlSchedule(TIMES, rows[:, 0])
    if hold == "linear":
        return ControlSchedule(TIMES, np.vstack([rows[:, 0], rows[-1:, 1]]), hold="linear")
    return AffineSchedule(TIMES, rows.reshape(-1, rows.shape[-1]))


def pendulum(e=0.3):
    """A point on a circle of radius 1 (bilateral constraint) pushed along the tangent (-y, x) u:
    B(q) depends on q; a wall at x = 0.3 (restitution e)."""
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    return System(q, v, ca.SX.eye(2), ca.vertcat(0, -9.81) + ca.vertcat(-q[1], q[0]) * u[0], control=u,
                  control_bounds=(-50, 50), constraints=q[0] ** 2 + q[1] ** 2 - 1.0,
                  contacts=[Contact(gap=0.3 - q[0], tangent=q[1], mu=0.2, e=e, name="wall")])


def rod(e=0.2):
    """A planar rod (x, y, theta) of length 1, its lower tip on the floor, a thrust u0 along its
    axis (cos theta, sin theta) and a torque u1."""
    q, v, u = ca.SX.sym("q", 3), ca.SX.sym("v", 3), ca.SX.sym("u", 2)
    B = ca.horzcat(ca.vertcat(ca.cos(q[2]), ca.sin(q[2]), 0), ca.vertcat(0, 0, 1))
    tip = Contact(gap=q[1] - 0.5 * ca.sin(q[2]), tangent=q[0] - 0.5 * ca.cos(q[2]), mu=0.4, e=e, name="tip")
    return System(q, v, ca.diag(ca.SX([1.0, 1.0, 1.0 / 12])), ca.vertcat(0, -9.81, 0) + ca.mtimes(B, u),
                  control=u, control_bounds=(-50, 50), contacts=[tip])


def thruster(e=0.0):
    """A rigid body (unit quaternion) standing on a foot 0.3 below its centre (a spatial contact),
    two thrusters fixed in the body at the foot: along the body's z and x axes."""
    b = free_body(1.0, np.diag([0.1, 0.15, 0.2]), name="b")
    u = ca.SX.sym("u", 2)
    R = b.rotation
    ez, ex = ca.vertcat(0, 0, 1), ca.vertcat(1, 0, 0)
    r = ca.SX([0.0, 0.0, -0.3])
    force = ca.vertcat(ca.mtimes(R, ez) * u[0] + ca.mtimes(R, ex) * u[1], ca.cross(r, ez) * u[0] + ca.cross(r, ex) * u[1])
    P = b.point([0.0, 0.0, -0.3])
    foot = Contact(gap=P[2], tangent=ca.vertcat(P[0], P[1]), mu=0.3, e=e, name="foot")
    return bodies_system([b], [foot], gravity=9.81, force=force, control=u, control_bounds=(-50, 50))


def jean_pratt_block(full=False, mu=0.5):
    """Jean-Pratt's system (m = M = 1, alpha = pi/4) with a control (u0 horizontal, u1 vertical) on
    the block: constant drift and B. ``full``: the slide as a bilateral constraint."""
    u = ca.SX.sym("u", 2)
    if full:
        q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
        force = ca.vertcat(-9.81 + u[0], -9.81 + u[1], -9.81)
        return System(q, v, ca.SX(np.eye(3)), force, constraints=q[2] - q[1] + q[0], control=u,
                      control_bounds=(-100, 100), contacts=[Contact(gap=q[1], tangent=q[0], mu=mu, name="P")])
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    return System(q, v, ca.SX(np.array([[2.0, -1.0], [-1.0, 2.0]])), ca.vertcat(u[0], -2 * 9.81 + u[1]),
                  control=u, control_bounds=(-100, 100), contacts=[Contact(gap=q[1], tangent=q[0], mu=mu, name="P")])


def block_chain(K=3):
    """lcp.scenes.block_chain(K)'s blocks and springs, the first block pushed along x (u0) and the
    last one lifted (u1)."""
    sc = lcp.scenes.block_chain(K)
    s = sc.system
    u = ca.SX.sym("u", 2)
    B = np.zeros((2 * K, 2))
    B[0, 0], B[2 * K - 1, 1] = 1.0, 1.0
    system = System(s.q_sym, s.v_sym, s.mass_expr, s.force_expr + ca.mtimes(ca.SX(B), u), contacts=s.contacts,
                    control=u, control_bounds=(-100, 100), names=s.names)
    return system, sc


# per-interval (start, end) values; the second component lifts off (then lands) where it exceeds the weight
Q_ROWS = {"pendulum": [[[4.0], [-2.0]], [[-6.0], [3.0]], [[10.0], [0.0]]],
          "rod": [[[30.0, 0.5], [30.0, 0.0]], [[0.0, 0.0], [0.0, 0.0]], [[0.0, -0.5], [5.0, 0.0]]],
          "thruster": [[[2.0, 0.5], [6.0, 0.0]], [[14.0, 0.0], [10.0, 0.0]], [[9.0, -1.0], [0.0, 0.0]]]}
Q_CASES = {"pendulum": (pendulum, [0.0, -1.0], [2.0, 0.0]),
           "rod": (rod, [0.0, 0.5 * np.sin(0.5), 0.5], [0.5, 0.0, 0.0]),
           "thruster": (thruster, [0.0, 0.0, 0.3, 1.0, 0.0, 0.0, 0.0], [0.3, 0.0, 0.0, 0.5, 0.2, 0.0])}
C_ROWS = [[[3.0, 0.0], [-2.0, 5.0]], [[-8.0, 30.0], [0.0, 25.0]], [[30.0, 0.0], [10.0, 0.0]]]


def same(a, b):
    assert a.status == b.status and a.message == b.message
    for name in ("t", "q", "v", "p_N", "p_T", "modes"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape and np.array_equal(x, y), name
    assert [(i.t, i.contact, i.p_N) for i in a.impacts] == [(i.t, i.contact, i.p_N) for i in b.impacts]


def close(a, b, rtol=1e-13):
    """Equal to rounding: the same status, message, modes and impacts' contacts, every array within
    rtol of its largest entry."""
    assert a.status == b.status and a.message == b.message and np.array_equal(a.modes, b.modes)
    for name in ("q", "v", "p_N", "p_T"):
        x, y = getattr(a, name), getattr(b, name)
        assert np.max(np.abs(x - y)) <= rtol * max(np.max(np.abs(y)), 1e-300), name
    assert [i.contact for i in a.impacts] == [i.contact for i in b.impacts]


@pytest.mark.parametrize("hold", ["constant", "linear", "affine"])
@pytest.mark.parametrize("name", sorted(Q_CASES))
def test_q_dependent_control_compiled_bit_for_bit(name, hold, monkeypatch):
    build, q0, v0 = Q_CASES[name]
    system = build()
    sched = schedule(hold, Q_ROWS[name])
    scheduled = system.with_control(sched)
    assert general_loop.applicable(scheduled, StepAssembly(scheduled, 1e-3, 0.5), None) is None
    calls = counting(monkeypatch, general_loop, "run_general_loop")
    fast = lcp.simulate(system, 0.6, h=1e-3, q0=q0, v0=v0, control=sched)
    slow = lcp.simulate(system, 0.6, h=1e-3, q0=q0, v0=v0, control=sched, fast=False)
    assert len(calls) == 1 and fast.success, fast.message
    same(fast, slow)
    assert np.any(slow.p_N > 0) and slow.stats.free_steps > 0  # the contact acted and was open
    if name != "thruster":  # it struck (the pendulum its wall, the rod the floor)
        assert len(slow.impacts) >= 1
    if name == "thruster":  # the quaternion stays a unit one
        assert np.allclose(np.linalg.norm(slow.q[:, 3:7], axis=1), 1.0, atol=1e-14)


@pytest.mark.parametrize("hold", ["constant", "linear", "affine"])
@pytest.mark.parametrize("kind", ["jean_pratt", "jean_pratt_full", "chain"])
def test_controlled_constant_system_compiled_bit_for_bit(kind, hold, monkeypatch):
    if kind == "chain":
        system, sc = block_chain(3)
        q0, v0 = sc.q0, sc.v0
    else:
        system = jean_pratt_block(full=kind.endswith("full"))
        q0, v0 = np.zeros(system.n), np.array([1.0, 0.0, -1.0][:system.n])
    sched = schedule(hold, C_ROWS)
    calls = counting(monkeypatch, compiled_loop, "moreau_jean_loop")
    fast = lcp.simulate(system, 0.6, h=1e-3, q0=q0, v0=v0, control=sched)
    slow = lcp.simulate(system, 0.6, h=1e-3, q0=q0, v0=v0, control=sched, fast=False)
    assert len(calls) == 1 and fast.solver == "auto (compiled)" and slow.solver == "auto"
    assert fast.success, fast.message
    if kind == "chain":  # NSGS on three contacts: the compiled loop's sums are not BLAS's (as uncontrolled)
        close(fast, slow)
    else:
        same(fast, slow)
    assert np.any(slow.p_N[:, -1] == 0) and np.any(slow.p_N[:, -1] > 0)  # lifted off by u1


def test_zero_control_is_the_uncontrolled_chain():
    """A zero schedule on the controlled chain: the drift's constant arithmetic plus S B 0, the
    uncontrolled chain's bits by both loops."""
    system, sc = block_chain(3)
    zero = ControlSchedule([0.0, 0.5], np.zeros((1, 2)))
    for fast in (True, False):
        a = lcp.simulate(system, 0.5, h=1e-3, q0=sc.q0, v0=sc.v0, control=zero, fast=fast)
        b = lcp.simulate(sc.system, 0.5, h=1e-3, q0=sc.q0, v0=sc.v0, fast=fast)
        assert np.array_equal(a.q, b.q) and np.array_equal(a.v, b.v) and np.array_equal(a.p_N, b.p_N)


@pytest.mark.parametrize("hold", ["constant", "linear", "affine"])
def test_frictionless_push_exact(hold):
    """A unit block on a frictionless floor pushed along x: v_x(t_k) = v0 + int_0^{t_k} u exactly
    (the impulse of every hold integrated over each step), by the compiled loop."""
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    system = System(q, v, ca.SX.eye(2), ca.vertcat(u[0], -9.81), control=u, control_bounds=(-50, 50),
                    contacts=[Contact(gap=q[1], tangent=q[0], mu=0.0)])
    sched = schedule(hold, [[[3.0], [-1.0]], [[-8.0], [2.0]], [[5.0], [5.0]]])
    h = 0.6 / 700
    res = lcp.simulate(system, 0.6, h=h, q0=[0.0, 0.0], v0=[0.5, 0.0], control=sched)
    assert res.solver == "auto (compiled)"
    exact = 0.5 + sched.integral(res.t)[:, 0]
    assert np.max(np.abs(res.v[:, 0] - exact)) < 1e-13
    assert np.all(res.v[:, 1] == 0.0)


@settings(max_examples=12, deadline=None)
@given(hold=st.sampled_from(["constant", "linear", "affine"]),
       values=st.lists(st.floats(-40.0, 40.0, allow_nan=False, allow_infinity=False), min_size=12, max_size=12),
       mu=st.floats(0.0, 1.0))
def test_drawn_schedules_controlled_block(hold, values, mu):
    system = jean_pratt_block(mu=mu)
    sched = schedule(hold, np.reshape(values, (3, 2, 2)))
    fast = lcp.simulate(system, 0.6, h=2e-3, q0=[0.0, 0.0], v0=[1.0, 0.0], control=sched)
    slow = lcp.simulate(system, 0.6, h=2e-3, q0=[0.0, 0.0], v0=[1.0, 0.0], control=sched, fast=False)
    assert fast.solver == "auto (compiled)"
    same(fast, slow)


@settings(max_examples=6, deadline=None)
@given(hold=st.sampled_from(["constant", "linear", "affine"]),
       values=st.lists(st.floats(-20.0, 20.0, allow_nan=False, allow_infinity=False), min_size=12, max_size=12))
def test_drawn_schedules_rod(hold, values):
    system = rod()
    sched = schedule(hold, np.reshape(values, (3, 2, 2)))
    fast = lcp.simulate(system, 0.6, h=2e-3, q0=[0.0, 0.45, 0.5], v0=[0.5, 0.0, 0.0], control=sched)
    slow = lcp.simulate(system, 0.6, h=2e-3, q0=[0.0, 0.45, 0.5], v0=[0.5, 0.0, 0.0], control=sched, fast=False)
    same(fast, slow)


def test_controlled_long_chain_sparse():
    """100 blocks (200 contact rows: the sparse assembly, S through the factors of W_h): the
    compiled loop adds S B int u by the factors, equal to the Python loop to rounding."""
    system, sc = block_chain(100)
    sched = schedule("affine", C_ROWS)
    assert StepAssembly(system.with_control(sched), 1e-3, 0.5).sparse
    fast = lcp.simulate(system, 0.02, h=1e-3, q0=sc.q0, v0=sc.v0, control=sched)
    slow = lcp.simulate(system, 0.02, h=1e-3, q0=sc.q0, v0=sc.v0, control=sched, fast=False)
    assert fast.solver == "auto (compiled)"
    close(fast, slow)
    assert slow.p_N[-1, -1] < slow.p_N[-1, -2]  # u1 lifts the last block's load


def test_python_loop_note_solver_and_spatial():
    """A controlled constant system the constant compiled loop does not take: solver "lemke" keeps
    the Python loop, and the message says why (the same numbers as fast=False); a spatial contact
    under a one-piece schedule runs the compiled general loop, to rounding of the Python loop."""
    system = jean_pratt_block()
    sched = schedule("constant", C_ROWS)
    fast = lcp.simulate(system, 0.2, h=1e-3, q0=[0.0, 0.0], v0=[1.0, 0.0], control=sched, solver="lemke")
    slow = lcp.simulate(system, 0.2, h=1e-3, q0=[0.0, 0.0], v0=[1.0, 0.0], control=sched, solver="lemke", fast=False)
    assert fast.message == slow.message + (" (Python loop: the compiled loop of a controlled constant system needs the "
                                           "solver 'auto' or 'nsgs' without error_tol, and no projection)")
    assert np.array_equal(fast.q, slow.q)
    q, v, u = ca.SX.sym("q", 3), ca.SX.sym("v", 3), ca.SX.sym("u", 1)
    puck = System(q, v, ca.SX.eye(3), ca.vertcat(u[0], 0, -9.81), control=u, control_bounds=(-9, 9),
                  contacts=[Contact(gap=q[2], tangent=ca.vertcat(q[0], q[1]), mu=0.3)])
    # a one-piece schedule on a spatial contact: a constant spatial system, run by the compiled general
    # loop (compiled_spatial takes no schedule), to rounding of the Python loop's constant S products
    one = ControlSchedule([0.0, 0.2], [2.0])
    res = lcp.simulate(puck, 0.2, h=1e-3, q0=np.zeros(3), v0=[1.0, 0.0, 0.0], control=one)
    ref = lcp.simulate(puck, 0.2, h=1e-3, q0=np.zeros(3), v0=[1.0, 0.0, 0.0], control=one, fast=False)
    assert res.success and res.message == ref.message and "Python loop" not in res.message
    assert np.max(np.abs(res.q - ref.q)) <= 1e-13 and np.max(np.abs(res.v - ref.v)) <= 1e-13
    # the slide under 2 N against mu g: v_x = 1 + (2 - 0.3 * 9.81) t while it slides
    t = res.t
    assert np.max(np.abs(res.v[:, 0] - (1.0 + (2.0 - 0.3 * 9.81) * t))) <= 1e-12


@pytest.mark.parametrize("K", [1, 3])
def test_one_piece_schedule(K):
    """A schedule of one piece is constant in time (the scheduled system is a constant one): the
    constant compiled loop steps it as any controlled constant system, with Jean-Pratt's block (one
    contact) and the chain (three), and the Python loop gives the same numbers."""
    if K == 1:
        system, q0, v0 = jean_pratt_block(), np.zeros(2), np.array([1.0, 0.0])
    else:
        system, sc = block_chain(K)
        q0, v0 = sc.q0, sc.v0
    sched = ControlSchedule([0.0, 0.3], [[4.0, 25.0]])
    assert system.with_control(sched).is_constant
    fast = lcp.simulate(system, 0.3, h=1e-3, q0=q0, v0=v0, control=sched)
    slow = lcp.simulate(system, 0.3, h=1e-3, q0=q0, v0=v0, control=sched, fast=False)
    assert fast.solver == "auto (compiled)"
    (same if K == 1 else close)(fast, slow)
    assert np.all(slow.p_N[-10:, -1] == 0) and slow.q[-1, -1] > 0  # u1 = 25 lifted the (last) block off


def test_batch_refuses_a_scheduled_scene():
    """The batch path (one compiled single-contact kernel for many scenes) has no control: a scene
    whose system carries a schedule, even one constant in time, is refused, not run without it."""
    from lcp.batch import simulate_batch
    from lcp.scenes.scene import Scene

    system = jean_pratt_block().with_control(ControlSchedule([0.0, 0.3], [[4.0, 0.0]]))
    assert system.is_constant
    scene = Scene(system, np.zeros(2), np.array([1.0, 0.0]), 0.3, "pushed", {}, None)
    with pytest.raises(ValueError, match="not a constant single-contact system"):
        simulate_batch([scene], 0.3, h=1e-3)
