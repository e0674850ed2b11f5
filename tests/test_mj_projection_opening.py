"""Moreau-Jean's position projection never pulls an opening contact shut: it acts on the bilateral
constraints and on the contacts closed in the step (loaded, not separating), with tolerances scaled
by the problem (the rows' constants, the system's length, the step's motion), not by |J||q| alone."""
import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import lcp
from lcp.model.system import Contact, System
from lcp.timestepping.projection import PositionProjection

G = 9.81


def _shaker(A=0.05, w=2 * math.pi * 3, e=0.8, mu=0.3):
    """A follower (x, y) on a cam (a table) whose height c is a coordinate pinned to s(t) = A sin(w t)
    by the rheonomic constraint c - s(t) = 0 (it switches projection="auto" on); contact gap y - c."""
    q, v, t = ca.SX.sym("q", 3), ca.SX.sym("v", 3), ca.SX.sym("t")
    return System(q, v, ca.diag(ca.vertcat(2.0, 1.0, 1.0)), ca.vertcat(0, 0, -G), t=t,
                  constraints=q[0] - A * ca.sin(w * t),
                  contacts=[Contact(gap=q[2] - q[0], tangent=q[1], mu=mu, e=e, name="cam")])


def _floor_point():
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    return System(q, v, ca.SX.eye(2), ca.vertcat(0, -G),
                  contacts=[Contact(gap=q[1], tangent=q[0], mu=0.3, e=0.5, name="floor")])


def test_projector_leaves_an_open_contact_alone_after_holding_it():
    # the contact entered the working set in the call before (penetrating): it is not pulled shut
    # from 2 mm above the floor in the next call (it was returned at a gap of 2e-31)
    P = PositionProjection(_floor_point())
    q1, ok, _, viol = P.project(0.0, np.array([0.0, -1e-3]))
    assert ok and abs(q1[1]) <= 1e-15 and viol <= 1e-15
    q2, ok, _, _ = P.project(0.0, np.array([0.0, 0.002]))
    assert ok and q2[1] == 0.002
    # an opening contact is not pushed out either: its motion opens it
    q3, ok, _, _ = P.project(0.0, np.array([0.0, -1e-3]), opening=[True])
    assert ok and q3[1] == -1e-3


def test_projector_tolerance_at_the_origin():
    # a point 1 mm in the floor is pushed out to q = 0, where the old scale |J||q| was zero: the
    # Newton iterate's gap of -1e-199 was "not converged" (ok=False, status -5 in a run)
    P = PositionProjection(_floor_point())
    qp, ok, _, viol = P.project(0.0, np.array([0.0, -1e-3]))
    assert ok and abs(qp[1]) <= 1e-15 and viol <= 1e-15
    qp, ok, _, viol = P.project(0.0, np.array([0.0, -1e-199]))
    assert ok and viol <= 1e-199


@settings(max_examples=25, deadline=None)
@given(speed=st.floats(0.2, 20.0), e=st.floats(0.1, 1.0), gap0=st.floats(1e-6, 0.05))
def test_a_separating_contact_is_never_pulled_shut(speed, e, gap0):
    """A follower falling at ``speed`` onto the moving cam from ``gap0`` above it bounces (restitution
    e): in every later step whose normal velocity separates, the follower moves by exactly the
    step's motion h (v- + v+)/2 (theta = 1/2): the projection moves it neither down nor up (it
    corrects the table's height only, whose coordinate the follower's does not share)."""
    s = _shaker(A=1e-3, w=10.0, e=e)
    h = 1e-3
    v_hit = math.sqrt(speed ** 2 + 2 * G * gap0)  # free fall onto the table (it moves by 1 mm at most)
    t_hit = (v_hit - speed) / G
    flight = 2 * e * v_hit / G
    n_after = max(2, min(15, int(0.5 * flight / h)))
    t_end = (math.ceil(t_hit / h) + n_after) * h
    res = lcp.simulate(s, t_end, h=h, q0=[0.0, 0.0, gap0], v0=[1e-2, 0.0, -speed])
    assert res.success, res.message
    assert res.stats.projections == res.stats.steps
    gap = res.q[:, 2] - res.q[:, 0]
    uN = res.v[:, 2] - res.v[:, 0]
    y, vy = res.q[:, 2], res.v[:, 2]
    hits = np.flatnonzero(res.p_N[:, 0] > 0)  # the steps with an impulse: the impact, then perhaps a landing
    hit = int(hits[0])
    checked = 0
    for k in range(hit, res.t.size - 1):
        if k > hit and res.p_N[k, 0] > 0:
            break
        if uN[k + 1] > 0:
            motion = 0.5 * h * (vy[k] + vy[k + 1])
            assert y[k + 1] - y[k] == pytest.approx(motion, rel=1e-12, abs=1e-15), (k, gap[k], gap[k + 1])
            checked += 1
    assert checked >= n_after - 2
    assert gap[hit + 2] > gap[hit + 1]  # it flies off: the opening motion is kept


def _event_reference(s, q0, v0, t):
    ev = lcp.simulate(s, float(t[-1]), method="event", q0=q0, v0=v0, t_eval=t)
    assert ev.success, ev.message
    return ev


def test_shaker_follower_converges_to_the_event_method():
    # the table accelerates down faster than g: the follower takes off, flies and lands again
    # (e = 0.8); the projection (on: the constraint is rheonomic) held it on the table after its
    # first bounce (at h = 1e-3 the end height was the table's, 8.7e-3 below the event method's)
    s = _shaker()
    q0, v0 = [0.0, 0.0, 0.0], [0.05 * 2 * math.pi * 3, 0.0, 0.05 * 2 * math.pi * 3]
    errs = []
    for h in (1e-3, 1e-4):
        res = lcp.simulate(s, 0.6, h=h, q0=q0, v0=v0)
        assert res.success, res.message
        assert res.stats.projections == res.stats.steps
        every = max(1, int(round(1e-3 / h)))
        ev = _event_reference(s, q0, v0, res.t[::every])
        errs.append(float(np.max(np.abs(res.q[::every, 2] - ev.q[:, 2]))))
        # the table's height is kept to the projection's tolerance
        assert np.max(np.abs(res.q[:, 0] - 0.05 * np.sin(2 * math.pi * 3 * res.t))) <= 1e-12
    assert errs[0] < 5e-3 and errs[1] < errs[0] / 3, errs


@pytest.mark.slow
def test_shaker_follower_converges_to_the_event_method_fine():
    s = _shaker()
    q0, v0 = [0.0, 0.0, 0.0], [0.05 * 2 * math.pi * 3, 0.0, 0.05 * 2 * math.pi * 3]
    errs = []
    for h in (1e-3, 1e-4, 1e-5):
        res = lcp.simulate(s, 0.6, h=h, q0=q0, v0=v0, save_every=max(1, int(round(1e-3 / h))))
        ev = _event_reference(s, q0, v0, res.t)
        errs.append(float(np.max(np.abs(res.q[:, 2] - ev.q[:, 2]))))
    assert errs[2] < errs[1] / 3 and errs[1] < errs[0] / 3, errs
