"""The event integrator on a constant system under a piecewise-affine control (cubic closed-form phases).

The Jean-Pratt block pushed horizontally by u(t) (|u| <= 20 N) against its reduced model, solved
independently in 40-digit arithmetic: forward sliding D+ a = u - c, backward D- a = u + c,
c = R (m + M) g, D+- = A (1 -+ kappa), stick while |u| <= c. Stop times (velocity roots) and
breakaway times (|u| reaching c) are roots of quadratics and lines per control interval.
"""
import math

import casadi as ca
import mpmath as mp
import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

import lcp
from lcp.model.control import ControlSchedule
from lcp.events.event_location import first_descent
from lcp.events.forcing import time_forcing
from lcp.events.model import system_model
from lcp.ocp import add_control, tangential_push
from lcp.model.schedule import AffineSchedule
from lcp.model.system import Contact, System

U_MAX = 20.0
G = 9.81


def block(R, v0):
    sc = lcp.scenes.jean_pratt(R=R, v0=v0, m=1.0, M=1.0, g=G)
    return sc, add_control(sc.system, tangential_push(sc.system), -U_MAX, U_MAX)


def pieces_of(schedule):
    """(t_k, t_k+1, u(t_k+), slope) per interval, as the schedule holds it."""
    t = schedule.times
    if schedule.hold == "affine":
        start, end = schedule.values[0::2, 0], schedule.values[1::2, 0]
    elif schedule.hold == "linear":
        start, end = schedule.values[:-1, 0], schedule.values[1:, 0]
    else:
        start = end = schedule.values[:, 0]
    return [(float(t[k]), float(t[k + 1]), float(start[k]), (float(end[k]) - float(start[k])) / (t[k + 1] - t[k]))
            for k in range(len(t) - 1)]


def reference(sc, schedule, v0):
    """Events [(t, kind)] and (x, v) at the nodes of the reduced model, in 40 digits; plus the
    smallest margins of the events' conditioning (for ``assume``)."""
    mp.mp.dps = 40
    R, A, kappa = mp.mpf(sc.params["R"]), mp.mpf(sc.A), mp.mpf(sc.kappa)
    c = R * 2 * mp.mpf(G)
    x, v = mp.mpf(0), mp.mpf(v0)
    events, nodes = [], [(x, v)]
    margin = mp.inf
    for t0f, t1f, ukf, skf in pieces_of(schedule):
        t0, t1, uk, sk = mp.mpf(t0f), mp.mpf(t1f), mp.mpf(ukf), mp.mpf(skf)
        t = t0
        slipped = 0  # the direction of a slide that starts at a slip event (|u| = c there)
        while t < t1:
            ut = uk + sk * (t - t0)
            if slipped:
                s, slipped = slipped, 0
            elif v == 0:
                if ut > c:
                    s = 1
                elif ut < -c:
                    s = -1
                else:  # stick until |u| reaches c
                    margin = min(margin, c - abs(ut))  # not at the friction bound at a node
                    tau = (c - ut) / sk if sk > 0 else ((-c - ut) / sk if sk < 0 else mp.inf)
                    if t + tau < t1:
                        events.append((t + tau, "slip"))
                        margin = min(margin, abs(sk), t1 - (t + tau), (t + tau) - t0)
                        t, slipped = t + tau, (1 if sk > 0 else -1)
                        continue
                    break
                margin = min(margin, abs(ut) - c)
            else:
                s = 1 if v > 0 else -1
            D = A * (1 - kappa) if s > 0 else A * (1 + kappa)
            a0, j = (ut - s * c) / D, sk / D
            # first tau > 0 with v + a0 tau + j tau^2 / 2 = 0
            if j == 0:
                roots = [-v / a0] if a0 != 0 else []
            else:  # without cancellation: qq = -(a0 + sign(a0) sqrt(disc)) / 2, roots qq / (j/2), v / qq
                disc = a0 * a0 - 2 * j * v
                roots = []
                if disc >= 0:
                    qq = -(a0 + (1 if a0 >= 0 else -1) * mp.sqrt(disc)) / 2
                    roots = [2 * qq / j] + ([v / qq] if qq != 0 else [])
            roots = [r for r in roots if r > mp.mpf(10) ** -30]
            if j != 0 and -a0 / j > 0 and -a0 / j < t1 - t:  # a velocity extremum inside: not a near miss
                margin = min(margin, abs(v + a0 * (-a0 / j) / 2))
            tau = min(roots) if roots else mp.inf
            if t + tau < t1:
                x += v * tau + a0 * tau ** 2 / 2 + j * tau ** 3 / 6
                margin = min(margin, abs(a0 + j * tau), t1 - (t + tau))
                events.append((t + tau, "stop"))
                v = mp.mpf(0)
                t = t + tau
                continue
            tau = t1 - t
            x += v * tau + a0 * tau ** 2 / 2 + j * tau ** 3 / 6
            v = v + a0 * tau + j * tau ** 2 / 2
            t = t1
        nodes.append((x, v))
    return events, nodes, margin


values = st.floats(-U_MAX, U_MAX, allow_nan=False)


@st.composite
def schedules(draw):
    K = draw(st.integers(1, 4))
    h = draw(st.lists(st.floats(0.02, 0.3), min_size=K, max_size=K))
    t = np.concatenate([[0.0], np.cumsum(h)])
    hold = draw(st.sampled_from(["constant", "linear", "affine"]))
    rows = {"constant": K, "linear": K + 1, "affine": 2 * K}[hold]
    u = draw(st.lists(values, min_size=rows, max_size=rows))
    if hold == "affine":
        return AffineSchedule(t, u)
    return ControlSchedule(t, u, hold=hold)


@given(sched=schedules(), R=st.sampled_from([0.5, 0.2, 1.0, 1.9]), v0=st.sampled_from([0.0, 1.0, -0.7, 2.5]))
def test_block_matches_reduced_model(sched, R, v0):
    sc, system = block(R, v0)
    events, nodes, margin = reference(sc, sched, v0)
    assume(margin > 1e-6)  # no event at the limit of its conditioning (a grazing stop, |u| = c at a node)
    sysw = system.with_control(sched)
    res = lcp.simulate(sysw, sched.t_end, method="event", q0=sc.q0, v0=sc.v0, t_eval=sched.times)
    assert res.success, res.message
    # the fast path: the forcing is recognized and every phase is in closed form
    assert system_model(sysw).cubic or system_model(sysw).polynomial
    assert res.integrators == ["closed-form"]
    got = [(e.t, e.kind) for e in res.events if e.kind != "breakpoint"]
    assert [k for _, k in got] == [k for _, k in events]
    for (tg, _), (tr, _) in zip(got, events):
        assert abs(tg - float(tr)) <= 1e-12
    x_ref = np.array([float(x) for x, _ in nodes])
    v_ref = np.array([float(v) for _, v in nodes])
    assert np.max(np.abs(res.q[:, 0] - x_ref)) <= 1e-12
    assert np.max(np.abs(res.v[:, 0] - v_ref)) <= 1e-12
    assert np.max(np.abs(res.q[:, 1])) <= 1e-15  # no lift-off, no sinking
    # the stick phases hold the block exactly at rest
    for (tr, kind) in events:
        if kind == "stop":
            k = int(np.searchsorted(sched.times, float(tr), side="right"))
            if k < len(sched.times) and float(nodes[k][1]) == 0.0:
                assert res.v[k, 0] == 0.0


def test_affine_ramp_stop_is_exact():
    """u = 15 - 60 t on [0, 0.3] with R = 0.5: v = ((15 - c) t - 30 t^2) / D+ stops at (15 - c) / 30."""
    sc, system = block(0.5, 0.0)
    res = lcp.simulate(system, 0.3, method="event", q0=sc.q0, v0=sc.v0,
                       control=ControlSchedule([0.0, 0.3], [15.0, -3.0], hold="linear"))
    c = 0.5 * 2 * G
    assert res.mode_sequence == [("slide+",), ("stick",)]
    assert abs(res.t_events[0] - (15.0 - c) / 30.0) <= 1e-15
    D = sc.A * (1 - sc.kappa)
    tau = (15.0 - c) / 30.0
    x = ((15.0 - c) * tau ** 2 / 2 - 10.0 * tau ** 3) / D
    assert abs(res.q[-1, 0] - x) <= 1e-15 and res.v[-1, 0] == 0.0
    # the forces are affine in t over the slide: N = 2g - M tan(alpha) a with a affine
    i = np.searchsorted(res.t, 0.05)
    a = ((15.0 - 60.0 * res.t[i]) - c) / D
    assert abs(res.force_N[i, 0] - (2 * G - a)) <= 1e-12


def test_scipy_phases_use_the_time_dependent_linear_path():
    """smooth='scipy' on the same system: DOP853 on y' = L y + c + c1 (t - t0) agrees to its tolerance."""
    sc, system = block(0.5, 1.0)
    sched = AffineSchedule([0.0, 0.1, 0.25], [18.0, -5.0, 12.0, 19.0])
    sysw = system.with_control(sched)
    exact = lcp.simulate(sysw, 0.25, method="event", q0=sc.q0, v0=sc.v0)
    ode = lcp.simulate(sysw, 0.25, method="event", q0=sc.q0, v0=sc.v0, smooth="scipy")
    assert ode.integrators == ["DOP853"] and exact.integrators == ["closed-form"]
    assert [e.kind for e in ode.events] == [e.kind for e in exact.events]
    assert np.allclose(ode.t_events, exact.t_events, atol=1e-10)
    assert np.max(np.abs(ode.q - exact.q)) <= 1e-10 and np.max(np.abs(ode.v - exact.v)) <= 1e-9


def _ball(force_t):
    q, v, u, t = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1), ca.SX.sym("t")
    return System(q, v, mass=ca.SX.eye(2), force=ca.vertcat(u, -G + force_t(t)), t=t, control=u,
                  contacts=[Contact(gap=q[1], tangent=q[0], mu=0.3, e=0.0, name="floor")])


def test_forcing_is_only_taken_for_its_structure():
    sched = AffineSchedule([0.0, 0.5, 1.0], [1.0, 2.0, -3.0, 0.5])
    plain = _ball(lambda t: 0.0).with_control(sched)
    f = time_forcing(plain)
    assert f is not None and f.covers(0.0, 1.0) and not f.covers(0.0, 1.5)
    assert np.allclose(f.at(0.75), [-3.0 + 3.5 * 0.5, -G])
    # a force with a time dependence of its own: the general path
    assert time_forcing(_ball(lambda t: 1e-3 * ca.sin(7 * t)).with_control(sched)) is None
    # a state-dependent control matrix: not constant
    q, v, u = ca.SX.sym("q", 1), ca.SX.sym("v", 1), ca.SX.sym("u", 1)
    s = System(q, v, mass=1.0, force=(1 + q[0] ** 2) * u, control=u)
    assert time_forcing(s.with_control(ControlSchedule([0.0, 1.0], [1.0, 2.0], hold="linear"))) is None
    # past the schedule's end the System's own force is integrated (the general path)
    res = lcp.simulate(plain, 1.5, method="event", q0=[0.0, 0.0], v0=[0.0, 0.0])
    assert res.success and "closed-form" not in res.integrators
    res = lcp.simulate(plain, 1.0, method="event", q0=[0.0, 0.0], v0=[0.0, 0.0])
    assert res.success and res.integrators == ["closed-form"]


def test_cubic_landing_and_lift_off():
    """A ball lifted by an upward ramp (lift-off at a force root), then landing when it reverses
    (a cubic gap root), against the closed form."""
    q, v, u, t = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("u", 1), ca.SX.sym("t")
    s = System(q, v, mass=ca.SX.eye(2), force=ca.vertcat(0.0, -G + u), t=t, control=u,
               contacts=[Contact(gap=q[1], tangent=q[0], mu=0.3, e=0.0, name="floor")])
    # u = 40 t on [0, 1]: the normal force G - 40 t vanishes at t1 = G / 40; then y'' = 40 t - G
    sched = ControlSchedule([0.0, 1.0, 2.0], [0.0, 40.0, -200.0], hold="linear")
    res = lcp.simulate(s.with_control(sched), 2.0, method="event", q0=[0.0, 0.0], v0=[0.0, 0.0])
    assert res.success and res.integrators == ["closed-form"]
    kinds = [(e.kind, e.t) for e in res.events if e.kind != "breakpoint"]
    t1 = G / 40.0
    assert kinds[0][0] == "lift-off" and abs(kinds[0][1] - t1) <= 1e-15
    # after t = 1: y'' = 40 - 240 (t - 1) - G; landing time from the cubic, by a reference root
    y1 = 40.0 / 6 * (1 - t1) ** 3  # y and y' at t = 1 (jerk 40 from rest at t1)
    v1 = 20.0 * (1 - t1) ** 2
    c = [y1, v1, 0.5 * (40.0 - G), -240.0 / 6]
    mp.mp.dps = 40
    root = mp.findroot(lambda x: c[0] + c[1] * x + c[2] * x ** 2 + c[3] * x ** 3, 1.0)
    assert kinds[1][0] == "impact" and abs(kinds[1][1] - (1.0 + float(root))) <= 1e-12
    assert abs(first_descent(c, 10.0) - float(root)) <= 1e-14


@pytest.mark.parametrize("coeffs, T, expected", [
    ((1.0, -1.0), 2.0, 1.0), ((1.0, 1.0), 2.0, math.inf), ((0.0, -1.0), 2.0, math.inf),
    ((1.0, -2.0, 1.0), 5.0, 1.0),  # reaches zero at 1 (and rises again): an event
    ((1.0, 0.0, -1.0), 5.0, 1.0), ((-1.0, 3.0, -1.0), 5.0, (3 + math.sqrt(5)) / 2),
    # -(3x - 1)(2x - 1)(x - 1): falls through zero at 1/3, rises through 1/2, falls through 1
    ((1.0, -6.0, 11.0, -6.0), 0.3, math.inf), ((1.0, -6.0, 11.0, -6.0), 10.0, 1 / 3),
    ((-1.0, 6.0, -11.0, 6.0), 10.0, 0.5), ((-1.0, 6.0, -11.0, 6.0), 0.45, math.inf)])
def test_first_descent(coeffs, T, expected):
    got = first_descent(coeffs, T)
    if math.isinf(expected):
        assert math.isinf(got)
    else:
        assert abs(got - expected) <= 1e-15 * max(1.0, expected)


def test_ocp_replay_in_one_integration_matches_the_restarted_one():
    """An affine-hold OCP solution replayed over the whole schedule at once (closed form) equals
    the replay restarted at every node, and its per-interval pieces keep their layout."""
    from lcp.ocp import OptimalControlProblem, effort, replay
    from lcp.ocp.replay import _whole_schedule_system, event_pieces

    sc, system = block(0.5, 0.0)
    ocp = OptimalControlProblem(system, 6, q0=sc.q0, v0=sc.v0, T=1.0, stage_cost=effort, hold="affine",
                                steps="free", terminal_constraints=lambda q, v: ca.vertcat(q[0] - 0.3, v[0]))
    res = ocp.solve(ocp.guess(u=0.0), sigma0=1e-2, factor=1e-2, max_iter=3000)
    assert res.control.hold == "affine"
    assert _whole_schedule_system(res, {"n_eval": 5}) is not None
    assert _whole_schedule_system(res, {"n_eval": 5, "rtol": 1e-12}) is not None  # (the tolerance too)
    assert _whole_schedule_system(res, {"n_eval": 5, "ode_method": "RK45"}) is None  # other options: restarted
    rp = replay(res, method="event", n_eval=5)
    q_r, v_r, pieces_r = event_pieces(res, restart=True, n_eval=5)
    assert np.max(np.abs(rp.q - q_r)) <= 1e-13 and np.max(np.abs(rp.v - v_r)) <= 1e-13
    assert len(rp.pieces) == len(pieces_r) == 6
    for a, b, h in zip(rp.pieces, pieces_r, np.diff(res.t)):
        assert a.t.shape == b.t.shape == (5,) and a.t[0] == 0.0 and abs(a.t[-1] - h) <= 1e-15
        assert np.max(np.abs(a.q - b.q)) <= 1e-13 and np.max(np.abs(a.force_N - b.force_N)) <= 1e-9
        assert a.integrators == ["closed-form"] and a.phases[0].t0 == 0.0


def _general(system):
    """The System integrated without the forcing (CasADi evaluations, DOP853): the reference path."""
    from lcp.events import model as events_model

    events_model.MODELS[system] = events_model.SystemModel(system, general=True)
    return system


def test_bilateral_constraint_against_the_general_path():
    """Two blocks held together by a bilateral constraint on a rough floor, pushed by an affine
    control on the second: the closed form agrees with the general (CasADi, DOP853) integration."""
    q, v, u = ca.SX.sym("q", 3), ca.SX.sym("v", 3), ca.SX.sym("u", 1)
    s = System(q, v, mass=ca.diag(ca.vertcat(1.0, 2.0, 3.0)), force=ca.vertcat(0.0, u, -3.0 * G),
               contacts=[Contact(gap=q[2], tangent=q[0], mu=0.4, e=0.0, name="floor")],
               constraints=q[0] - q[1], control=u)
    sched = AffineSchedule([0.0, 0.2, 0.5], [30.0, 2.0, -30.0, 5.0])
    fast = s.with_control(sched)
    res = lcp.simulate(fast, 0.5, method="event", q0=[0.0, 0.0, 0.0], v0=[0.5, 0.5, 0.0], n_eval=11)
    ref = lcp.simulate(_general(s.with_control(sched)), 0.5, method="event", q0=[0.0, 0.0, 0.0],
                       v0=[0.5, 0.5, 0.0], n_eval=11)
    assert res.success and ref.success
    assert system_model(fast).cubic and res.integrators == ["closed-form"] and ref.integrators == ["DOP853"]
    assert res.mode_sequence == ref.mode_sequence and len(res.mode_sequence) >= 2
    assert np.allclose(res.t_events, ref.t_events, atol=1e-10)
    assert np.max(np.abs(res.q - ref.q)) <= 1e-10 and np.max(np.abs(res.v - ref.v)) <= 1e-9
    assert np.max(np.abs(res.q[:, 0] - res.q[:, 1])) <= 1e-15  # the constraint holds exactly
