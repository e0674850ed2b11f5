"""A force that is not finite is named as the cause, in both methods (before: Moreau-Jean blamed a
singular mass matrix, the event method said "M and q must be finite")."""
from __future__ import annotations

import casadi as ca
import pytest

import lcp
from lcp import Contact, System


def _sqrt_force_system():
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    return System(q, v, ca.SX.eye(2), ca.vertcat(-ca.sqrt(q[0]), -9.81),
                  contacts=[Contact(gap=q[1], tangent=q[0], mu=0.0)], names=("x", "y"))


@pytest.mark.parametrize("method", ["moreau-jean", "event"])
def test_a_force_that_turns_nan_mid_run_is_named(method):
    # x decreases through 0, where sqrt(x) stops being real
    res = lcp.simulate(_sqrt_force_system(), 3.0, q0=[0.5, 0.0], v0=[-1.0, 0.0], method=method)
    assert res.status == -2 and not res.success
    assert "force F(t, q, v) is not finite" in res.message and "'x'" in res.message
    assert "mass matrix" not in res.message
    # said where it happened: x reaches 0 at t = 0.4436 (Moreau-Jean's last state is just before)
    assert "t = 0.44" in res.message
    if method == "moreau-jean":
        assert 0.43 < res.t[-1] < 0.445


def test_moreau_jean_names_the_force_at_the_start():
    res = lcp.simulate(_sqrt_force_system(), 1.0, q0=[-1.0, 0.0], v0=[0.0, 0.0])
    assert res.status == -2 and "Step 0" in res.message and "force F(t, q, v) is not finite" in res.message


def test_the_event_method_refuses_a_start_where_the_force_is_not_finite():
    with pytest.raises(ValueError, match=r"initial state.*force F\(t, q, v\) is not finite.*'x'"):
        lcp.simulate(_sqrt_force_system(), 1.0, q0=[-1.0, 0.0], v0=[0.0, 0.0], method="event")
