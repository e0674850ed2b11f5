"""Moreau-Jean's activation rule: a closed, loaded contact is never dropped by rounding; a genuine
lift-off still happens, at most one step late; a pushed box on two corners does not chatter."""
import casadi as ca
import numpy as np
import pytest

import lcp
from lcp.classical import box_on_corners, stacked_blocks
from lcp.scenes import block_chain
from lcp.model.system import Contact, System
from lcp.timestepping.activation import CLOSE_ULPS, Activation
from lcp.timestepping.moreau_jean import MoreauJeanOptions, moreau_jean

EPS = np.finfo(float).eps
HS = [1e-2, 1e-3, 1e-4, 1e-5, 1e-6]


def _check_stack_at_rest(sc, res):
    """Every contact active and loaded in every step, the exact weights carried, no penetration
    beyond the rounding of the gaps, and none that grows."""
    assert res.success, res.message
    assert not np.any(res.modes == lcp.contact.problem.ContactMode.INACTIVE)
    np.testing.assert_allclose(res.p_N / res.h, np.broadcast_to(sc.exact(0.0)["N"][0], res.p_N.shape), rtol=1e-9)
    gaps = np.array([sc.system.gaps(q) for q in res.q])
    size = sc.params["height"] * sc.params["K"]
    assert gaps.min() >= -8 * EPS * size
    half = gaps.shape[0] // 2
    assert gaps[half:].min() >= gaps[:half].min() - 8 * EPS * size  # penetration does not grow
    assert np.max(np.abs(res.v)) <= 1e-12


@pytest.mark.parametrize("K", [2, 3, 5, 10])
@pytest.mark.parametrize("h", HS)
@pytest.mark.parametrize("height", [0.1, 0.1 * (1 + 1 / 3)])
def test_stack_at_rest_keeps_every_contact(K, h, height):
    # heights that are not binary fractions: gaps like 0.3 - 0.2 - 0.1 round to +2.8e-17, which the
    # plain test "predicted gap <= 0" took for an open contact (the block above then sank g h^2)
    sc = stacked_blocks(K, height=height)
    res = lcp.simulate(sc, 300 * h, h=h)
    _check_stack_at_rest(sc, res)
    assert res.max_constraint_violation <= 8 * EPS * height * K


@pytest.mark.slow
@pytest.mark.parametrize("K", [2, 5, 10])
@pytest.mark.parametrize("h", [1e-2, 1e-4, 1e-6])
def test_stack_at_rest_1e5_steps(K, h):
    sc = stacked_blocks(K, height=0.1)
    res = lcp.simulate(sc, 1e5 * h, h=h, save_every=100)
    assert res.stats.steps == 100_000
    _check_stack_at_rest(sc, res)
    assert res.stats.free_steps == 0


@pytest.mark.parametrize("h", HS)
def test_chain_on_a_raised_floor_keeps_every_contact(h):
    # floor at y = 0.3, blocks at y = 0.1 + 0.2 = 0.30000000000000004: gap +5.6e-17 at rest
    K = 4
    q, v = ca.SX.sym("q", 2 * K), ca.SX.sym("v", 2 * K)
    F = [0.0] * (2 * K)
    for i in range(K):
        F[2 * i + 1] = -9.81
    for i in range(K - 1):
        tension = 50.0 * (q[2 * i + 2] - q[2 * i] - 1.0)
        F[2 * i] = F[2 * i] + tension
        F[2 * i + 2] = F[2 * i + 2] - tension
    contacts = [Contact(gap=q[2 * i + 1] - 0.3, tangent=q[2 * i], mu=0.4, name=f"b{i}") for i in range(K)]
    s = System(q, v, ca.SX.eye(2 * K), ca.vertcat(*F), contacts=contacts)
    q0 = np.zeros(2 * K)
    q0[0::2] = np.arange(K)
    q0[1::2] = 0.1 + 0.2
    res = lcp.simulate(s, 300 * h, h=h, q0=q0, v0=np.zeros(2 * K))
    assert res.success and not np.any(res.modes == -1)
    np.testing.assert_allclose(res.N, 9.81, rtol=1e-9)
    assert np.max(np.abs(res.q - q0)) <= 1e-15


def test_activation_rule_tolerates_rounding_only():
    sc = block_chain(1)
    asm = lcp.timestepping.assembly.StepAssembly(sc.system, 1e-3, 0.5)
    act = Activation(asm, 1)
    q = np.array([0.0, 0.0])
    H = asm.H
    zero = np.zeros(1)
    assert act(q, np.array([0.0]), H, zero, zero, 1e-3, 0.5).size == 1  # exactly closed, at rest
    # a rounding residue of a gap built from q ~ 1 closes (the stacked blocks' +2.8e-17)
    q1 = np.array([0.0, 1.0])
    assert act(q1, np.array([0.5 * CLOSE_ULPS * EPS]), H, zero, zero, 1e-3, 0.5).size == 1
    # a gap of 1e-12 with nothing closing it is open: the tolerance is rounding-sized, not physical
    assert act(q, np.array([1e-12]), H, zero, zero, 1e-3, 0.5).size == 0
    # a loaded contact: a rounding residue does not open it, a gap beyond the opening threshold does
    act.loaded[0] = True
    assert act(q1, np.array([1e3 * EPS]), H, zero, zero, 1e-3, 0.5).size == 1
    assert act(q1, np.array([1e-9]), H, zero, zero, 1e-3, 0.5).size == 0


@pytest.mark.parametrize("h", [1e-3, 1e-4])
def test_lift_off_under_a_growing_upward_force_is_on_time(h):
    # block on a floor pulled up by c t: loaded until t* = m g / c, then y = c (t - t*)^3 / (6 m)
    m, g, c = 1.0, 9.81, 20.0
    q, v, t = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("t")
    s = System(q, v, m * ca.SX.eye(2), ca.vertcat(0, -m * g + c * t), t=t,
               contacts=[Contact(gap=q[1], tangent=q[0], mu=0.5)])
    t_star = m * g / c
    res = lcp.simulate(s, 0.8, h=h, q0=[0, 0], v0=[0, 0])
    assert res.success
    loaded = res.p_N[:, 0] > 0
    last_loaded = res.t[np.flatnonzero(loaded)[-1]]
    assert t_star - 2 * h <= last_loaded <= t_star + h
    late = res.t > t_star + 2 * h
    exact = c * (res.t[late] - t_star) ** 3 / (6 * m)
    assert np.max(np.abs(res.q[late, 1] - exact)) <= 2 * c * 0.8 ** 2 * h  # O(h): a kink at t*
    assert np.all(res.modes[res.t[:-1] > t_star + 2 * h, 0] == -1)


def test_pushed_box_does_not_chatter_before_it_tips():
    # the free motion lifts the back corner long before the box tips; the rule must keep it
    sc = box_on_corners(mu=1.2, push_height=0.45, t_end=2.3)
    t_tip = sc.solution.t_tip
    res = lcp.simulate(sc, h=1e-3)
    assert res.success, res.message
    assert res.impacts == []
    before = res.t[:-1] < t_tip - 2e-3
    assert np.all(res.modes[before] == lcp.contact.problem.STICK)
    assert np.all(res.p_N[before] > 0)


def test_options_validate_projection():
    with pytest.raises(ValueError, match="projection must be"):
        MoreauJeanOptions(h=1e-3, projection="yes")
    with pytest.raises(ValueError, match="projection_tol"):
        MoreauJeanOptions(h=1e-3, projection_tol=0.0)
    with pytest.raises(ValueError, match="projection_tol"):
        lcp.simulate(block_chain(1), 0.1, h=1e-3, projection_tol=float("nan"))
    sc = block_chain(1)
    res = moreau_jean(sc.system, sc.q0, sc.v0, 0.01, MoreauJeanOptions(h=1e-3, projection=True))
    assert res.success and res.stats.projections == res.stats.steps
