"""What a Moreau-Jean result tells: named contact modes, impacts, constraint violation, and the
generalized forces of lcp.model.forces (time-dependent ones against exact solutions)."""
import math

import casadi as ca
import numpy as np
import pytest

import lcp
from lcp.classical import bouncing_ball
from lcp.contact.problem import MODE_NAMES, OPEN, SLIDE_NEG, SLIDE_POS, STICK, ContactMode, ModeArray
from lcp.model.forces import applied_forces, point_force, point_velocity, torque
from lcp.scenes import jean_pratt
from lcp.model.system import Contact, System


# ----------------------------------------------------------------------------- modes
def test_modes_are_named_and_keep_their_integers():
    assert [int(x) for x in (OPEN, STICK, SLIDE_POS, SLIDE_NEG, ContactMode.INACTIVE)] == [0, 1, 2, 3, -1]
    assert MODE_NAMES[1] == MODE_NAMES[STICK] == "stick"
    res = lcp.simulate(jean_pratt(), 0.3, h=1e-2)
    md = res.modes
    assert isinstance(md, ModeArray) and md.dtype == np.int8
    assert np.array_equal(md == 2, md == SLIDE_POS) and (md == 1).sum() > 0
    assert "SLIDE_POS" in repr(md) and "STICK" in str(md[:, 0])
    assert md.names[0, 0] == "SLIDE_POS" and md.names[-1, 0] == "STICK"
    assert type(md == 1) is np.ndarray  # a mask is not a mode array
    slow = lcp.simulate(jean_pratt(), 0.3, h=1e-2, fast=False)
    np.testing.assert_array_equal(slow.modes, md)
    assert isinstance(slow.modes, ModeArray)


# ----------------------------------------------------------------------------- impacts
@pytest.mark.parametrize("fast", [True, False])
@pytest.mark.parametrize("e", [0.0, 0.5])
def test_impacts_of_a_dropped_ball(fast, e):
    sc = bouncing_ball(e=e, height=1.0)
    ex = sc.solution
    h = 1e-4
    res = lcp.simulate(sc, h=h, fast=fast)
    assert res.success
    imp = res.impacts
    assert imp and all(isinstance(i.t, float) and i.contact == 0 and i.name == "floor" for i in imp)
    # the first impact: closing time estimated inside its step, impulse m (1 + e) v1 to O(h)
    assert abs(imp[0].t - ex.impact_times[0]) <= h
    assert imp[0].p_N == pytest.approx(ex.impulses[0], rel=10 * h * 9.81 / ex.approach_speeds[0] + 1e-3)
    assert imp[0].p_T == 0.0
    if e > 0:  # the next impacts too, within O(h) growing with their number
        for k in range(1, 4):
            assert abs(imp[k].t - ex.impact_times[k]) <= 20 * k * h
    # no impact while resting: none after the accumulation (plus the O(h) of the scheme)
    assert all(i.t <= ex.t_inf + 0.02 for i in imp)


def test_impacts_agree_between_paths_and_with_decimation():
    sc = bouncing_ball(e=0.5)
    a = lcp.simulate(sc, h=1e-3)
    b = lcp.simulate(sc, h=1e-3, fast=False)
    c = lcp.simulate(sc, h=1e-3, fast=False, save_every=7)
    assert "compiled" in a.solver and len(a.impacts) == len(b.impacts) == len(c.impacts) > 3
    for x, y, z in zip(a.impacts, b.impacts, c.impacts):
        assert x.t == pytest.approx(y.t, abs=1e-12) and x.p_N == pytest.approx(y.p_N, rel=1e-12)
        assert y == z
    assert lcp.simulate(sc, h=1e-3, save_every=7).impacts is None  # compiled, decimated: not recorded


def test_landing_without_speed_is_not_an_impact():
    # a block resting on a floor, then loaded by a growing downward push: no impact, ever
    q, v, t = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("t")
    s = System(q, v, ca.SX.eye(2), ca.vertcat(0, -9.81 - t), t=t, contacts=[Contact(gap=q[1], tangent=q[0])])
    res = lcp.simulate(s, 0.5, h=1e-3, q0=[0, 0], v0=[0, 0])
    assert res.success and res.impacts == []


# ----------------------------------------------------------------------------- violation, message
def test_max_constraint_violation_without_projection():
    sc = bouncing_ball(e=0.0)
    res = lcp.simulate(sc, h=1e-3)
    assert res.max_constraint_violation == pytest.approx(max(0.0, -float(res.q[:, 1].min())), rel=1e-14)
    assert res.max_constraint_violation > 0  # the velocity-level impact leaves O(h) penetration


def test_several_solutions_are_named_in_the_message():
    # no gravity, kappa > 1: the contact carries no load, and stick and open both solve each step
    res = lcp.simulate(jean_pratt(R=2.5, g=0.0), 0.02, h=1e-3, fast=False)
    assert res.success and res.stats.ambiguous_steps > 0
    assert "several solutions" in res.message and "step 0" in res.message


# ----------------------------------------------------------------------------- forces
def test_point_force_is_virtual_work():
    q = ca.SX.sym("q", 3)  # x, y, angle of a body; force F at the body point (a, b)
    x, y, th = q[0], q[1], q[2]
    a, b = 0.3, -0.2
    r = ca.vertcat(x + a * ca.cos(th) - b * ca.sin(th), y + a * ca.sin(th) + b * ca.cos(th))
    F = ca.vertcat(2.0, -5.0)
    Q = ca.Function("Q", [q], [point_force(q, r, F)])
    for qv in ([0.1, -0.4, 0.7], [0.0, 0.0, -2.0]):
        th_ = qv[2]
        rx, ry = a * math.cos(th_) - b * math.sin(th_), a * math.sin(th_) + b * math.cos(th_)
        np.testing.assert_allclose(np.array(Q(qv)).ravel(), [2.0, -5.0, rx * -5.0 - ry * 2.0], rtol=1e-14)
    v = ca.SX.sym("v", 3)
    vel = ca.Function("vel", [q, v], [point_velocity(q, v, r)])
    np.testing.assert_allclose(np.array(vel([0, 0, 0], [1, 2, 3])).ravel(), [1 - 3 * b, 2 + 3 * a], rtol=1e-14)
    assert float(ca.evalf(ca.substitute(torque(q, th, 4.0), q, ca.DM([0, 0, 0]))[2])) == 4.0
    Qs = applied_forces(q, [(r, F), (q[:2], [0, -1.0])])
    np.testing.assert_allclose(np.array(ca.evalf(ca.substitute(Qs, q, ca.DM([0, 0, 0])))).ravel(),
                               [2.0, -6.0, a * -5.0 - b * 2.0])
    with pytest.raises(ValueError, match="same shape"):
        point_force(q, r, [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="q must be"):
        point_force(ca.SX.sym("q", 2) * 2, r, F)


def test_time_dependent_force_driven_oscillator_second_order():
    # m x'' + k x = F0 sin(w t) from rest: x = F0 / (m (w0^2 - w^2)) (sin(w t) - (w / w0) sin(w0 t))
    m, k, F0, w = 2.0, 50.0, 3.0, 3.0
    w0 = math.sqrt(k / m)
    q, v, t = ca.SX.sym("q", 1), ca.SX.sym("v", 1), ca.SX.sym("t")
    s = System(q, v, m, -k * q + point_force(q, q, F0 * ca.sin(w * t)), t=t)
    T = 3.0
    errs = []
    for h in (4e-3, 2e-3, 1e-3):
        res = lcp.simulate(s, T, h=h, q0=[0.0], v0=[0.0])
        exact = F0 / (m * (w0 ** 2 - w ** 2)) * (np.sin(w * res.t) - w / w0 * np.sin(w0 * res.t))
        errs.append(np.max(np.abs(res.q[:, 0] - exact)))
    order = np.polyfit(np.log([4e-3, 2e-3, 1e-3]), np.log(errs), 1)[0]
    assert 1.8 <= order <= 2.2
    assert errs[-1] <= 1e-4


def test_ramp_push_on_a_block_stick_then_slip():
    # push c t on a block with friction mu: stick until t* = mu m g / c, then x = c (t - t*)^3 / (6 m)
    m, mu, g, c = 1.5, 0.4, 9.81, 10.0
    q, v, t = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("t")
    s = System(q, v, m * ca.SX.eye(2), ca.vertcat(0, -m * g) + point_force(q, q, ca.vertcat(c * t, 0)), t=t,
               contacts=[Contact(gap=q[1], tangent=q[0], mu=mu)])
    t_star = mu * m * g / c
    T = 1.2
    for h in (8e-3, 4e-3 * (1 + 1 / 7), 1e-3, 2.5e-4 * (1 + 1 / 3)):
        res = lcp.simulate(s, T, h=h, q0=[0, 0], v0=[0, 0])
        assert res.success and np.max(np.abs(res.q[:, 1])) <= 1e-15
        stuck = res.t <= t_star - h
        assert np.all(res.q[stuck, 0] == 0.0)  # a loaded stick holds exactly
        dt = np.maximum(res.t - t_star, 0.0)
        # second order: only the step containing t* errs, its velocity gain by at most c h^2 / (2 m)
        # (stick or slide over the whole step instead of the switch inside it)
        dv = c * h * h / (2 * m)
        assert np.max(np.abs(res.v[:, 0] - c * dt ** 2 / (2 * m))) <= dv * (1 + 1e-9)
        assert np.max(np.abs(res.q[:, 0] - c * dt ** 3 / (6 * m))) <= dv * (T - t_star + h)
