"""A step that jumps over a singularity of the force is rejected, never a silent success.

A force 1e-3 / (x - 0.5) is a barrier the block cannot pass (its potential is infinite at 0.5).
Moreau-Jean used to step across it and end at x = 0.0035 (h = 1e-3) or 0.10 (h = 1e-2) with
success=True. Now the step whose forces miss their linearisation by more than half their size is
rejected: status -7, the coordinate and the time named. Smooth nonlinear forces pass.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import lcp
from lcp import Contact, System


def _block(force_x):
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    return System(q, v, ca.SX.eye(2), ca.vertcat(force_x(q[0], v[0]), -9.81),
                  contacts=[Contact(gap=q[1], tangent=q[0], mu=0.0)], names=("x", "y"))


@pytest.mark.parametrize("h", [1e-2, 1e-3, 1e-4])
def test_a_step_across_a_force_singularity_is_rejected(h):
    res = lcp.simulate(_block(lambda x, v: 1e-3 / (x - 0.5)), 1.0, q0=[1.0, 0.0], v0=[-1.0, 0.0], h=h)
    assert res.status == -7 and not res.success
    assert "force on x" in res.message and "reduce h" in res.message
    assert abs(res.t[-1] - 0.5) < 0.02  # stopped where the block reaches the barrier


@settings(deadline=None)
@given(k1=st.floats(0.0, 50.0), k3=st.floats(0.0, 200.0), w=st.floats(0.5, 8.0), c=st.floats(0.0, 2.0),
       h=st.sampled_from([1e-2, 3e-3, 1e-3]))
def test_smooth_nonlinear_forces_are_never_rejected(k1, k3, w, c, h):
    system = _block(lambda x, v: -k1 * x - k3 * x ** 3 + ca.sin(w * x) - c * v * ca.fabs(v))
    res = lcp.simulate(system, 1.0, q0=[0.8, 0.0], v0=[0.5, 0.0], h=h)
    assert res.success, res.message
    assert np.all(np.isfinite(res.q))
