"""The order-two scheme while contacts stay closed (``scheme="order2"``, lcp.timestepping.closed_rattle):
a point mass in a circular bowl (frictionless: the exact pendulum by elliptic functions; with
sliding friction: DOP853 at rtol 1e-13 on the reduced equation), the rocking block's sticking
pivot (its DOP853 reference), lift-off from a sphere at cos(theta) = 2/3 cos(theta0), and the
result naming its scheme. Moreau-Jean is of order one on every one of these."""
import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy.integrate import solve_ivp

import lcp
from lcp.model.system import Contact, System
from lcp.scenes import jean_pratt
from lcp.scenes.classical import PendulumExact, incline, rocking_block

G = 9.81
STEPS = (4e-3, 2e-3, 1e-3, 5e-4)


def _orders(errors):
    e = np.asarray(errors)
    return np.log2(e[:-1] / e[1:])


def _bowl(mu=0.0, L=1.0):
    """A point mass inside a circle of radius L about the origin: gap L - |q|, tangent the arc length."""
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    c = Contact(gap=L - ca.norm_2(q), tangent=L * ca.atan2(q[0], -q[1]), mu=mu, name="bowl")
    return System(q, v, ca.SX.eye(2), ca.vertcat(0, -G), contacts=[c], names=("x", "y"))


def _sphere(R=1.0):
    """A point mass on top of a circle of radius R: gap |q| - R."""
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    c = Contact(gap=ca.norm_2(q) - R, tangent=R * ca.atan2(q[0], q[1]), name="sphere")
    return System(q, v, ca.SX.eye(2), ca.vertcat(0, -G), contacts=[c], names=("x", "y"))


def test_frictionless_bowl_is_a_pendulum_of_order_two():
    th0, t_end = math.pi / 3, 1.0
    s = _bowl()
    q0 = np.array([math.sin(th0), -math.cos(th0)])
    ex = PendulumExact(1.0, th0, G)
    q_ref, v_ref = ex(t_end)["q"][0], ex(t_end)["v"][0]
    eq, ev, mj = [], [], []
    for h in STEPS:
        res = lcp.simulate(s, t_end, h=h, q0=q0, v0=[0.0, 0.0], scheme="order2")
        assert res.success, res.message
        assert res.method == "moreau-jean" and res.scheme == "order2"
        # one Moreau-Jean step catches the contact from rest, then every step holds it
        assert res.stats.closed_steps == res.stats.steps - 1
        eq.append(np.max(np.abs(res.q[-1] - q_ref)))
        ev.append(np.max(np.abs(res.v[-1] - v_ref)))
        # SHAKE holds the mass on the bowl to rounding, never inside it
        assert np.max(np.abs(np.hypot(res.q[1:, 0], res.q[1:, 1]) - 1)) < 1e-13
        # the mean normal force over each step: the pendulum's tension m (g cos(theta) + L theta'^2)
        # at the step's midpoint, within O(h^2)
        exs = ex(res.t[:-1] + h / 2)
        th, thd = exs["theta"], exs["theta_dot"]
        N = res.p_N[:, 0] / h
        tension = G * np.cos(th) + thd ** 2
        assert np.max(np.abs(N - tension)[1:]) < 50 * h * h  # measured 45.1 h^2 at every h
        if h >= 2e-3:
            mj.append(np.max(np.abs(lcp.simulate(s, t_end, h=h, q0=q0, v0=[0.0, 0.0]).q[-1] - q_ref)))
    assert np.all(_orders(eq) >= 1.9) and np.all(_orders(ev) >= 1.9)
    assert eq[2] < 1e-6  # h = 1e-3: 5.5e-7 (Moreau-Jean: 3.0e-4)
    assert 0.9 <= _orders(mj)[0] <= 1.1  # Moreau-Jean: order one


@settings(max_examples=10, deadline=None)
@given(th0=st.floats(0.2, 1.4))
def test_bowl_error_quarters_with_h(th0):
    # any release angle below 90 degrees: the contact stays loaded (tension >= m g cos(theta0))
    s = _bowl()
    ref = PendulumExact(1.0, th0, G)(0.5)["q"][0]
    q0 = [math.sin(th0), -math.cos(th0)]
    e = [np.max(np.abs(lcp.simulate(s, 0.5, h=h, q0=q0, v0=[0.0, 0.0], scheme="order2").q[-1] - ref))
         for h in (2e-3, 1e-3)]
    assert 3.6 <= e[0] / e[1] <= 4.4


def test_sliding_friction_in_bowl_order_two():
    # Coulomb sliding coupled to the normal multiplier: m L theta'' = -m g sin(theta) - mu N sign(theta'),
    # N = m (g cos(theta) + L theta'^2); released at 60 degrees, it slides down without stopping up to 0.4 s
    mu, th0, t_end = 0.2, math.pi / 3, 0.4
    s = _bowl(mu)

    def rhs(_t, y):
        return [y[1], -G * math.sin(y[0]) + mu * (y[1] ** 2 + G * math.cos(y[0]))]  # theta' < 0

    sol = solve_ivp(rhs, (0.0, t_end), [th0, 0.0], method="DOP853", rtol=1e-13, atol=1e-14)
    th, thd = sol.y[:, -1]
    assert thd < 0
    q_ref = np.array([math.sin(th), -math.cos(th)])
    q0 = np.array([math.sin(th0), -math.cos(th0)])
    err = []
    for h in STEPS:
        res = lcp.simulate(s, t_end, h=h, q0=q0, v0=[0.0, 0.0], scheme="order2")
        assert res.success, res.message
        assert res.stats.closed_steps == res.stats.steps - 1
        assert res.stats.mode_counts["slide-"] == res.stats.steps
        # the friction impulse is -mu p_N sign(u_T) in every step
        assert np.allclose(res.p_T[:, 0], mu * res.p_N[:, 0], rtol=1e-12, atol=0)
        err.append(np.max(np.abs(res.q[-1] - q_ref)))
    assert np.all(_orders(err) >= 1.9)
    assert err[2] < 1e-6  # h = 1e-3: 4.6e-7 (Moreau-Jean: 2.5e-4)


def test_rocking_block_sticking_pivot_order_two():
    # the pivot corner sticks (mu = 2): its tangent held as a constraint; theta before the first
    # impact (t = 0.2647) against Housner's equation by DOP853
    sc = rocking_block(t_end=0.2)
    ref = sc.solution(0.2)["theta"][0]
    err = []
    for h in STEPS:
        res = lcp.simulate(sc, h=h, scheme="order2")
        assert res.success, res.message
        assert res.stats.closed_steps == res.stats.steps - 1 and res.stats.mode_counts["stick"] >= res.stats.steps
        # the pivot corner does not move: x and the height of the corner stay put to rounding
        err.append(abs(res.q[-1, 2] - ref))
    assert np.all(_orders(err) >= 1.9)
    assert err[2] < 2e-7  # h = 1e-3: 8.6e-8 (Moreau-Jean: 4.2e-5)
    mj = lcp.simulate(sc, h=1e-3, fast=False)
    assert abs(mj.q[-1, 2] - ref) > 100 * err[2]


def test_disk_rolling_in_circular_track_order_two():
    # a uniform disk (radius r) rolling without slip inside a circle of radius R: its centre is a
    # pendulum of length R - r under 2 g / 3 (exact by elliptic functions); the contact sticks
    # (friction/normal at most tan(60 deg)/3 < mu), its tangent row (the contact point's velocity,
    # with the spin) held by the midpoint rule
    R, r, th0, t_end = 1.0, 0.25, math.pi / 3, 1.0
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    n = q[:2] / ca.norm_2(q[:2])
    rim = Contact(gap=R - r - ca.norm_2(q[:2]), tangent_jacobian=ca.horzcat(-n[1], n[0], r), mu=1.0, name="rim")
    s = System(q, v, ca.diag(ca.vertcat(1.0, 1.0, r * r / 2)), ca.vertcat(0, -G, 0), contacts=[rim])
    L = R - r
    ref = PendulumExact(L, th0, 2 * G / 3)(t_end)["q"][0]
    q0 = [L * math.sin(th0), -L * math.cos(th0), 0.0]
    err, slip = [], []
    for h in STEPS:
        res = lcp.simulate(s, t_end, h=h, q0=q0, v0=[0.0, 0.0, 0.0], scheme="order2")
        assert res.success, res.message
        assert res.stats.closed_steps == res.stats.steps - 1 and res.stats.mode_counts["stick"] == res.stats.steps
        err.append(np.max(np.abs(res.q[-1, :2] - ref)))
        # rolling: the spin follows the centre, theta = -(L / r) (phi - phi0), to O(h^2)
        phi = math.atan2(res.q[-1, 0], -res.q[-1, 1])
        slip.append(abs(res.q[-1, 2] + L / r * (phi - th0)))
    assert np.all(_orders(err) >= 1.9) and np.all(_orders(slip) >= 1.9)
    assert err[2] < 1e-6  # h = 1e-3: 5.1e-7 (Moreau-Jean: 5.7e-4)


def _sphere_reference(th0, R=1.0):
    """The lift-off time and state of a mass released at rest at th0 from the top of a sphere, and
    the exact motion: DOP853 (rtol 1e-13) on theta'' = g/R sin(theta) up to N = 0, then a parabola."""
    def rhs(_t, y):
        return [y[1], G / R * math.sin(y[0])]

    def leave(_t, y):
        return G * math.cos(y[0]) - R * y[1] ** 2

    leave.terminal, leave.direction = True, -1
    sol = solve_ivp(rhs, (0.0, 5.0), [th0, 0.0], method="DOP853", rtol=1e-13, atol=1e-15, events=leave,
                    dense_output=True)
    ts = float(sol.t_events[0][0])
    th, w = sol.y_events[0][0]
    qs = R * np.array([math.sin(th), math.cos(th)])
    vs = R * w * np.array([math.cos(th), -math.sin(th)])

    def q_at(t):
        if t <= ts:
            y = sol.sol(t)
            return R * np.array([math.sin(y[0]), math.cos(y[0])])
        d = t - ts
        return qs + vs * d + 0.5 * np.array([0.0, -G]) * d * d

    return ts, math.cos(th), q_at


def test_lift_off_from_sphere():
    th0 = 0.3
    ts, cos_leave, q_at = _sphere_reference(th0)
    assert cos_leave == pytest.approx(2 / 3 * math.cos(th0), abs=1e-12)  # the classical angle
    s = _sphere()
    q0 = np.array([math.sin(th0), math.cos(th0)])
    before, after = [], []
    for h in STEPS + (2.5e-4,):
        res = lcp.simulate(s, 0.8, h=h, q0=q0, v0=[0.0, 0.0], scheme="order2")
        assert res.success, res.message
        r = np.hypot(res.q[:, 0], res.q[:, 1])
        i = round(0.5 / h)
        before.append(np.max(np.abs(res.q[i] - q_at(0.5))))
        after.append(np.max(np.abs(res.q[-1] - q_at(0.8))))
        # held on the sphere while it presses, never inside it
        assert np.max(np.abs(r[1:i + 1] - 1)) < 1e-13 and np.min(r) > 1 - 1e-13
        # released within a step or two of the exact lift-off, and no force after it (no pull-back)
        loaded = np.flatnonzero(res.p_N[:, 0] > 0)
        assert abs(res.t[loaded[-1]] - ts) <= 2 * h
        assert np.all(res.p_N[loaded[-1] + 1:, 0] == 0) and np.all(res.p_N[:, 0] >= 0)
        # free flight after it: the gap grows and no contact step follows
        k = loaded[-1] + 2
        assert np.all(np.diff(r[k:]) > 0)
        assert res.stats.free_steps >= len(res.t) - 1 - k
    assert np.all(_orders(before) >= 1.9)
    # after the switch: order two as well (measured 2.24, 2.14, 2.08, 2.05; 9.6e-8 at h = 1e-3)
    assert np.all(_orders(after) >= 1.9) and after[2] < 2e-7
    mj = lcp.simulate(s, 0.8, h=1e-3, q0=q0, v0=[0.0, 0.0])
    assert np.max(np.abs(mj.q[-1] - q_at(0.8))) > 1e3 * after[2]


@settings(max_examples=10, deadline=None)
@given(th0=st.floats(0.1, 1.0))
def test_lift_off_error_quarters_with_h(th0):
    # the error 0.2 s after the lift-off, wherever it falls in the step (measured 3.86 ... 4.03)
    ts, _, q_at = _sphere_reference(th0)
    s = _sphere()
    q0 = np.array([math.sin(th0), math.cos(th0)])
    t_end = round((ts + 0.2) / 4e-3) * 4e-3
    e = []
    for h in (1e-3, 5e-4):
        res = lcp.simulate(s, t_end, h=h, q0=q0, v0=[0.0, 0.0], scheme="order2")
        assert res.success and np.all(res.p_N >= 0)
        e.append(np.max(np.abs(res.q[-1] - q_at(res.t[-1]))))
        assert e[-1] <= 0.7 * h * h  # measured 0.06 ... 0.6 h^2
    assert 3.6 <= e[0] / e[1] <= 4.4


@pytest.mark.parametrize("alpha, mu, v0", [(0.5, 0.2, 0.0), (0.5, 0.2, -1.0)])
def test_incline_slide_exact(alpha, mu, v0):
    # constant acceleration g (sin - mu cos) down the slope: exact to rounding (Moreau-Jean's step
    # on a constant system, which the scheme keeps: it is exact there)
    sc = incline(alpha=alpha, mu=mu, v0=v0, t_end=0.5)
    for h in (1e-2, 1e-3):
        res = lcp.simulate(sc, h=h, scheme="order2")
        assert res.success and res.scheme == "order2"
        ex = sc.exact(res.t)
        assert np.max(np.abs(res.q - ex["q"])) < 1e-13
        assert np.max(np.abs(res.v[-1] @ [math.cos(alpha), math.sin(alpha)]
                             - (v0 - G * (math.sin(alpha) - mu * math.cos(alpha)) * 0.5))) < 1e-12


@pytest.mark.parametrize("R, v0, h", [(0.5, 1.0, 1e-3), (0.5, -1.0, 1e-3)])
def test_jean_pratt_unchanged(R, v0, h):
    # a constant system: every contact step is Moreau-Jean's, to the last bit
    sc = jean_pratt(R=R, v0=v0)
    o2 = lcp.simulate(sc, 0.3, h=h, scheme="order2")
    mj = lcp.simulate(sc, 0.3, h=h, fast=False)
    assert o2.stats.closed_steps == 0 and o2.scheme == "order2" and mj.scheme == "moreau-jean"
    assert np.array_equal(o2.q, mj.q) and np.array_equal(o2.p_T, mj.p_T)


def test_scheme_reported():
    sc = jean_pratt()
    assert lcp.simulate(sc, 0.01, h=1e-3).scheme == "moreau-jean"
    assert lcp.simulate(sc, 0.01, method="event").scheme == "event"
    res = lcp.simulate(_bowl(), 0.01, h=1e-3, q0=[0.0, -1.0], v0=[1.0, 0.0], scheme="order2")
    assert "scheme='order2'" in repr(res)
