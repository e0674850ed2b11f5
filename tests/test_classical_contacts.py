"""Classical contact systems (lcp.classical) against their exact solutions or independent
references: Moreau-Jean within its order on several step sizes, and the event method where it
applies (it must succeed and be right, or say why not)."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import lcp
from lcp.classical import bouncing_ball, box_on_corners, incline, rocking_block, stacked_blocks


def observed_order(hs, errs):
    """Least-squares slope of log(error) against log(h)."""
    return float(np.polyfit(np.log(hs), np.log(errs), 1)[0])


# ----------------------------------------------------------------------------- incline
def _incline_bound(sc, h, T):
    """Moreau-Jean (theta = 1/2) on the incline: exact while the acceleration is constant; the step
    of the stop errs by at most B h^2 / 8 if it sticks (B the deceleration), and by a velocity of
    at most |a1 - a2| h if the motion reverses (a1, a2 the accelerations before and after), which
    then grows linearly."""
    segs = sc.solution.segments
    bound = 1e-12 * max(1.0, T * T)
    if len(segs) > 1:
        a1, a2 = segs[0].a, segs[1].a
        bound += abs(a1) * h * h / 8
        if segs[1].mode != "stick":
            bound += abs(a1 - a2) * h * (T - segs[1].t0 + h) + abs(a2) * h * h
    return bound


@pytest.mark.parametrize("alpha, mu, v0, regime", [
    (0.3, 0.5, 0.0, ("stick",)),
    (0.5, 0.2, 0.0, ("slide-",)),
    (0.3, 0.5, 2.0, ("slide+", "stick")),
    (0.5, 0.2, 2.0, ("slide+", "slide-")),
    (0.3, 0.1, -1.0, ("slide-",)),
])
def test_incline_regimes(alpha, mu, v0, regime):
    T = 1.0
    sc = incline(alpha, mu, v0, t_end=T)
    assert tuple(sg.mode for sg in sc.solution.segments) == regime
    errs, hs = [], [1e-2 * (1 + 1 / 7), 5e-3 * (1 + 1 / 11), 2.5e-3 * (1 + 1 / 13), 1.25e-3 * (1 + 1 / 17)]
    for h in hs:
        res = lcp.simulate(sc, h=h)
        assert res.success, res.message
        err = float(np.max(np.abs(res.q - sc.exact(res.t)["q"])))
        assert err <= _incline_bound(sc, h, T)
        assert np.max(np.abs([sc.system.gaps(q) for q in res.q])) <= 1e-14
        errs.append(err)
    if regime == ("slide+", "slide-"):
        assert 0.7 <= observed_order(hs, errs) <= 1.5  # first order: the reversal inside a step
    if regime == ("slide+", "stick"):
        assert observed_order(hs, errs) >= 1.5  # the stop step only: B h^2 / 8
    res = lcp.simulate(sc, method="event")
    assert res.success, res.message
    assert np.max(np.abs(res.q - sc.exact(res.t)["q"])) <= 1e-10


@settings(deadline=None)  # examples: the profile's (conftest)
@given(alpha=st.floats(0.02, 1.3), mu=st.floats(0.0, 1.5), v0=st.floats(-3.0, 3.0))
def test_incline_random_parameters(alpha, mu, v0):
    T = 0.8
    sc = incline(alpha, mu, v0, t_end=T)
    for h in (1e-2, 1e-3):
        res = lcp.simulate(sc, h=h)
        assert res.success, res.message
        assert np.max(np.abs(res.q - sc.exact(res.t)["q"])) <= _incline_bound(sc, h, T) + 1e-12 * abs(v0)


# ----------------------------------------------------------------------------- bouncing ball
def _rest_time(ex, h):
    """When Moreau-Jean's ball is at rest at the latest: t_inf plus its O(h) drift (measured at
    most 0.6 % of t_inf at h = 1e-3, e <= 0.9), plus the fall from where a velocity-level impact
    may stop it, up to v1 h above the floor (sqrt(2 v1 h / g))."""
    return 1.02 * ex.t_inf + math.sqrt(2 * ex.approach_speeds[0] * h / ex.g) + 10 * h


@pytest.mark.parametrize("e", [0.0, 0.5, 0.8])
def test_bouncing_ball_impacts_and_rest(e):
    sc = bouncing_ball(e=e, height=1.0)
    ex = sc.solution
    v1 = ex.approach_speeds[0]
    errs, rest = [], []
    for h in (1e-3, 1e-4):
        res = lcp.simulate(sc, h=h)
        assert res.success, res.message
        err = float(np.max(np.abs(res.q[:, 1] - sc.exact(res.t)["y"])))
        # impact times off by about a step, at the impact speed; the offsets carry over the flights
        # (at most 2 v1 h measured for e <= 0.9)
        assert err <= 3 * v1 * h
        errs.append(err)
        moving = np.flatnonzero(np.any(res.v != 0, axis=1))
        rest.append(abs(res.t[moving[-1] + 1] - ex.t_inf))  # the discrete accumulation point
        assert np.all(res.v[res.t > _rest_time(ex, h)] == 0.0)  # at rest after the accumulation
        late = res.t > _rest_time(ex, h)
        # velocity-level: it may rest up to a step's free fall above the floor, or sink O(h)
        assert np.all((res.q[late, 1] <= 9.81 * h * h / 2) & (res.q[late, 1] >= -v1 * h))
        assert abs(res.impacts[0].t - ex.impact_times[0]) <= h
    if e > 0:  # (with e = 0 the one impact's O(h) error depends on where it falls in its step)
        assert errs[1] <= 0.3 * errs[0]
        assert rest[1] <= 0.3 * rest[0]  # Moreau-Jean comes to rest at t_inf + O(h)
    res = lcp.simulate(sc, method="event")
    assert res.success, res.message
    assert np.max(np.abs(res.q[:, 1] - sc.exact(res.t)["y"])) <= 1e-9
    if 0 < e < 1:
        acc = res.accumulations[0]
        assert acc.t == pytest.approx(ex.t_inf, rel=1e-9)
        np.testing.assert_allclose([i.t for i in res.impacts[:5]], ex.impact_times[:5], rtol=1e-12)


@settings(deadline=None)  # examples: the profile's (conftest)
@given(e=st.floats(0.0, 0.9), height=st.floats(0.05, 3.0))
def test_bouncing_ball_random_parameters(e, height):
    sc = bouncing_ball(e=e, height=height)
    ex = sc.solution
    h = 1e-3
    res = lcp.simulate(sc, h=h)
    assert res.success
    assert np.max(np.abs(res.q[:, 1] - sc.exact(res.t)["y"])) <= 3 * ex.approach_speeds[0] * h
    assert np.all(res.v[res.t > _rest_time(ex, h)] == 0.0)


# ----------------------------------------------------------------------------- stacked blocks
@pytest.mark.parametrize("push, regime", [(5.0, "stick"), (12.0, "together"), (20.0, "top slips")])
def test_pushed_stack_regimes(push, regime):
    sc = stacked_blocks(2, mu=[0.5, 0.3], push=push)
    assert sc.params["regime"] == regime
    for h in (1e-2, 1e-3):
        res = lcp.simulate(sc, 0.5, h=h)
        assert res.success, res.message
        ex = sc.exact(res.t)
        # constant forces from rest: theta = 1/2 is exact in every regime
        assert np.max(np.abs(res.q - ex["q"])) <= 1e-12
        np.testing.assert_allclose(res.N, np.broadcast_to(ex["N"][0], res.N.shape), rtol=1e-10)
        expect = {"stick": (1, 1), "together": (2, 1), "top slips": (2, 3)}[regime]
        assert tuple(res.modes[-1]) == expect


@settings(deadline=None)  # examples: the profile's (conftest)
@given(push=st.floats(0.5, 60.0), m0=st.floats(0.2, 5.0), m1=st.floats(0.2, 5.0), mu0=st.floats(0.05, 1.0),
       mu1=st.floats(0.05, 1.0))
def test_pushed_stack_random_parameters(push, m0, m1, mu0, mu1):
    sc = stacked_blocks(2, m=[m0, m1], mu=[mu0, mu1], push=push)
    res = lcp.simulate(sc, 0.3, h=1e-2)
    assert res.success, res.message
    ex = sc.exact(res.t)
    assert np.max(np.abs(res.q - ex["q"])) <= 1e-10 * max(1.0, float(np.max(np.abs(ex["a"]))))


# ----------------------------------------------------------------------------- box on two corners
def test_box_slides_under_a_ramp_force():
    sc = box_on_corners(mu=0.3, push_height=0.25, t_end=1.6)
    sol = sc.solution
    assert sol.regime == "slide" and sol.t_valid > 1.6
    m, c = sc.params["m"], sc.params["ramp"]
    for h in (4e-3 * (1 + 1 / 7), 1e-3):
        res = lcp.simulate(sc, h=h)
        assert res.success and res.impacts == []
        assert res.stats.projections == res.stats.steps  # curved contacts: projected
        assert np.max(np.abs(res.q[:, 2])) <= 1e-12 and res.max_constraint_violation <= 1e-12
        dv = c * h * h / (2 * m)  # only the step of the onset errs (as a ramp-pushed block)
        assert np.max(np.abs(res.q[:, 0] - sol(res.t)["x"])) <= dv * (1.6 - sol.t_slide + h) + 1e-12


def test_box_tips_about_its_front_corner():
    sc = box_on_corners(mu=1.2, push_height=0.45, t_end=2.6)
    sol = sc.solution
    assert sol.regime == "tip"
    hs, errs = [4e-3, 2e-3, 1e-3], []
    for h in hs:
        res = lcp.simulate(sc, h=h)
        assert res.success and res.impacts == []
        th = res.q[:, 2]
        errs.append(float(np.max(np.abs(th - sol.tip_angle(res.t)))))
        front_x = res.q[:, 0] + 0.5 * np.cos(th) + 0.25 * np.sin(th)
        assert np.max(np.abs(front_x - 0.5)) <= 0.05 * h  # the pivot sticks (to the scheme's O(h))
        tipping = res.t[:-1] > sol.t_tip + 2 * h
        assert np.all(res.modes[tipping, 0] == -1) and np.all(res.modes[tipping, 1] == 1)
    assert 0.8 <= observed_order(hs, errs) <= 1.5 and errs[-1] <= 2e-4


def test_box_event_method():
    sc = box_on_corners(mu=0.3, push_height=0.25, t_end=1.6)
    res = lcp.simulate(sc, method="event")
    assert res.success, res.message
    assert np.max(np.abs(res.q[:, 0] - sc.solution(res.t)["x"])) <= 1e-9
    assert np.max(np.abs(res.q[:, 2])) <= 1e-12


# ----------------------------------------------------------------------------- rocking block
def test_rocking_block_against_housner():
    sc = rocking_block(t_end=0.75)
    ref = sc.solution
    hs, errs = [1e-3, 5e-4, 2.5e-4], []
    for h in hs:
        res = lcp.simulate(sc, h=h)
        assert res.success, res.message
        errs.append(float(np.max(np.abs(res.q[:, 2] - ref(res.t)["theta"]))))
        imp = res.impacts
        assert [i.contact for i in imp] == [1, 0]  # one impact per pivot change, alternating
        assert abs(imp[0].t - ref.impact_times[0]) <= 2 * h
        # the angular velocity ratio across the first impact is Housner's
        k = np.searchsorted(res.t, imp[0].t)
        ratio = res.v[k + 1, 2] / res.v[k - 2, 2]
        assert ratio == pytest.approx(ref.r, abs=0.02)
    assert observed_order(hs, errs) >= 0.7 and errs[-1] <= 2e-3
    ev = lcp.simulate(sc, method="event")
    assert ev.success, ev.message
    assert np.max(np.abs(ev.q[:, 2] - ref(ev.t)["theta"])) <= 1e-9
