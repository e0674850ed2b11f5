"""The order-two scheme (``scheme="order2"``): order two on smooth constrained motion against
references from ``solve_ivp`` (DOP853, rtol 1e-12) on reduced equations, the pendulum's period and
energy over 100 periods, and Moreau-Jean's contact answers kept (sliding stop, restitution,
Jean-Pratt's exactness)."""
import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, strategies as st
from scipy.integrate import solve_ivp

import lcp
from lcp.model.system import System
from lcp.scenes import jean_pratt
from lcp.scenes.classical import bouncing_ball, incline, pendulum, slider_crank
from lcp.timestepping.moreau_jean import MoreauJeanOptions

from .conftest import X_ROUNDING, Y_TOL
from .helpers import jean_pratt_errors

STEPS = (4e-3, 2e-3, 1e-3, 5e-4)
G = 9.81


def _pendulum_reference(theta0, t, L=1.0, g=G, rhs=None):
    """theta(t), theta'(t) of the reduced pendulum equation, by DOP853 at rtol 1e-12."""
    f = rhs or (lambda _t, y: [y[1], -g / L * math.sin(y[0])])
    sol = solve_ivp(f, (0.0, t), [theta0, 0.0], method="DOP853", rtol=1e-12, atol=1e-14)
    return sol.y[0, -1], sol.y[1, -1]


def _orders(errors):
    e = np.asarray(errors)
    return np.log2(e[:-1] / e[1:])


def test_pendulum_order_two_at_90_degrees():
    t_end = 1.0
    th, thd = _pendulum_reference(math.pi / 2, t_end)
    q_ref = np.array([math.sin(th), -math.cos(th)])
    v_ref = thd * np.array([math.cos(th), math.sin(th)])
    sc = pendulum(theta0=math.pi / 2)
    # the reduced reference agrees with the scene's exact (elliptic-function) solution
    assert np.max(np.abs(sc.exact(t_end)["q"][0] - q_ref)) < 1e-10
    eq, ev = [], []
    for h in STEPS:
        res = lcp.simulate(sc, t_end, h=h, scheme="order2")
        assert res.success, res.message
        assert res.t[-1] == pytest.approx(t_end, abs=1e-12)
        assert res.stats.free_steps == res.stats.steps and res.stats.projections == 0
        eq.append(np.max(np.abs(res.q[-1] - q_ref)))
        ev.append(np.max(np.abs(res.v[-1] - v_ref)))
        # SHAKE keeps the length and RATTLE the velocity constraint to rounding at every point
        assert np.max(np.abs(np.hypot(res.q[:, 0], res.q[:, 1]) - 1)) < 1e-13
        assert np.max(np.abs(np.sum(res.q * res.v, axis=1))) < 1e-12
    assert np.all(_orders(eq) >= 1.9) and np.all(_orders(ev) >= 1.9)
    assert eq[2] < 5e-6  # h = 1e-3: 2.9e-6 (Moreau-Jean: 2.9e-3)
    # Moreau-Jean with its projection is of order one here (the measurement)
    mj = [np.max(np.abs(lcp.simulate(sc, t_end, h=h).q[-1] - q_ref)) for h in STEPS[:2]]
    assert 0.9 <= _orders(mj)[0] <= 1.1


def test_slider_crank_order_two():
    # q-dependent mass matrix, Coriolis forces, two nonlinear loop-closure constraints
    sc = slider_crank(t_end=0.5)
    ref = sc.exact(0.5)
    eq, ev = [], []
    for h in STEPS:
        res = lcp.simulate(sc, h=h, scheme="order2")
        assert res.success, res.message
        eq.append(np.max(np.abs(res.q[-1] - ref["q"][0])))
        ev.append(np.max(np.abs(res.v[-1] - ref["v"][0])))
        # SHAKE's tolerance: 1e-12 relative to the size of the terms, l1 + l2 = 0.17 m
        assert res.max_constraint_violation <= 1e-12 * 0.17 * 1.01
    assert np.all(_orders(eq) >= 1.9) and np.all(_orders(ev) >= 1.9)
    assert eq[-1] < 1e-3  # h = 5e-4: 4.8e-4 rad on the crank after 15 rad of travel


def test_damped_driven_pendulum_order_two():
    # velocity- and time-dependent forces: the first kick's linearized implicit term is needed
    c, A, w = 0.7, 3.0, 4.0
    q, v, t = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("t")
    F = ca.vertcat(A * ca.sin(w * t), -G) - c * v
    s = System(q, v, ca.SX.eye(2), F, constraints=q[0] ** 2 + q[1] ** 2 - 1, t=t)

    def rhs(tt, y):
        return [y[1], -G * math.sin(y[0]) - c * y[1] + A * math.sin(w * tt) * math.cos(y[0])]

    th, _ = _pendulum_reference(1.2, 1.0, rhs=rhs)
    q_ref = np.array([math.sin(th), -math.cos(th)])
    err = []
    for h in STEPS:
        res = lcp.simulate(s, 1.0, h=h, q0=[math.sin(1.2), -math.cos(1.2)], v0=[0.0, 0.0], scheme="order2")
        assert res.success, res.message
        err.append(np.max(np.abs(res.q[-1] - q_ref)))
    assert np.all(_orders(err) >= 1.9)


@given(theta0=st.floats(0.1, 3.0))
def test_pendulum_error_quarters_with_h(theta0):
    th, _ = _pendulum_reference(theta0, 0.5)
    q_ref = np.array([math.sin(th), -math.cos(th)])
    sc = pendulum(theta0=theta0)
    e = [np.max(np.abs(lcp.simulate(sc, 0.5, h=h, scheme="order2").q[-1] - q_ref)) for h in (2e-3, 1e-3)]
    assert 3.6 <= e[0] / e[1] <= 4.4


def test_pendulum_period_and_energy_over_100_periods():
    sc = pendulum(theta0=math.pi / 2, periods=100)
    res = lcp.simulate(sc, h=1e-3, scheme="order2")
    assert res.success, res.message
    x = res.q[:, 0]
    i = np.flatnonzero((x[:-1] > 0) & (x[1:] <= 0))  # one downward crossing per period
    tc = res.t[i] + (res.t[i + 1] - res.t[i]) * x[i] / (x[i] - x[i + 1])
    assert len(tc) == 100
    period = (tc[-1] - tc[0]) / (len(tc) - 1)
    assert abs(period / sc.solution.period - 1) <= 1e-5  # measured 1.4e-6 (Moreau-Jean: 4.3e-2)
    E = 0.5 * np.sum(res.v ** 2, axis=1) + G * res.q[:, 1]
    dE = E - E[0]
    assert np.max(np.abs(dE)) <= 1e-4  # of m g L = 9.81 J; Moreau-Jean loses 3.2 J
    # no secular drift: the last ten periods' error no larger than the first ten's
    n10 = len(E) // 10
    assert np.max(np.abs(dE[-n10:])) <= 1.1 * np.max(np.abs(dE[:n10]))
    assert abs(np.mean(dE[-n10:]) - np.mean(dE[:n10])) <= 1e-7


@pytest.mark.parametrize("alpha, mu, v0", [(0.0, 0.4, 2.0), (0.3, 0.5, 2.0), (0.3, 0.5, -1.0)])
def test_block_slides_to_rest_as_moreau_jean(alpha, mu, v0):
    sc = incline(alpha=alpha, mu=mu, v0=v0, t_end=1.0)
    for h in (1e-2, 1e-3):
        mj = lcp.simulate(sc, h=h, fast=False)
        o2 = lcp.simulate(sc, h=h, scheme="order2")
        assert o2.success
        # the contact stays closed: every step is Moreau-Jean's, to the last bit
        assert np.array_equal(o2.q, mj.q) and np.array_equal(o2.v, mj.v) and np.array_equal(o2.p_T, mj.p_T)
        err = np.max(np.abs(o2.q - sc.exact(o2.t)["q"]))
        assert err <= 0.5 * h * h * (v0 ** 2 + 1)  # the stop within a step: O(h^2)
        s_end = sc.exact(1.0)["s"][0]
        ca_, sa = math.cos(alpha), math.sin(alpha)
        assert abs(o2.q[-1] @ [ca_, sa] - s_end) <= 0.5 * h * h * (v0 ** 2 + 1)
        assert abs(o2.v[-1] @ [ca_, sa]) <= 1e-12  # at rest


def test_bouncing_ball_restitution_and_impact_times():
    sc = bouncing_ball(e=0.5, height=1.0)
    ex = sc.solution
    errs = []
    for h in (1e-2, 1e-3, 1e-4):
        res = lcp.simulate(sc, h=h, scheme="order2")
        assert res.success, res.message
        t_imp = np.array([i.t for i in res.impacts])
        assert len(t_imp) >= 5
        err = np.max(np.abs(t_imp[:5] - ex.impact_times[:5]))
        assert err <= 5 * h  # measured 2.8 h, 2.6 h, 4.1 h: Moreau-Jean's own errors (below)
        mj = np.array([i.t for i in lcp.simulate(sc, h=h, fast=False).impacts])
        assert np.max(np.abs(t_imp[:5] - mj[:5])) <= 1e-9
        errs.append(err)
        # Newton's law: each impulse m (1 + e) times the approach speed, to O(h) (the step's impulse
        # also carries the weight over part of the step)
        p = np.array([i.p_N for i in res.impacts[:5]])
        assert np.max(np.abs(p - ex.impulses[:5])) <= 2 * (1 + 0.5) * G * h
        # between impacts a RATTLE step is exact under constant gravity
        assert res.stats.free_steps > 0.8 * res.stats.steps * min(1.0, ex.t_inf / sc.t_end)
        # after t_inf: bounces below the step's resolution only (as Moreau-Jean's); an impact step
        # sinks by O(h) as Moreau-Jean's (velocity-level impacts, no projection of an affine gap)
        assert abs(res.q[-1, 1]) <= G * h * h and abs(res.v[-1, 1]) <= G * h
        assert np.min(res.q[:, 1]) >= -h * ex.approach_speeds[0]
    assert errs[2] < errs[0] / 20


@pytest.mark.parametrize("R, v0, h", [(0.5, 1.0, 1e-2), (0.5, 1.0, 1e-3), (0.3, 1.0, 1e-3), (0.5, -1.0, 1e-3)])
def test_jean_pratt_exactness_kept(R, v0, h):
    # the contact never opens: the scheme takes Moreau-Jean's steps, so the B h^2/8 law holds
    sc = jean_pratt(R=R, v0=v0)
    o2 = lcp.simulate(sc, 0.3, h=h, scheme="order2")
    mj = lcp.simulate(sc, 0.3, h=h, fast=False)
    assert o2.success and o2.stats.free_steps == 0
    assert np.array_equal(o2.q, mj.q) and np.array_equal(o2.p_N, mj.p_N) and np.array_equal(o2.p_T, mj.p_T)
    err = jean_pratt_errors(sc, o2)
    assert err["x"] <= err["bound"] + X_ROUNDING
    assert err["y"] <= Y_TOL


def test_scheme_option_validated():
    with pytest.raises(ValueError, match="scheme must be one of"):
        MoreauJeanOptions(h=1e-3, scheme="rattle")
    with pytest.raises(ValueError, match="scheme must be one of"):
        lcp.simulate(pendulum(), 0.1, scheme=2)
    with pytest.raises(ValueError, match="scheme must be one of"):
        lcp.simulate(jean_pratt(), 0.1, method="event", scheme="order-2")
    assert MoreauJeanOptions(h=1e-3).scheme == "moreau-jean"


def test_control_schedule_refused():
    from lcp.model.control import ControlSchedule

    q, v, u = ca.SX.sym("q", 1), ca.SX.sym("v", 1), ca.SX.sym("u", 1)
    s = System(q, v, mass=1.0, force=u, control=u)
    with pytest.raises(ValueError, match="control schedule"):
        lcp.simulate(s, 1.0, h=0.25, q0=[0.0], v0=[0.0], control=ControlSchedule([0, 0.5, 1.0], [1.0, -1.0]),
                     scheme="order2")


def test_shake_failure_is_reported():
    # a step far too large for the pendulum: SHAKE cannot reach the circle, status -5, never silent
    res = lcp.simulate(pendulum(theta0=1.5), 2.0, h=0.5, scheme="order2")
    assert res.status == -5 and "SHAKE" in res.message
    assert res.t[-1] < 2.0
