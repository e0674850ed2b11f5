"""Mass ratios beyond double precision are reported, never a silent success.

The Jean-Pratt block at m/M = 1e-12 (one coupled block of the mass matrix, condition number
2 M / m): Moreau-Jean returned success=True with x 0.34 m off and the block moving at 93 m/s
while marked stuck; at 1e-11, 2.5e-3 m off with no note. Independent bodies of very different
masses are separate blocks, each well conditioned, and stay exact (tests/test_contact_scales.py).
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import lcp
from lcp import Contact, System
from lcp.model.conditioning import block_condition, mass_condition


@pytest.mark.parametrize("ratio", [1e-9, 1e-11, 1e-12])
@pytest.mark.parametrize("fast", [True, False])
def test_moreau_jean_reports_an_unresolvable_mass_ratio(ratio, fast):
    sc = lcp.scenes.jean_pratt(m=ratio, M=1.0)
    res = lcp.simulate(sc, 1.0, h=1e-3, fast=fast)
    assert res.status == -6 and not res.success
    assert "condition number" in res.message and f"{2 / ratio:.3g}"[:3] in res.message


def test_the_event_method_reports_it_past_its_own_limit():
    sc = lcp.scenes.jean_pratt(m=1e-12, M=1.0)
    for scene_or_system in (sc, sc.system):
        kw = {} if scene_or_system is sc else dict(q0=sc.q0, v0=sc.v0)
        res = lcp.simulate(scene_or_system, 1.0, method="event", **kw)
        assert res.status == -6 and "condition number" in res.message
    # at 1e-9 the event method is still right (its phases use accelerations, not 1/m impulses)
    sc = lcp.scenes.jean_pratt(m=1e-9, M=1.0)
    res = lcp.simulate(sc, 1.0, method="event", t_eval=np.linspace(0, 1, 11))
    assert res.success
    assert np.max(np.abs(res.q[:, 0] - sc.exact(res.t)["x"])) < 1e-8


@settings(max_examples=15, deadline=None)
@given(log_ratio=st.floats(-6.0, 0.0), R=st.floats(0.05, 0.9))
def test_resolvable_ratios_stay_successes_and_exact(log_ratio, R):
    sc = lcp.scenes.jean_pratt(m=10.0 ** log_ratio, M=1.0, R=R)
    res = lcp.simulate(sc, 0.5, h=1e-3)
    assert res.success, res.message


def test_independent_bodies_are_judged_block_by_block():
    q, v = ca.SX.sym("q", 5), ca.SX.sym("v", 5)
    contacts = [Contact(gap=q[1] - 0.5 * q[2], tangent=q[0], mu=0.3),
                Contact(gap=q[1] + 0.5 * q[2], tangent=q[0], mu=0.3),
                Contact(gap=q[4], tangent=q[3], mu=0.3)]
    s = System(q, v, mass=ca.diag(ca.vertcat(1, 1, 0.1, 1e12, 1e12)),
               force=ca.vertcat(0, -9.81, 0, 0, -9.81e12), contacts=contacts)
    assert mass_condition(s, np.zeros(5)) == 1.0  # five independent coordinates
    res = lcp.simulate(s, 0.2, h=1e-3, q0=[0] * 5, v0=[1.0, -2.0, 3.0, 0.5, 0.0])
    assert res.success, res.message


def test_block_condition_splits_independent_blocks():
    A = np.zeros((4, 4))
    A[:2, :2] = [[2.0, -1.0], [-1.0, 2.0]]
    A[2:, 2:] = np.diag([1e-9, 1e9])  # two more independent (1 x 1) bodies
    assert block_condition(A) == pytest.approx(3.0)
    A[2, 3] = A[3, 2] = 1e-3  # now coupled: one block with the light and the heavy coordinates
    assert block_condition(A) > 1e17
