"""The event method on moving contacts: gaps and tangents that depend on time.

The local velocity of a moving contact is u = H(t, q) v + b(t, q), b = (dg/dt, ds/dt); impacts
apply Newton's law to it, the acceleration-level problem is written on du/dt (its drift by AD on
u(t, q, v)), and events are located on g(t, q(t)). References: the same physics with the obstacle a
coordinate pinned by a rheonomous bilateral constraint (which the event method integrated before),
the moving table's impacts by root finding on the flight parabola
(:func:`lcp.scenes.moving.table_impacts`), the conveyor's closed form, the lift-off time of a ball
on a table whose downward acceleration exceeds g, and Moreau-Jean as h -> 0.
"""
import casadi as ca
import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

import lcp
from lcp.model.system import Contact, System
from lcp.scenes.moving import cam_follower, conveyor, moving_table, table_impacts

A, W, E = 0.05, 6.0, 0.7
TABLE = dict(amplitude=A, omega=W, e=E, height=0.3)  # three impacts by t = 0.9, no accumulation yet
CAM = dict(rest=1.0)  # the spring pulls the follower below the cam: three impacts by t = 1


def _impact_times(r):
    return np.array([im.t for im in r.impacts])


@pytest.fixture(scope="module")
def cam_runs():
    grid = np.linspace(0.0, 1.0, 201)
    moving = lcp.simulate(cam_follower(**CAM), method="event", t_eval=grid)
    pinned = lcp.simulate(cam_follower(pinned=True, **CAM), method="event", t_eval=grid)
    assert moving.success and pinned.success
    return moving, pinned


def test_cam_time_dependent_gap_agrees_with_the_pinned_cam(cam_runs):
    moving, pinned = cam_runs
    assert len(moving.impacts) == len(pinned.impacts) == 3
    np.testing.assert_allclose(_impact_times(moving), _impact_times(pinned), rtol=0, atol=1e-9)
    np.testing.assert_allclose([im.p_N for im in moving.impacts], [im.p_N for im in pinned.impacts],
                               rtol=0, atol=1e-9)
    np.testing.assert_allclose(moving.q[:, 1], pinned.q[:, 1], rtol=0, atol=1e-9)
    np.testing.assert_allclose(moving.v[:, 1], pinned.v[:, 1], rtol=0, atol=1e-9)
    # the follower never enters the cam: g(t, q(t)) >= 0 on the output grid
    cam = 1.0 + 0.1 * np.sin(10.0 * moving.t)
    assert np.min(moving.q[:, 1] - cam) > -1e-12


def _cam_errors(event, h, t_end):
    r = lcp.simulate(cam_follower(t_end=t_end, **CAM), h=h)
    assert r.success
    ti = _impact_times(event)
    ti = ti[ti < t_end]
    tm = _impact_times(r)
    assert tm.size == ti.size
    y = np.interp(event.t, r.t, r.q[:, 1])
    away = (np.min(np.abs(event.t[:, None] - ti[None, :]), axis=1) > 0.02) & (event.t <= t_end)
    return np.abs(tm - ti).max(), np.abs(y[away] - event.q[away, 1]).max()


def test_moreau_jean_converges_to_the_event_method_on_the_cam(cam_runs):
    event = cam_runs[0]
    e3, e4 = _cam_errors(event, 1e-3, 0.5), _cam_errors(event, 1e-4, 0.5)
    # Moreau-Jean's impacts fall on its grid: within a step of the event method's (about 0.3 h to
    # 0.5 h here); the motion away from them at first order: ten times smaller steps, errors at
    # least five times smaller
    assert e3[0] < 1e-3 and e4[0] < 1e-4, (e3, e4)
    assert e4[1] < e3[1] / 5, (e3, e4)


@pytest.mark.slow
def test_moreau_jean_converges_to_the_event_method_on_the_cam_1e5(cam_runs):
    event = cam_runs[0]
    e4, e5 = _cam_errors(event, 1e-4, 1.0), _cam_errors(event, 1e-5, 1.0)
    assert e4[0] < 1e-4 and e5[0] < 1e-5, (e4, e5)
    assert e5[1] < e4[1] / 5, (e4, e5)


def _table_speed(t):
    return A * W * np.cos(W * np.asarray(t))


@pytest.mark.parametrize("spatial", [False, True])
def test_table_impacts_against_the_root_finding_reference(spatial):
    ref = table_impacts(**TABLE, n_impacts=3)
    if spatial:  # the same ball with a two-dimensional tangent plane (the Coulomb-disk integrator)
        t = ca.SX.sym("t")
        q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
        s = System(q, v, ca.SX.eye(3), ca.vertcat(0, -9.81, 0), t=t,
                   contacts=[Contact(gap=q[1] - A * ca.sin(W * t), tangent=ca.vertcat(q[0], q[2]), e=E,
                                     name="table")])
        run = dict(q0=[0.0, 0.3, 0.0], v0=[0.0, 0.0, 0.0])
    else:
        s, run = moving_table(**TABLE).system, dict(q0=[0.0, 0.3], v0=[0.0, 0.0])
    r = lcp.simulate(s, 0.9, method="event", **run)
    assert r.success and len(r.impacts) == 3
    ti = _impact_times(r)
    np.testing.assert_allclose(ti, ref[:, 0], rtol=0, atol=1e-9)
    # the output at an impact time is its right limit: u+ = v+ - s'(t); u- = u+ - p_N (mass 1)
    r2 = lcp.simulate(s, 0.9, method="event", t_eval=np.concatenate([[0.0], ti, [0.9]]), **run)
    np.testing.assert_array_equal(_impact_times(r2), ti)
    u_plus = r2.v[1:-1, 1] - _table_speed(ti)
    u_minus = u_plus - np.array([im.p_N for im in r2.impacts])
    np.testing.assert_allclose(u_minus, ref[:, 1], rtol=0, atol=1e-9)
    np.testing.assert_allclose(u_plus, -E * u_minus, rtol=1e-12, atol=0)
    # on a fixed table the rebound would be -e v-: the table's speed is not negligible here
    v_minus = u_minus + _table_speed(ti)
    assert np.all(np.abs(r2.v[1:-1, 1] + E * v_minus) > 1e-3)


def test_table_impacts_agree_with_the_pinned_table():
    r = lcp.simulate(moving_table(**TABLE, t_end=0.9), method="event")
    ref = lcp.simulate(moving_table(pinned=True, **TABLE, t_end=0.9), method="event")
    np.testing.assert_allclose(_impact_times(r), _impact_times(ref), rtol=0, atol=1e-9)


def test_accumulation_on_a_moving_table_is_resolved_not_extrapolated():
    # A w^2 = 1.8 < g: the bounces accumulate and the ball then rides the table; the fixed floor's
    # geometric series does not hold under a moving table, so no jump to a limit is made
    kw = dict(amplitude=A, omega=W, e=0.5, height=0.1, t_end=1.5)
    grid = np.linspace(0.0, 1.5, 151)
    r = lcp.simulate(moving_table(**kw), method="event", t_eval=grid)
    assert r.success and not r.accumulations
    assert "no extrapolation" in r.message and "'table'" in r.message
    t_acc = r.impacts[-1].t
    assert 0.4 < t_acc < 0.5 and len(r.impacts) > 15
    after = r.t > t_acc
    np.testing.assert_allclose(r.q[after, 1], A * np.sin(W * r.t[after]), rtol=0, atol=1e-9)
    np.testing.assert_allclose(r.v[after, 1], _table_speed(r.t[after]), rtol=0, atol=1e-9)
    pinned = lcp.simulate(moving_table(pinned=True, **kw), method="event", t_eval=grid)
    assert pinned.success and len(pinned.accumulations) == 1
    assert abs(pinned.accumulations[0].t - t_acc) < 1e-6
    np.testing.assert_allclose(r.q[:, 1], pinned.q[:, 1], rtol=0, atol=1e-9)


@pytest.mark.parametrize("spatial", [False, True])
def test_lift_off_from_a_decelerating_table(spatial):
    # the ball rides the table (e = 0) until the table's downward acceleration A w^2 sin(w t)
    # reaches g: N = g - A w^2 sin(w t) = 0 at t* = asin(g / (A w^2)) / w, then flies freely
    a, w, g = 0.05, 20.0, 9.81
    t_star = np.arcsin(g / (a * w * w)) / w
    t = ca.SX.sym("t")
    if spatial:
        q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
        s = System(q, v, ca.SX.eye(3), ca.vertcat(0, -g, 0), t=t,
                   contacts=[Contact(gap=q[1] - a * ca.sin(w * t), tangent=ca.vertcat(q[0], q[2]), mu=0.3,
                                     name="table")])
        q0, v0 = [0.0, 0.0, 0.0], [0.0, a * w, 0.0]
    else:
        sc = moving_table(amplitude=a, omega=w, e=0.0, height=0.0, t_end=0.1)
        s, q0, v0 = sc.system, [0.0, 0.0], [0.0, a * w]
    t_end = t_star + 0.01
    grid = np.linspace(0.0, t_end, 41)
    r = lcp.simulate(s, t_end, method="event", q0=q0, v0=v0, t_eval=grid)
    assert r.success
    lift = [ev for ev in r.events if ev.kind == "lift-off"]
    assert len(lift) == 1
    assert abs(lift[0].t - t_star) < 1e-9
    # riding: on the table, with its speed; the normal force N = g + s''(t)
    ride = r.t < t_star
    np.testing.assert_allclose(r.q[ride, 1], a * np.sin(w * r.t[ride]), rtol=0, atol=1e-9)
    np.testing.assert_allclose(r.force_N[ride, 0], g - a * w * w * np.sin(w * r.t[ride]), rtol=0, atol=1e-8)
    # then a parabola from the lift-off state, above the table
    fly = r.t > t_star
    tau = r.t[fly] - t_star
    y = a * np.sin(w * t_star) + a * w * np.cos(w * t_star) * tau - 0.5 * g * tau * tau
    np.testing.assert_allclose(r.q[fly, 1], y, rtol=0, atol=1e-9)
    assert np.all(r.q[fly, 1] - a * np.sin(w * r.t[fly]) > 0)
    assert np.all(r.force_N[fly, 0] == 0)


@settings(max_examples=12, deadline=None)
@given(a=st.floats(0.03, 0.08), w=st.floats(15.0, 25.0))
def test_one_lift_off_from_any_decelerating_table(a, w):
    # at the lift-off root N = g - a w^2 sin(w t) is summed from terms of size g: the event may be
    # located where N is +1e-15; the decision there must open the contact, not stick for 1e-11 s
    # and lift off again (12 of 75 tables on a grid of (a, w) did, before)
    g = 9.81
    assume(a * w * w > 1.05 * g)
    t_star = np.arcsin(g / (a * w * w)) / w
    sc = moving_table(amplitude=a, omega=w, e=0.0, height=0.0, t_end=0.1)
    t_end = t_star + 0.01
    r = lcp.simulate(sc.system, t_end, method="event", q0=[0.0, 0.0], v0=[0.0, a * w],
                     t_eval=np.linspace(0.0, t_end, 41))
    assert r.success
    lift = [ev for ev in r.events if ev.kind == "lift-off"]
    assert len(lift) == 1 and abs(lift[0].t - t_star) < 1e-9
    assert [ph.modes for ph in r.phases] == [("stick",), ("open",)]


@settings(max_examples=6, deadline=None)
@given(V=st.floats(-2.0, 2.0).filter(lambda x: abs(x) > 0.05), v0=st.floats(-1.0, 1.0), mu=st.floats(0.1, 0.8))
def test_conveyor_stick_slip_is_exact(V, v0, mu):
    sc = conveyor(V=V, mu=mu, v0=v0)
    grid = np.linspace(0.0, sc.t_end, 41)
    r = lcp.simulate(sc, method="event", t_eval=grid)
    assert r.success
    ex = sc.exact(r.t)
    scale = max(1.0, abs(V), abs(v0))
    np.testing.assert_allclose(r.v[:, 0], ex["xdot"], rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(r.q[:, 0], ex["x"], rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(r.q[:, 1], 0.0, rtol=0, atol=1e-14)
    ts = sc.solution.t_stick
    if abs(V - v0) > 1e-9:
        stops = [ev.t for ev in r.events if ev.kind == "stop"]
        assert len(stops) == 1 and abs(stops[0] - ts) < 1e-12 * max(1.0, ts)
        # friction m mu g towards the belt while sliding, none once the block moves with the belt
        slide = r.t < ts - 1e-9
        np.testing.assert_allclose(r.force_T[slide, 0], ex["f"][slide], rtol=1e-12, atol=1e-12)
        # (both sides skip 1e-9 around ts: the stop is located to 1e-12, and an output time between
        # the exact and the located stop still reports the slide: V = 2 - 2.2e-16, v0 = 0.5, mu = 0.375)
        np.testing.assert_allclose(r.force_T[r.t > ts + 1e-9, 0], 0.0, rtol=0, atol=1e-12)


def test_spatial_conveyor_oblique_belt_is_exact():
    # a belt moving along (0.6, 0.8) in the tangent plane: the block is dragged along it, stops
    # relative to it at t = |V| / (mu g)
    t = ca.SX.sym("t")
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    Vx, Vz, mu, g = 0.6, 0.8, 0.4, 9.81
    s = System(q, v, ca.SX.eye(3), ca.vertcat(0, -g, 0), t=t,
               contacts=[Contact(gap=q[1], tangent=ca.vertcat(q[0] - Vx * t, q[2] - Vz * t), mu=mu, name="belt")])
    grid = np.linspace(0.0, 0.5, 51)
    r = lcp.simulate(s, 0.5, method="event", q0=[0, 0, 0], v0=[0, 0, 0], t_eval=grid)
    assert r.success and r.mode_sequence == [("slide",), ("stick",)]
    assert "closed-form" not in r.integrators  # a moving contact: never the constant-system phases
    ts = 1.0 / (mu * g)
    assert abs(r.t_events[0] - ts) < 1e-12
    a = mu * g
    path = np.where(grid < ts, 0.5 * a * grid ** 2, 0.5 * a * ts ** 2 + (grid - ts))
    speed = np.minimum(a * grid, 1.0)
    for i, Vi in ((0, Vx), (2, Vz)):
        np.testing.assert_allclose(r.q[:, i], Vi * path, rtol=0, atol=1e-12)
        np.testing.assert_allclose(r.v[:, i], Vi * speed, rtol=0, atol=1e-12)


def test_acceleration_drift_of_a_moving_contact_is_its_second_derivative():
    # the drift of du/dt = H qdd + Hdv holds (d/dt H) v and the derivatives of b = (dg/dt, ds/dt)
    # in t and q: compared with finite differences of u(t, q(t), v(t)) along a motion with qdd = 0
    from lcp.events.model import accel_function

    t, q, v = ca.SX.sym("t"), ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    s = System(q, v, ca.SX.eye(2), ca.vertcat(0, -9.81), t=t,
               contacts=[Contact(gap=q[1] - 0.1 * ca.sin(3 * t) * q[0], tangent=q[0] - 2 * t * q[1] ** 2, mu=0.3,
                                 name="cam")])
    Hdv = np.array(accel_function(s)(0.4, [0.2, 0.5], [0.3, -0.7])[5], dtype=float).ravel()

    def u(tt):  # uniform motion q(t) = q + (t - 0.4) v, qdd = 0
        qq = np.array([0.2, 0.5]) + (tt - 0.4) * np.array([0.3, -0.7])
        return s.contact_jacobian(qq, tt) @ np.array([0.3, -0.7]) + s.contact_rates(qq, tt)

    d = 1e-5
    fd = (u(0.4 + d) - u(0.4 - d)) / (2 * d)
    np.testing.assert_allclose(Hdv, fd, rtol=0, atol=1e-8)


def test_unsupported_uses_of_moving_contacts_are_refused_by_name():
    sc = moving_table(**TABLE, t_end=0.9)
    with pytest.raises(ValueError, match="'table' has a time-dependent gap"):
        lcp.simulate(sc, h=1e-3, scheme="order2")
    # the closed-form phases need constant kinematics: a moving contact is not
    with pytest.raises(ValueError, match="smooth='closed-form' needs constant mass, kinematics"):
        lcp.simulate(sc, method="event", smooth="closed-form")


@pytest.mark.parametrize("V, mu, h0", [(1.0, 0.4, 0.2), (0.3, 0.8, 0.2), (-1.0, 0.3, 0.05)])
def test_block_dropped_on_the_belt(V, mu, h0):
    # it lands at t1 = sqrt(2 h0 / g) with P_N = m g t1 (e = 0); the impact's friction drags it by
    # P_T = min(mu P_N, m |V|) towards the belt (on the relative velocity -V), then it slides with
    # mu g until it moves with the belt (or sticks at once when the impulse sufficed)
    g = 9.81
    sc = conveyor(V=V, mu=mu, g=g)
    sc.q0[1] = h0
    t1 = np.sqrt(2 * h0 / g)
    PN, PT = g * t1, np.sign(V) * min(mu * g * t1, abs(V))
    ts = t1 + (abs(V) - abs(PT)) / (mu * g)
    T = ts + 0.3
    grid = np.linspace(0.0, T, 61)
    r = lcp.simulate(sc, T, method="event", t_eval=grid)
    assert r.success and len(r.impacts) == 1
    imp = r.impacts[0]
    assert abs(imp.t - t1) < 1e-12
    np.testing.assert_allclose([imp.p_N, imp.p_T], [PN, PT], rtol=1e-12, atol=0)
    xdot = np.where(grid < t1, 0.0, np.where(grid < ts, PT + np.sign(V) * mu * g * (grid - t1), V))
    np.testing.assert_allclose(r.v[:, 0], xdot, rtol=0, atol=1e-12)
    stops = [ev.t for ev in r.events if ev.kind == "stop"]
    assert (len(stops) == 1 and abs(stops[0] - ts) < 1e-12) if ts > t1 else not stops


def _rotating_plate(pinned):
    """A ball (mass 1) dropped on a frictional plate through the origin whose angle turns as
    theta(t) = 0.2 + 0.3 sin 2t: H depends on t (normal (-sin theta, cos theta)); pinned: theta a
    coordinate held on theta(t) by a rheonomous bilateral constraint."""
    t = ca.SX.sym("t")
    th = 0.2 + 0.3 * ca.sin(2 * t)
    if pinned:
        q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
        z = q[2]
        s = System(q, v, ca.SX.eye(3), ca.vertcat(0, -9.81, 0), t=t, constraints=[q[2] - th],
                   contacts=[Contact(gap=-ca.sin(z) * q[0] + ca.cos(z) * q[1],
                                     tangent=ca.cos(z) * q[0] + ca.sin(z) * q[1], mu=0.3, e=0.5, name="plate")])
        return s, [1.0, 0.6, 0.2], [0.0, 0.0, 0.6]
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    s = System(q, v, ca.SX.eye(2), ca.vertcat(0, -9.81), t=t,
               contacts=[Contact(gap=-ca.sin(th) * q[0] + ca.cos(th) * q[1],
                                 tangent=ca.cos(th) * q[0] + ca.sin(th) * q[1], mu=0.3, e=0.5, name="plate")])
    return s, [1.0, 0.6], [0.0, 0.0]


def test_rotating_plate_time_dependent_normal_agrees_with_the_pinned_plate():
    grid = np.linspace(0.0, 1.5, 76)
    runs = []
    for pinned in (False, True):
        s, q0, v0 = _rotating_plate(pinned)
        r = lcp.simulate(s, 1.5, method="event", q0=q0, v0=v0, t_eval=grid)
        assert r.success
        runs.append(r)
    moving, pinned = runs
    # frictional bounces, then an accumulation near t = 0.89 and a slide down the turning plate
    assert moving.mode_sequence[-1] == pinned.mode_sequence[-1] == ("slide-",)
    before = grid < 0.88
    k = 8  # the impacts before the accumulation, clearly apart
    np.testing.assert_allclose(_impact_times(moving)[:k], _impact_times(pinned)[:k], rtol=0, atol=1e-9)
    np.testing.assert_allclose(moving.q[before, :2], pinned.q[before, :2], rtol=0, atol=1e-9)
    np.testing.assert_allclose(moving.v[before, :2], pinned.v[before, :2], rtol=0, atol=1e-9)
    # the accumulation's limit: resolved bounce by bounce here, extrapolated by Aitken in the pinned
    # form; both within about 2e-8 s of the limit found with tol = 1e-13 (0.8901533069), so the
    # slide after it agrees to that order
    np.testing.assert_allclose(moving.q[:, :2], pinned.q[:, :2], rtol=0, atol=1e-7)
    np.testing.assert_allclose(moving.v[:, :2], pinned.v[:, :2], rtol=0, atol=1e-7)
