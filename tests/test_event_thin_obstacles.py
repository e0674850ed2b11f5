"""The event method finds impacts that an ODE step would carry through a thin obstacle.

Two discs (radius 0.1 each, unit masses, frictionless, inelastic) fly at each other. In free flight
the ODE steps are long (the dynamics are trivial to integrate), and the gap between the discs is
positive at both ends of the step that carries them through each other: the event functions,
evaluated at step ends, saw no impact and the discs passed through (minimum gap -0.2, status 0).
"""
import casadi as ca
import numpy as np
import pytest

import lcp


def _discs(drag=0.0, e=0.0):
    q, v = ca.SX.sym("q", 4), ca.SX.sym("v", 4)
    d = q[0:2] - q[2:4]
    dist = ca.norm_2(d)
    n = d / dist
    c = lcp.Contact(gap=dist - 0.2, tangent_jacobian=ca.horzcat(-n[1], n[0], n[1], -n[0]), mu=0.0, e=e, name="discs")
    return lcp.System(q, v, ca.SX.eye(4), -drag * v, contacts=[c])


@pytest.mark.parametrize("drag", [0.0, 1.0])
@pytest.mark.parametrize("v0", [[-10.0, 0.0, 0.0, 0.0], [-10.0, 0.05, 0.0, 0.0], [-30.0, 0.3, 5.0, 0.0]])
def test_discs_flying_head_on_collide(drag, v0):
    sys = _discs(drag)
    sim = lcp.simulate(sys, 2.0, method="event", q0=[1.0, 0.0, -1.0, 0.0], v0=v0, n_eval=4001)
    assert sim.success
    assert len(sim.impacts) >= 1
    gaps = np.array([sys.gaps(q)[0] for q in sim.q])
    assert gaps.min() >= -1e-9
    # momentum is conserved through the (frictionless, internal) impact
    p0 = np.array(v0[0:2]) + np.array(v0[2:4])
    if drag == 0.0:
        assert np.allclose(sim.v[-1, 0:2] + sim.v[-1, 2:4], p0, atol=1e-9)


def test_head_on_impact_time_is_exact():
    """Head-on at relative speed 10 from centre distance 2: contact at distance 0.2, t = 1.8 / 10;
    inelastic with equal masses, both move at the mean velocity after it."""
    sys = _discs()
    sim = lcp.simulate(sys, 0.5, method="event", q0=[1.0, 0.0, -1.0, 0.0], v0=[-10.0, 0.0, 0.0, 0.0])
    assert sim.impacts[0].t == pytest.approx(0.18, abs=1e-12)
    assert sim.v[-1, 0] == pytest.approx(-5.0, abs=1e-9) and sim.v[-1, 2] == pytest.approx(-5.0, abs=1e-9)
