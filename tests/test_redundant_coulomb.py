"""Coulomb's law holds contact by contact where contacts are redundant, in both Moreau-Jean loops.

Redundant contacts (two pucks joined by a bar, both stuck along it; a block resting on two corners)
leave only the sum of their tangential impulses determined, and W singular to rounding. A solve
on such a W may return any split, and a correction on it may move the split out of a contact's
disk while the velocities stay right: that happened (a friction impulse at 2.46 mu p_N with a
"solved" residual). Whatever split a loop returns must keep every contact inside its cone.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

import lcp
from lcp.model.control import ControlSchedule
from lcp.model.system import Contact, System


def _disk_excess(res, mu, dims):
    """max over steps and contacts of |p_T,j| - mu_j p_N,j, relative to the largest normal impulse."""
    worst, col = 0.0, 0
    scale = max(float(np.max(res.p_N)), 1e-300)
    for j, (m, d) in enumerate(zip(mu, dims)):
        tang = np.linalg.norm(res.p_T[:, col:col + d], axis=1)
        col += d
        worst = max(worst, float(np.max(tang - m * res.p_N[:, j])) / scale)
    return worst


@settings(max_examples=12, deadline=None)
@given(mu_a=st.floats(0.1, 0.9), mu_b=st.floats(0.1, 0.9), push=st.floats(-6.0, 6.0),
       pulse=st.floats(-12.0, 12.0), vx=st.floats(-1.0, 1.0), vy=st.floats(-0.5, 0.5))
def test_pucks_joined_by_a_bar_stay_in_their_disks(mu_a, mu_b, push, pulse, vx, vy):
    """Two spatial pucks joined by a bar along x, the first pushed by a two-piece schedule: the
    friction impulse of each puck within its disk at every step, compiled and Python loops."""
    q, v, u = ca.SX.sym("q", 6), ca.SX.sym("v", 6), ca.SX.sym("u", 1)
    pair = System(q, v, ca.SX.eye(6), ca.vertcat(u[0], 0, -9.81, 0, 0, -9.81), constraints=q[3] - q[0] - 1.0,
                  control=u, control_bounds=(-50, 50),
                  contacts=[Contact(gap=q[2], tangent=ca.vertcat(q[0], q[1]), mu=mu_a, name="a"),
                            Contact(gap=q[5], tangent=ca.vertcat(q[3], q[4]), mu=mu_b, name="b")])
    sched = ControlSchedule([0.0, 0.15, 0.4], [pulse, push])
    kw = dict(q0=[0.0, 0.0, 0.0, 1.0, 0.0, 0.0], v0=[vx, vy, 0.0, vx, vy, 0.0], control=sched)
    for fast in (True, False):
        res = lcp.simulate(pair, 0.4, h=1e-3, fast=fast, **kw)
        assert res.success, res.message
        assert _disk_excess(res, (mu_a, mu_b), (2, 2)) <= 1e-12


@settings(max_examples=12, deadline=None)
@given(mu_a=st.floats(0.1, 0.9), mu_b=st.floats(0.1, 0.9), force=st.floats(-8.0, 8.0), vx=st.floats(-1.0, 1.0))
def test_constant_bar_pair_stays_in_its_disks(mu_a, mu_b, force, vx):
    """The same pair under a constant push (a constant system with coupled spatial contacts: the
    compiled general loop) and with planar contacts (the constant compiled loop)."""
    q, v = ca.SX.sym("q", 6), ca.SX.sym("v", 6)
    spatial = System(q, v, ca.SX.eye(6), ca.vertcat(force, 0, -9.81, 0, 0, -9.81), constraints=q[3] - q[0] - 1.0,
                     contacts=[Contact(gap=q[2], tangent=ca.vertcat(q[0], q[1]), mu=mu_a),
                               Contact(gap=q[5], tangent=ca.vertcat(q[3], q[4]), mu=mu_b)])
    q4, v4 = ca.SX.sym("q", 4), ca.SX.sym("v", 4)
    planar = System(q4, v4, ca.SX.eye(4), ca.vertcat(force, -9.81, 0, -9.81), constraints=q4[2] - q4[0] - 1.0,
                    contacts=[Contact(gap=q4[1], tangent=q4[0], mu=mu_a), Contact(gap=q4[3], tangent=q4[2], mu=mu_b)])
    for system, q0, v0, dims in ((spatial, [0, 0, 0, 1.0, 0, 0], [vx, 0.2, 0, vx, 0.2, 0], (2, 2)),
                                 (planar, [0, 0, 1.0, 0], [vx, 0, vx, 0], (1, 1))):
        for fast in (True, False):
            res = lcp.simulate(system, 0.4, h=1e-3, q0=q0, v0=v0, fast=fast)
            assert res.success, res.message
            assert _disk_excess(res, (mu_a, mu_b), dims) <= 1e-12
