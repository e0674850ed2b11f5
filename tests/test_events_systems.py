"""The event method on textbook systems, against references derived here.

Accumulations of impacts (a bouncing ball), redundant contacts (a box on two corners, a four-legged
table, a block in a V groove), an incline with stick, slip and reversal, and a control schedule
that holds a block exactly at the friction bound. Every reference is analytic, or an independent
high-accuracy ``solve_ivp`` integration of the reduced equations of motion.
"""
import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from lcp.model.control import ControlSchedule
from lcp.events import event_driven
from lcp.model.system import Contact, System

G = 9.81


# ------------------------------------------------------------------------------------ systems
def ball(m=1.0, e=0.8, mu=0.3, smooth_floor=None):
    """A point mass (x, y) over the floor y = 0 (or y = k x^2 with ``smooth_floor=k``)."""
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    gap = q[1] if smooth_floor is None else q[1] - smooth_floor * q[0] ** 2
    return System(q, v, mass=m * ca.SX.eye(2), force=ca.vertcat(0, -m * G),
                  contacts=[Contact(gap=gap, tangent=q[0], mu=mu, e=e, name="floor")])


def box(m=1.0, w=1.0, h=0.5, mu=0.5, c=1.0, hf=0.0):
    """A box (x, y, theta) of width w and height h on its two bottom corners, pushed horizontally
    by F = c t along a line hf above its centre (torque -F hf)."""
    q, v, t = ca.SX.sym("q", 3), ca.SX.sym("v", 3), ca.SX.sym("t")
    x, y, th = q[0], q[1], q[2]
    cs, sn = ca.cos(th), ca.sin(th)
    contacts = [Contact(gap=y + sn * sx * w / 2 - cs * h / 2, tangent=x + cs * sx * w / 2 + sn * h / 2, mu=mu,
                        name=name) for sx, name in ((-1, "rear"), (1, "front"))]
    inertia = m * (w * w + h * h) / 12
    return System(q, v, mass=ca.diag(ca.vertcat(m, m, inertia)), force=ca.vertcat(c * t, -m * G, -c * t * hf),
                  contacts=contacts, t=t)


def table(m=4.0, legs=(-0.5, -0.2, 0.2, 0.5), H=0.7, mu=0.3, c=0.0, hf=0.1):
    """A planar table (x, y, theta): four legs reaching H below its centre, pushed by F = c t."""
    q, v, t = ca.SX.sym("q", 3), ca.SX.sym("v", 3), ca.SX.sym("t")
    x, y, th = q[0], q[1], q[2]
    cs, sn = ca.cos(th), ca.sin(th)
    contacts = [Contact(gap=y + sn * d - cs * H, tangent=x + cs * d + sn * H, mu=mu, name=f"leg {i}")
                for i, d in enumerate(legs)]
    return System(q, v, mass=ca.diag(ca.vertcat(m, m, 0.1 * m)), force=ca.vertcat(c * t, -m * G, -c * t * hf),
                  contacts=contacts, t=t)


def v_groove(m=1.0, mu=0.5, beta=0.5, c=0.0):
    """A point block wedged in a V groove (walls at beta from the vertical), pulled up by c t."""
    q, v, t = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("t")
    x, y = q[0], q[1]
    cb, sb = math.cos(beta), math.sin(beta)
    contacts = [Contact(gap=cb * x + sb * y, tangent=-sb * x + cb * y, mu=mu, name="left wall"),
                Contact(gap=-cb * x + sb * y, tangent=sb * x + cb * y, mu=mu, name="right wall")]
    return System(q, v, mass=m * ca.SX.eye(2), force=ca.vertcat(0, -m * G + c * t), contacts=contacts, t=t)


def incline(alpha, mu, m=1.0):
    """A point mass (x, y) on the slope through the origin rising at angle alpha."""
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    ca_, sa = math.cos(alpha), math.sin(alpha)
    return System(q, v, mass=m * ca.SX.eye(2), force=ca.vertcat(0, -m * G),
                  contacts=[Contact(gap=-sa * q[0] + ca_ * q[1], tangent=ca_ * q[0] + sa * q[1], mu=mu)])


def ball_impacts(height, e, n):
    """Exact impact times and approach speeds of a ball dropped from rest at ``height``."""
    v0 = math.sqrt(2 * G * height)
    u = v0 * e ** np.arange(n)  # approach speed at impact k
    t = math.sqrt(2 * height / G) + np.concatenate([[0.0], np.cumsum(2 * u[1:] / G)])
    t_inf = math.sqrt(2 * height / G) + 2 * e * v0 / (G * (1 - e))
    return t, u, t_inf


# ------------------------------------------------------------------------- accumulations of impacts
@pytest.mark.parametrize("m, e, height", [(1.0, 0.8, 1.0), (0.3, 0.5, 2.0), (5.0, 0.9, 0.1)])
def test_ball_impacts_accumulate_and_the_ball_then_rests_exactly(m, e, height):
    t_end = 1e6
    t_eval = np.concatenate([np.linspace(0, 10, 101), [1e3, 1e5, 1e6]])
    res = event_driven(ball(m=m, e=e), [0.0, height], [0.0, 0.0], t_end, t_eval=t_eval)
    assert res.success, res.message
    (acc,) = res.accumulations
    t_k, u_k, t_inf = ball_impacts(height, e, acc.n_impacts)
    assert len(res.impacts) == acc.n_impacts >= 10
    np.testing.assert_allclose([imp.t for imp in res.impacts], t_k, rtol=0, atol=1e-13)
    p_exact = m * (1 + e) * u_k
    np.testing.assert_allclose([imp.p_N for imp in res.impacts], p_exact, rtol=0, atol=1e-13 * p_exact[0])
    assert all(imp.p_T == 0.0 and imp.contact == 0 and imp.name == "floor" for imp in res.impacts)
    assert abs(acc.t - t_inf) <= 1e-12 and acc.method == "closed-form" and acc.contacts == (0,)
    # the unresolved impacts: their impulse closes the momentum balance (at rest before and after)
    p_total = sum(imp.p_N for imp in res.impacts) + acc.P_N[0]
    assert abs(p_total - m * G * t_inf) <= 1e-12 * m * G * t_inf
    after = res.t > t_inf
    assert np.all(res.q[after] == 0.0) and np.all(res.v[after] == 0.0)  # exactly, up to t = 1e6
    assert np.all(res.modes[after[:-1]] == 1)  # stick
    np.testing.assert_allclose(res.force_N[after, 0], m * G, rtol=1e-15)
    # before the limit the ball is on its parabolas
    k = np.searchsorted(t_k, res.t[~after], side="right") - 1
    before = res.t[~after]
    free = k < 0
    y_exact = np.where(free, height - G * before ** 2 / 2, 0.0)
    tk, uk = t_k[np.maximum(k, 0)], e * u_k[np.maximum(k, 0)]
    y_exact = np.where(free, y_exact, uk * (before - tk) - G * (before - tk) ** 2 / 2)
    assert np.max(np.abs(res.q[~after, 1] - y_exact)) <= 1e-12


def test_a_sliding_ball_loses_its_speed_at_the_impacts_then_slides_to_rest():
    m, e, mu, height, vx0 = 1.0, 0.6, 0.2, 1.0, 5.0
    res = event_driven(ball(m=m, e=e, mu=mu), [0.0, height], [vx0, 0.0], 5.0, n_eval=501)
    assert res.success, res.message
    (acc,) = res.accumulations
    t_k, u_k, t_inf = ball_impacts(height, e, acc.n_impacts)
    np.testing.assert_allclose([imp.t for imp in res.impacts], t_k, rtol=0, atol=1e-13)
    # each impact takes mu (1 + e) u_k off the sliding speed; all of them, mu (1 + e) v0 / (1 - e)
    np.testing.assert_allclose([imp.p_T for imp in res.impacts], -mu * m * (1 + e) * u_k, rtol=0,
                               atol=1e-13 * u_k[0])
    vx_inf = vx0 - mu * (1 + e) * u_k[0] / (1 - e)
    assert vx_inf > 0
    assert abs(acc.t - t_inf) <= 1e-12
    t_stop = t_inf + vx_inf / (mu * G)
    assert res.events[-1].kind == "stop" and abs(res.events[-1].t - t_stop) <= 1e-12
    later = res.t > t_stop
    x_stop = float(res.q[later, 0][0])
    # from t_inf on: uniform deceleration mu g, then rest
    x_inf = x_stop - vx_inf ** 2 / (2 * mu * G)
    sl = (res.t > t_inf) & ~later
    dt = res.t[sl] - t_inf
    np.testing.assert_allclose(res.q[sl, 0], x_inf + vx_inf * dt - mu * G * dt ** 2 / 2, rtol=0, atol=1e-12)
    assert np.all(res.q[res.t > t_inf, 1] == 0.0) and np.all(res.v[later] == 0.0)


@pytest.mark.parametrize("system, smooth", [(ball(), "scipy"), (ball(smooth_floor=0.5), "auto")],
                         ids=["flat floor, DOP853", "curved floor"])
def test_accumulation_by_extrapolation_when_phases_are_not_polynomial(system, smooth):
    res = event_driven(system, [0.0, 1.0], [0.0, 0.0], 10.0, smooth=smooth)
    assert res.success, res.message
    (acc,) = res.accumulations
    _, _, t_inf = ball_impacts(1.0, 0.8, 1)
    assert acc.method == "aitken" and abs(acc.t - t_inf) <= 1e-12
    assert np.all(np.abs(res.q[res.t > t_inf]) <= 1e-15) and np.all(np.abs(res.v[res.t > t_inf]) <= 1e-15)


@settings(max_examples=12, deadline=None)
@given(m=st.floats(0.01, 100.0), e=st.floats(0.05, 0.95), height=st.floats(1e-3, 10.0), mu=st.floats(0.0, 1.0))
def test_random_balls(m, e, height, mu):
    res = event_driven(ball(m=m, e=e, mu=mu), [0.0, height], [0.0, 0.0], 20 * math.sqrt(height / G) / (1 - e))
    assert res.success, res.message
    (acc,) = res.accumulations
    t_k, _, t_inf = ball_impacts(height, e, acc.n_impacts)
    np.testing.assert_allclose([imp.t for imp in res.impacts], t_k, rtol=1e-13, atol=0)
    assert abs(acc.t - t_inf) <= 1e-12 * max(1.0, t_inf)
    assert res.q[-1, 1] == 0.0 and res.v[-1, 1] == 0.0


# ------------------------------------------------------------------------------- redundant contacts
def box_onsets(m, w, h, mu, c, hf):
    """Onset of sliding (|F| = mu m g) and of tipping about the front corner (F (h/2 + hf) = m g w/2)."""
    return mu * m * G / c, m * G * w / (2 * c * (h / 2 + hf))


@pytest.mark.parametrize("m, w, h, mu, c, hf", [
    (1.0, 1.0, 0.5, 0.5, 1.0, 0.0),  # slides
    (1.0, 1.0, 0.5, 0.5, 1.0, 0.2),
    (3.0, 0.6, 1.0, 0.3, 5.0, 0.1),
    (1.0, 1.0, 0.5, 0.9, 1.0, 0.6),  # tips
    (2.0, 0.4, 0.8, 0.8, 2.0, 0.0),
])
def test_box_on_two_corners_slides_or_tips_at_the_exact_time(m, w, h, mu, c, hf):
    t_slide, t_tip = box_onsets(m, w, h, mu, c, hf)
    slides = t_slide < t_tip  # mu < w / (h + 2 hf)
    t_on = min(t_slide, t_tip)
    res = event_driven(box(m, w, h, mu, c, hf), [0.0, h / 2, 0.0], np.zeros(3), 1.2 * t_on,
                       t_eval=np.linspace(0, 1.2 * t_on, 61))
    assert res.success, res.message
    ev = res.events[0]
    assert abs(ev.t - t_on) <= 1e-12 * max(1.0, t_on)
    if slides:
        assert ev.kind == "slip" and res.mode_sequence[:2] == [("stick", "stick"), ("slide+", "slide+")]
    else:
        assert (ev.kind, ev.contact) == ("lift-off", 0) and res.mode_sequence[1] == ("open", "stick")
    assert not res.phases[0].forces_unique and res.nonunique_forces >= 1 and "not unique" in res.message
    # while both corners stick: the box is at rest, its forces are admissible and balance the load
    st_ = res.t < t_on
    F = c * res.t[st_]
    N, f = res.force_N[st_], res.force_T[st_]
    assert np.all(np.abs(res.q[st_] - res.q[0]) <= 1e-15) and np.all(np.abs(res.v[st_]) <= 1e-15)
    np.testing.assert_allclose(N.sum(axis=1), m * G, rtol=1e-13)
    np.testing.assert_allclose(f.sum(axis=1), -F, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(N[:, 1] - N[:, 0], 2 * F * (h / 2 + hf) / w, rtol=1e-12, atol=1e-12)  # moments
    assert np.all(np.abs(f) <= mu * N + 1e-12) and np.all(N >= -1e-12)
    after = res.t > t_on
    if slides:  # both corners slide: x = c (t - t_s)^3 / (6 m)
        np.testing.assert_allclose(res.q[after, 0], c * (res.t[after] - t_on) ** 3 / (6 * m), rtol=1e-9, atol=1e-13)
        assert np.max(np.abs(res.q[after, 1:] - res.q[0, 1:])) <= 1e-13
    else:  # pivot on the front corner: the reduced equation, integrated independently
        inertia = m * (w * w + h * h) / 12 + m * (w * w + h * h) / 4

        def pivot(t, y):
            s_, c_ = math.sin(y[0]), math.cos(y[0])
            F_ = c * t
            Q = F_ * (s_ * w / 2 - c_ * h / 2) + m * G * (c_ * w / 2 + s_ * h / 2) - F_ * hf
            return [y[1], Q / inertia]

        t_next = res.events[1].t if len(res.events) > 1 else res.t[-1]
        sel = after & (res.t < t_next)
        ref = solve_ivp(pivot, (t_on, res.t[sel][-1]), [0.0, 0.0], rtol=1e-13, atol=1e-16, t_eval=res.t[sel],
                        method="DOP853")
        np.testing.assert_allclose(res.q[sel, 2], ref.y[0], rtol=1e-7, atol=1e-12)


def test_table_on_four_legs_rests_exactly_with_admissible_forces():
    m, legs = 4.0, np.array([-0.5, -0.2, 0.2, 0.5])
    q0 = np.array([0.0, 0.7, 0.0])
    res = event_driven(table(m=m, legs=tuple(legs)), q0, np.zeros(3), 1e6, t_eval=[0.0, 1.0, 1e3, 1e6])
    assert res.success, res.message
    assert res.mode_sequence == [("stick",) * 4] and res.events == []
    assert np.max(np.abs(res.q - q0)) <= 1e-15 and np.max(np.abs(res.v)) <= 1e-21  # at t = 1e6 too
    N = res.force_N
    np.testing.assert_allclose(N.sum(axis=1), m * G, rtol=1e-14)
    np.testing.assert_allclose(N @ legs, 0.0, atol=1e-13)  # moment balance about the centre
    assert np.all(N > 0) and np.all(np.abs(res.force_T) <= 1e-13)
    assert res.nonunique_forces == 1 and not res.phases[0].forces_unique


@pytest.mark.parametrize("mu, kind", [(0.3, "slip"), (0.8, "lift-off")])
def test_pushed_table_slides_or_tips_at_the_exact_time(mu, kind):
    m, H, hf, c, a = 4.0, 0.7, 0.1, 2.0, 0.5
    t_slide, t_tip = mu * m * G / c, m * G * a / (c * (H + hf))
    t_on = t_slide if kind == "slip" else t_tip
    res = event_driven(table(m=m, H=H, mu=mu, c=c, hf=hf), [0.0, H, 0.0], np.zeros(3), 1.05 * t_on)
    assert res.success, res.message
    ev = res.events[0]
    assert ev.kind == kind and abs(ev.t - t_on) <= 1e-12 * t_on
    if kind == "slip":
        assert res.mode_sequence[1] == ("slide+",) * 4
    else:  # tips about the front leg
        assert ev.contact == 0 and res.mode_sequence[1] == ("open", "open", "open", "stick")


def test_block_wedged_in_a_v_groove_rests_then_is_pulled_out():
    m, c = 1.0, 2.0
    res = event_driven(v_groove(m=m, c=c), [0.0, 0.0], [0.0, 0.0], 8.0, t_eval=np.linspace(0, 8, 81))
    assert res.success, res.message
    t_lift = m * G / c
    assert [(e.kind, e.contact) for e in res.events] == [("lift-off", 0)]
    assert abs(res.events[0].t - t_lift) <= 1e-12 * t_lift
    assert res.mode_sequence == [("stick", "stick"), ("open", "open")] and res.nonunique_forces == 1
    held = res.t < t_lift
    assert np.max(np.abs(res.q[held])) <= 1e-15 and np.max(np.abs(res.v[held])) <= 1e-15
    # the walls carry the net weight m g - c t (their vertical components), within the friction cones
    b = 0.5
    up = (res.force_N[held] * math.sin(b) + res.force_T[held] * math.cos(b)).sum(axis=1)
    np.testing.assert_allclose(up, m * G - c * res.t[held], rtol=1e-12, atol=1e-12)
    assert np.all(np.abs(res.force_T[held]) <= 0.5 * res.force_N[held] + 1e-12)
    free = res.t > t_lift
    np.testing.assert_allclose(res.q[free, 1], c * (res.t[free] - t_lift) ** 3 / (6 * m), rtol=1e-9)


# ------------------------------------------------------------------------------------ an incline
@pytest.mark.parametrize("alpha, mu", [(0.3, 0.5), (0.5, 0.3)])
def test_incline_from_rest_sticks_or_slips(alpha, mu):
    res = event_driven(incline(alpha, mu), [0.0, 0.0], [0.0, 0.0], 2.0, n_eval=21)
    assert res.success, res.message
    ca_, sa = math.cos(alpha), math.sin(alpha)
    s = ca_ * res.q[:, 0] + sa * res.q[:, 1]  # along the slope
    assert np.max(np.abs(-sa * res.q[:, 0] + ca_ * res.q[:, 1])) <= 1e-15  # on the slope
    if math.tan(alpha) <= mu:
        assert np.max(np.abs(res.q)) <= 1e-15 and np.max(np.abs(res.v)) <= 1e-15
        np.testing.assert_allclose(res.force_T[:, 0], G * sa, rtol=1e-14)  # friction holds the block
    else:
        np.testing.assert_allclose(s, -G * (sa - mu * ca_) * res.t ** 2 / 2, rtol=1e-13, atol=1e-15)


@pytest.mark.parametrize("alpha, mu", [(0.3, 0.5), (0.5, 0.3)])
def test_launch_up_the_slope_stops_then_sticks_or_slides_back(alpha, mu):
    v0 = 2.0
    ca_, sa = math.cos(alpha), math.sin(alpha)
    res = event_driven(incline(alpha, mu), [0.0, 0.0], [v0 * ca_, v0 * sa], 2.0, n_eval=41)
    assert res.success, res.message
    a_up = G * (sa + mu * ca_)
    t1 = v0 / a_up
    s1 = v0 * v0 / (2 * a_up)
    assert res.events[0].kind == "stop" and abs(res.events[0].t - t1) <= 1e-15 * max(1.0, t1) * 4
    t = res.t
    s = ca_ * res.q[:, 0] + sa * res.q[:, 1]
    up = t <= t1
    np.testing.assert_allclose(s[up], v0 * t[up] - a_up * t[up] ** 2 / 2, rtol=1e-14, atol=1e-15)
    if math.tan(alpha) <= mu:
        assert res.mode_sequence == [("slide+",), ("stick",)]
        np.testing.assert_allclose(s[~up], s1, rtol=1e-14)
    else:
        a_down = G * (sa - mu * ca_)
        assert res.mode_sequence == [("slide+",), ("slide-",)]
        np.testing.assert_allclose(s[~up], s1 - a_down * (t[~up] - t1) ** 2 / 2, rtol=1e-13)


# -------------------------------------------------------------------- control schedules, marginal stick
def test_control_schedule_holds_a_block_exactly_at_the_friction_bound():
    m, mu = 2.0, 0.4
    q, v, u = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1)
    s = System(q, v, mass=m * ca.SX.eye(2), force=ca.vertcat(u, -m * G), control=u,
               contacts=[Contact(gap=q[1], tangent=q[0], mu=mu, name="floor")])
    Fb = mu * m * G
    replay = s.with_control(ControlSchedule([0, 1, 2, 3, 4], [0.5 * Fb, Fb, 1.5 * Fb, 0.0]))
    res = event_driven(replay, [0.0, 0.0], [0.0, 0.0], 6.0, t_eval=np.linspace(0, 6, 61))
    assert res.success, res.message
    # at rest through [0, 2) (marginal stick on [1, 2)); slides from 2; decelerates from 3; stops
    a1, a2 = 0.5 * Fb / m, -Fb / m
    t_stop = 3 + a1 / -a2
    kinds = [(round(e.t, 12), e.kind) for e in res.events]
    assert kinds == [(1.0, "breakpoint"), (2.0, "breakpoint"), (3.0, "breakpoint"), (round(t_stop, 12), "stop")]
    assert abs(res.events[-1].t - t_stop) <= 1e-12
    assert res.mode_sequence == [("stick",), ("slide+",), ("stick",)]
    t = res.t
    d3 = np.minimum(t, t_stop) - 3
    x = np.where(t < 2, 0.0, np.where(t < 3, a1 * (t - 2) ** 2 / 2, a1 / 2 + a1 * d3 + a2 * d3 ** 2 / 2))
    np.testing.assert_allclose(res.q[:, 0], x, rtol=0, atol=1e-13)
    held = (t >= 1) & (t < 2)
    np.testing.assert_allclose(res.force_T[held, 0], -Fb, rtol=1e-14)  # exactly on the bound


# ----------------------------------------------------------------- systems the method was not tuned on
@pytest.mark.slow
@settings(max_examples=20, deadline=None)
@given(m=st.floats(0.1, 10.0), w=st.floats(0.2, 2.0), h=st.floats(0.2, 2.0), mu=st.floats(0.05, 1.5),
       hf=st.floats(-0.5, 1.0))
def test_random_boxes_slide_or_tip_at_the_exact_time_or_say_why_not(m, w, h, mu, hf):
    c = m  # F = m t: the onsets are a few seconds away
    t_slide, t_tip = box_onsets(m, w, h, mu, c, hf)
    t_tip = t_tip if h / 2 + hf > 0 else math.inf  # pushed below the centre: tips backwards, later
    t_on = min(t_slide, t_tip)
    res = event_driven(box(m, w, h, mu, c, hf), [0.0, h / 2, 0.0], np.zeros(3), 1.1 * t_on, n_eval=23)
    if not res.success:
        assert res.status < 0 and res.message  # a failure is reported, never a wrong answer
        return
    ev = res.events[0]
    assert abs(ev.t - t_on) <= 1e-11 * max(1.0, t_on)
    assert ev.kind == ("slip" if t_slide < t_tip else "lift-off")


def test_block_between_parallel_walls_says_that_its_motion_is_not_unique():
    # A rigid block touching two parallel walls without preload may stay (friction with any
    # squeeze) or fall (no squeeze, no friction): both motions are consistent.
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    walls = [Contact(gap=q[0], tangent=q[1], mu=0.5, name="left"),
             Contact(gap=-q[0], tangent=q[1], mu=0.5, name="right")]
    res = event_driven(System(q, v, mass=ca.SX.eye(2), force=ca.vertcat(0, -G), contacts=walls), [0.0, 0.0],
                       [0.0, 0.0], 1.0, n_eval=3)
    assert res.success and "motions were consistent" in res.message
    assert res.mode_sequence == [("open", "open")]  # a vanishing Moreau-Jean step lets it fall
    np.testing.assert_allclose(res.q[:, 1], -G * res.t ** 2 / 2, rtol=1e-15)


def box_dropped(e, mu=0.5, m=1.0, w=1.0, h=0.5):
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    x, y, th = q[0], q[1], q[2]
    cs, sn = ca.cos(th), ca.sin(th)
    contacts = [Contact(gap=y + sn * sx * w / 2 - cs * h / 2, tangent=x + cs * sx * w / 2 + sn * h / 2, mu=mu, e=e,
                        name=name) for sx, name in ((-1, "rear"), (1, "front"))]
    return System(q, v, mass=ca.diag(ca.vertcat(m, m, m * (w * w + h * h) / 12)), force=ca.vertcat(0, -m * G, 0),
                  contacts=contacts)


@pytest.mark.parametrize("e", [0.5, 0.7])
def test_box_dropped_flat_bounces_on_both_corners_to_rest(e):
    # both corners land together: a redundant impact (its friction impulses are not unique)
    drop = 0.25
    res = event_driven(box_dropped(e), [0.0, 0.25 + drop, 0.0], np.zeros(3), 3.0, n_eval=31)
    assert res.success, res.message
    (acc,) = res.accumulations
    t_k, u_k, t_inf = ball_impacts(drop, e, acc.n_impacts)
    assert acc.contacts == (0, 1) and acc.method == "aitken" and abs(acc.t - t_inf) <= 1e-12
    times = np.array([imp.t for imp in res.impacts]).reshape(-1, 2)
    np.testing.assert_allclose(times, np.column_stack([t_k, t_k]), rtol=0, atol=1e-13)
    p_N = np.array([imp.p_N for imp in res.impacts]).reshape(-1, 2)
    np.testing.assert_allclose(p_N, np.column_stack([u_k, u_k]) * (1 + e) / 2, rtol=0, atol=1e-12)
    assert np.max(np.abs([imp.p_T for imp in res.impacts])) <= 1e-13  # least-norm: no internal squeeze
    rest = res.t > t_inf
    np.testing.assert_allclose(res.q[rest], np.tile([0.0, 0.25, 0.0], (rest.sum(), 1)), rtol=0, atol=1e-15)
    assert np.max(np.abs(res.v[rest])) <= 1e-15 and res.mode_sequence[-1] == ("stick", "stick")


@pytest.mark.parametrize("name, system, q0, v0", [
    ("tilted box", box_dropped(0.5), [0.0, 0.5, 0.1], [0.0, 0.0, 0.0]),
    ("ball in a bowl", ball(smooth_floor=0.5), [0.3, 1.0], [0.5, 0.0]),
])
def test_bouncing_to_persistent_contact_ends_on_the_surface(name, system, q0, v0):
    res = event_driven(system, q0, v0, 6.0, n_eval=61)
    assert res.success, res.message
    assert res.accumulations and res.impacts
    t_last = res.accumulations[-1].t
    after = res.t > t_last
    gaps = np.array([system.gaps(q) for q in res.q[after]])
    assert np.max(np.abs(gaps)) <= 1e-13  # in persistent contact from the accumulation on
    # energy only decreases (impacts with e < 1, friction)
    energy = np.array([system.kinetic_energy(q, v) for q, v in zip(res.q, res.v)]) + G * res.q[:, 1]
    assert np.all(np.diff(energy) <= 1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("mu, kind", [(0.3, "slip"), (0.8, "lift-off")])
def test_eight_legged_table_past_the_enumeration_limit(mu, kind):
    # 4^8 branches: Lemke's method picks the modes; the redundant legs must stay closed
    m, H, hf, c = 4.0, 0.7, 0.1, 2.0
    legs = tuple(np.linspace(-0.5, 0.5, 8))
    t_on = mu * m * G / c if kind == "slip" else m * G * 0.5 / (c * (H + hf))
    res = event_driven(table(m=m, legs=legs, H=H, mu=mu, c=c, hf=hf), [0.0, H, 0.0], np.zeros(3), 1.2 * t_on,
                       n_eval=25)
    assert res.success, res.message
    assert "lemke" in res.solver and abs(res.events[0].t - t_on) <= 1e-12 * t_on
    after = res.t > t_on
    if kind == "slip":  # all legs slide together: x = c (t - t_s)^3 / (6 m)
        np.testing.assert_allclose(res.q[after, 0], c * (res.t[after] - t_on) ** 3 / (6 * m), rtol=1e-9, atol=1e-13)
    else:
        assert res.events[0].contact == 0 and res.mode_sequence[1][-1] == "stick"
        assert all(md == "open" for md in res.mode_sequence[1][:-1])


@pytest.mark.parametrize("alpha, mu", [(0.5, 0.2), (0.7, 0.3)])
def test_ball_bouncing_down_an_incline(alpha, mu):
    # The normal motion is a ball on a floor under g cos(alpha); friction acts at the impacts only
    # (mu (1 + e) u_k against the slide) until the accumulation, then while sliding or sticking.
    e, h = 0.8, 1.0
    ca_, sa = math.cos(alpha), math.sin(alpha)
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    s = System(q, v, mass=ca.SX.eye(2), force=ca.vertcat(0, -G),
               contacts=[Contact(gap=-sa * q[0] + ca_ * q[1], tangent=ca_ * q[0] + sa * q[1], mu=mu, e=e)])
    res = event_driven(s, [-sa * h, ca_ * h], [0.0, 0.0], 8.0, n_eval=81)
    assert res.success, res.message
    (acc,) = res.accumulations
    gn = G * ca_
    vn0 = math.sqrt(2 * gn * h)
    t_k = math.sqrt(2 * h / gn) + np.concatenate([[0.0], np.cumsum(2 * vn0 * e ** np.arange(1, acc.n_impacts) / gn)])
    t_inf = math.sqrt(2 * h / gn) + 2 * e * vn0 / (gn * (1 - e))
    np.testing.assert_allclose([imp.t for imp in res.impacts], t_k, rtol=0, atol=1e-13)
    assert acc.method == "closed-form" and abs(acc.t - t_inf) <= 1e-12
    # (these slopes are steep enough for the ball to slide down at every impact, and after)
    vt_inf = -G * sa * t_inf + mu * (1 + e) * vn0 / (1 - e)
    after = res.t > t_inf
    vt = ca_ * res.v[after, 0] + sa * res.v[after, 1]
    np.testing.assert_allclose(vt, vt_inf - G * (sa - mu * ca_) * (res.t[after] - t_inf), rtol=1e-13)
    assert res.mode_sequence[-1] == ("slide-",)
    on_slope = -sa * res.q[after, 0] + ca_ * res.q[after, 1]
    assert np.max(np.abs(on_slope)) <= 8 * np.finfo(float).eps * np.max(np.abs(res.q[after]))
