"""Accumulations of impacts and impact cascades on spatial contacts, friction in cascades, and
the event method's start check.

A ball on a spatial contact (q = (x, z, y), two tangent directions) bounces infinitely often
before t_inf = t_1 (1 + e) / (1 - e) exactly as on a planar contact: before, the spatial
integrator resolved bounce after bounce until they fell below its velocity tolerance and then
"rested" with the last bounce's residual velocity (gap 5e-8 rising at 8.4e-9 m/s, t_inf missed
by 8.6e-9). Columns of beads with friction close several contacts at one instant: the cascade goes
round by round on the coupled problem of the closed and approaching contacts.
"""
from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import lcp
from lcp import Contact, System
from lcp.classical import BouncingBallExact
from lcp.events.accumulation import BounceSequence

G = 9.81


def ball(spatial: bool, mu: float, e: float) -> System:
    """A point mass over the floor y = 0: q = (x, y) planar, q = (x, z, y) spatial."""
    n = 3 if spatial else 2
    q, v = ca.SX.sym("q", n), ca.SX.sym("v", n)
    tangent = ca.vertcat(q[0], q[1]) if spatial else q[0]
    force = ca.vertcat(*([0.0] * (n - 1) + [-G]))
    return System(q, v, ca.SX.eye(n), force, contacts=[Contact(gap=q[n - 1], tangent=tangent, mu=mu, e=e,
                                                               name="floor")])


def bead_column(K: int, e: float, mu: float, spatial: bool, vx=None, r: float = 0.1, spacing: float = 0.05,
                drop: float = 0.5):
    """K beads (point masses) above a floor, each resting on the one below through a contact with
    friction mu: q = (x_i, y_i) planar, (x_i, z_i, y_i) spatial; horizontal velocities vx (along x)."""
    d = 3 if spatial else 2
    q, v = ca.SX.sym("q", d * K), ca.SX.sym("v", d * K)
    y = q[d - 1::d]

    def tangent(i):
        return ca.vertcat(q[d * i], q[d * i + 1]) if spatial else q[d * i]

    force = ca.vertcat(*[ca.DM([0.0] * (d - 1) + [-G]) for _ in range(K)])
    contacts = [Contact(gap=y[0] - r, tangent=tangent(0), mu=mu, e=e, name="floor")]
    contacts += [Contact(gap=y[i] - y[i - 1] - 2 * r, tangent=tangent(i) - tangent(i - 1), mu=mu, e=e,
                         name=f"bead{i}") for i in range(1, K)]
    q0, v0 = np.zeros(d * K), np.zeros(d * K)
    q0[d - 1::d] = r + drop + np.arange(K) * (2 * r + spacing)
    if vx is not None:
        v0[0::d] = vx
    return System(q, v, ca.SX.eye(d * K), force, contacts=contacts), q0, v0


# ----------------------------------------------------------------------------- accumulation
@settings(max_examples=12, deadline=None)
@given(e=st.floats(0.3, 0.9), height=st.floats(0.2, 2.0), mu=st.sampled_from([0.0, 0.3]))
def test_spatial_ball_accumulation_time_is_the_closed_form(e, height, mu):
    exact = BouncingBallExact(e, height, 1.0, G)
    t_end = 1.5 * exact.t_inf
    res = lcp.simulate(ball(True, mu, e), t_end, method="event", q0=[0.0, 0.0, height], v0=[0.0, 0.0, 0.0],
                       t_eval=[0.0, exact.t_inf, t_end])
    assert res.success and res.status == 0, res.message
    assert len(res.accumulations) == 1
    acc = res.accumulations[0]
    assert acc.method == "closed-form" and acc.contacts == (0,)
    assert abs(acc.t - exact.t_inf) <= 1e-12 * exact.t_inf
    # the impacts resolved one by one are the exact ones
    times = np.array([imp.t for imp in res.impacts])
    np.testing.assert_allclose(times, exact.impact_times[:times.size], rtol=1e-12, atol=0)
    # after the limit the ball rests exactly on the floor
    assert res.q[-1].tolist() == [0.0, 0.0, 0.0] and res.v[-1].tolist() == [0.0, 0.0, 0.0]


@pytest.mark.parametrize("speed,mu", [(5.0, 0.1), (3.0, 0.1)])
def test_ball_bouncing_while_sliding_spatial_agrees_with_planar(speed, mu):
    # friction acts at every impact (the ball slides through them) and, for speed 5, in the
    # sliding phase after the accumulation, until the ball stops
    e, height, theta = 0.8, 1.0, 0.7
    exact = BouncingBallExact(e, height, 1.0, G)
    ts = np.linspace(0.0, 8.0, 81)
    planar = lcp.simulate(ball(False, mu, e), 8.0, method="event", q0=[0.0, height], v0=[speed, 0.0], t_eval=ts)
    d = np.array([math.cos(theta), math.sin(theta)])  # an oblique sliding direction
    spatial = lcp.simulate(ball(True, mu, e), 8.0, method="event", q0=[0.0, 0.0, height],
                           v0=[speed * d[0], speed * d[1], 0.0], t_eval=ts)
    for res in (planar, spatial):
        assert res.success, res.message
        assert len(res.accumulations) == 1
        assert abs(res.accumulations[0].t - exact.t_inf) <= 1e-12 * exact.t_inf
    along = spatial.q[:, :2] @ d
    across = spatial.q[:, :2] @ np.array([-d[1], d[0]])
    np.testing.assert_allclose(along, planar.q[:, 0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(across, 0.0, rtol=0, atol=1e-12)
    np.testing.assert_allclose(spatial.q[:, 2], planar.q[:, 1], rtol=0, atol=1e-12)
    # the tangential velocity left after the impacts: speed - mu (1 + e) (sum of approach speeds)
    v_left = speed - mu * (1 + e) * exact.approach_speeds[0] / (1 - e)
    stops = [ev.t for ev in planar.events if ev.kind == "stop"]
    if v_left > 0:
        assert len(stops) == 1 and abs(stops[0] - (exact.t_inf + v_left / (mu * G))) <= 1e-12 * stops[0]
        assert [ev.t for ev in spatial.events if ev.kind == "stop"] == pytest.approx(stops, rel=1e-12, abs=0)
    else:
        assert not stops
    assert spatial.accumulations[0].P_N == pytest.approx(planar.accumulations[0].P_N, rel=1e-9)
    P_T = np.asarray(spatial.accumulations[0].P_T[0])
    assert P_T @ d == pytest.approx(planar.accumulations[0].P_T[0], rel=1e-9, abs=1e-15)


@pytest.mark.parametrize("spatial", [False, True])
def test_bounces_below_the_tolerance_rest_on_the_floor(spatial, monkeypatch):
    # without the accumulation's summing up the bounces are resolved until they fall below the
    # velocity tolerance; the contact closed there starts on the floor (before: it kept the last
    # bounce's residual velocity through the 'resting' phase, 5e-8 above the floor at t = 10)
    monkeypatch.setattr(BounceSequence, "geometric", lambda self: False)
    n = 3 if spatial else 2
    q0 = np.zeros(n)
    q0[-1] = 1.0
    res = lcp.simulate(ball(spatial, 0.3, 0.8), 10.0, method="event", q0=q0, v0=np.zeros(n), t_eval=[0.0, 5.0, 10.0])
    assert res.success, res.message
    assert not res.accumulations and len(res.impacts) > 50
    assert res.q[-1].tolist() == [0.0] * n and res.v[-1].tolist() == [0.0] * n


# ----------------------------------------------------------------------------- cascades with friction
@pytest.mark.parametrize("spatial", [False, True])
def test_frictional_bead_column_reaches_t_end(spatial):
    K = 5
    system, q0, v0 = bead_column(K, 0.5, 0.3, spatial, vx=np.linspace(-0.5, 0.5, K))
    res = lcp.simulate(system, 3.0, method="event", q0=q0, v0=v0, t_eval=np.linspace(0.0, 3.0, 31))
    assert res.success and res.status == 0, res.message
    d = 3 if spatial else 2
    np.testing.assert_allclose(res.q[-1, d - 1::d], 0.1 + 0.2 * np.arange(K), atol=1e-9)
    assert np.all(system.gaps(res.q[-1]) >= -1e-9)
    np.testing.assert_allclose(res.v[-1], 0.0, rtol=0, atol=1e-12)  # stacked and stuck
    # several contacts closed at one instant: impulses on several contacts at one time
    times = [imp.t for imp in res.impacts]
    assert len(times) > len(set(times))
    # friction acted at the impacts (the beads' horizontal velocities differ)
    assert sum(bool(np.any(np.asarray(imp.p_T) != 0.0)) for imp in res.impacts) > K


def test_spatial_bead_column_agrees_with_planar():
    # the beads move in the x-y plane: the spatial contacts' second tangent carries nothing
    K = 5
    ts = np.linspace(0.0, 3.0, 61)
    planar_sys, q0, v0 = bead_column(K, 0.5, 0.3, False, vx=np.linspace(-0.5, 0.5, K))
    spatial_sys, q0s, v0s = bead_column(K, 0.5, 0.3, True, vx=np.linspace(-0.5, 0.5, K))
    planar = lcp.simulate(planar_sys, 3.0, method="event", q0=q0, v0=v0, t_eval=ts)
    spatial = lcp.simulate(spatial_sys, 3.0, method="event", q0=q0s, v0=v0s, t_eval=ts)
    assert planar.success and spatial.success, (planar.message, spatial.message)
    np.testing.assert_allclose(spatial.q[:, 0::3], planar.q[:, 0::2], rtol=0, atol=1e-9)
    np.testing.assert_allclose(spatial.q[:, 2::3], planar.q[:, 1::2], rtol=0, atol=1e-9)
    np.testing.assert_allclose(spatial.q[:, 1::3], 0.0, rtol=0, atol=1e-15)
    # the same impulses per contact (the cascades' rounds may record a vanishing impulse or not)
    total = [np.bincount([imp.contact for imp in res.impacts], [imp.p_N for imp in res.impacts], K)
             for res in (planar, spatial)]
    np.testing.assert_allclose(total[1], total[0], rtol=1e-9)


def test_frictional_bead_column_moreau_jean_converges_to_the_event_method():
    K = 3
    system, q0, v0 = bead_column(K, 0.5, 0.3, False, vx=np.linspace(-0.5, 0.5, K))
    ts = np.round(np.linspace(0.0, 1.5, 31), 10)
    ev = lcp.simulate(system, 1.5, method="event", q0=q0, v0=v0, t_eval=ts)
    assert ev.success, ev.message
    errors = []
    for h in (1e-3, 1e-4, 1e-5):
        mj = lcp.simulate(system, 1.5, h=h, q0=q0, v0=v0)
        assert mj.success, mj.message
        errors.append(float(np.abs(mj.q[np.round(ts / h).astype(int)] - ev.q).max()))
    assert errors[2] < 1e-4 and errors[2] < errors[0] / 20, errors


@pytest.mark.parametrize("spatial", [False, True])
def test_a_cascade_past_its_round_cap_is_said_with_its_time(spatial, monkeypatch):
    # no silent success: a cascade finished at once (past the cap of rounds) is in the message
    import lcp.events.integrator as planar_integrator
    import lcp.events.spatial as spatial_integrator

    monkeypatch.setattr(spatial_integrator if spatial else planar_integrator, "CASCADE_ROUNDS", 2)
    system, q0, v0 = bead_column(5, 0.5, 0.0, spatial)
    res = lcp.simulate(system, 3.0, method="event", q0=q0, v0=v0, t_eval=[0.0, 3.0])
    assert "did not end after 2 rounds" in res.message and "At t = " in res.message
    assert any("finished at once" in imp.reason for imp in res.impulses)
    assert np.all(system.gaps(res.q[-1]) >= -1e-9)


# ----------------------------------------------------------------------------- the start check
@pytest.mark.parametrize("spatial", [False, True])
def test_a_start_penetrating_by_rounding_is_projected(spatial):
    # 8.8e-7: the woodpecker toy's data (Siconos) penetrate by this much
    n = 3 if spatial else 2
    system = ball(spatial, 0.3, 0.5)
    q0 = np.zeros(n)
    q0[0], q0[-1] = 0.3, -8.8e-7
    res = lcp.simulate(system, 1.0, method="event", q0=q0, v0=np.zeros(n), t_eval=[0.0, 1.0])
    assert res.success, res.message
    assert "projected" in res.message and "off by 8.8e-07" in res.message  # the common start check
    assert res.q[0, -1] == 0.0 and res.q[-1, -1] == 0.0 and res.q[-1, 0] == 0.3
    q0[-1] = -1e-2
    with pytest.raises(ValueError, match="penetrates contact 'floor'"):
        lcp.simulate(system, 1.0, method="event", q0=q0, v0=np.zeros(n))
