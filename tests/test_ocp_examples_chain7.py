"""studies._ocp_models.block_chain7: nosnoc's seven friction blocks, its data, its nosnoc model and its feasibility.

Seven unit blocks, the first tied to a wall at x = 0 and each to the next by springs k = 5 N/m
(rest spacing 0.2 m), damping 0.1 N s/m on every velocity, friction 0.4 N on every block, the first
pushed by |u| <= 20 N; from rest 0.2 m beyond the equilibrium, a quadratic tracking cost over
T = 5 s, positions within [-2, 3.2] m and speeds within 10 m/s, no terminal constraint.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import lcp
from lcp.model.control import ControlSchedule
from studies import _nosnoc_examples as peers
from studies._ocp_models import CHAIN7, EXAMPLES

K = CHAIN7["K"]
X_EQ = CHAIN7["spacing"] * np.arange(K)


def force(ex, q, v, u):
    s = ex.system
    f = ca.Function("F", [s.t_sym, s.q_sym, s.v_sym, s.control_sym],
                    [s.force_expr + ca.mtimes(s.control_matrix_expr, s.control_sym)])
    return np.array(f(0.0, q, v, [u])).ravel()


def test_chain7_statics_and_friction():
    ex = EXAMPLES["block_chain7"]()
    assert ex.system.n == 2 * K and ex.system.n_contacts == K
    assert np.allclose(ex.q0[0::2], X_EQ + CHAIN7["shift"]) and not np.any(ex.v0)
    q = np.zeros(2 * K)
    q[0::2] = X_EQ
    f = force(ex, q, np.zeros(2 * K), 0.0)
    # at the equilibrium every spring is at rest: no horizontal force; each block pressed so that mu N = 0.4 N
    np.testing.assert_allclose(f[0::2], 0.0, atol=1e-14)
    mu = np.array([c.mu for c in ex.system.contacts])
    np.testing.assert_allclose(-f[1::2] * mu, CHAIN7["mu_fric"], rtol=1e-15)
    # at the start only the wall spring pulls (every block shifted alike): -k * shift on the first block
    f0 = force(ex, ex.q0, np.zeros(2 * K), 0.0)
    np.testing.assert_allclose(f0[0::2], [-CHAIN7["k"] * CHAIN7["shift"]] + [0.0] * (K - 1), atol=1e-14)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2 ** 31 - 1), st.sampled_from([1.0, -1.0]))
def test_chain7_nosnoc_model_is_the_examples(seed, sign):
    # nosnoc's Stewart form (studies._nosnoc_examples._chain7) against the System: every block
    # sliding in direction `sign` (friction 0.4 N against it), the same accelerations
    if not peers.available():
        pytest.skip("nosnoc (optional peer) not installed")
    import nosnoc as ns

    ex = EXAMPLES["block_chain7"]()
    model = peers._chain7(ns, ca, 4)[0]
    rng = np.random.default_rng(seed)
    x = np.concatenate([X_EQ + rng.uniform(-0.5, 0.5, K), sign * rng.uniform(0.01, 2.0, K)])
    u = rng.uniform(-CHAIN7["u_max"], CHAIN7["u_max"])
    col = 0 if sign > 0 else 1  # nosnoc's region: c = v_i > 0 is the first column of S = [1; -1]
    xdot = sum(np.array(ca.Function("f", [model.x, model.u], [F[:, col]])(x, u)).ravel() for F in model.F)
    q, v = np.zeros(2 * K), np.zeros(2 * K)
    q[0::2], v[0::2] = x[:K], x[K:]
    acc = force(ex, q, v, u)[0::2] - sign * CHAIN7["mu_fric"]
    np.testing.assert_allclose(xdot[K:], acc, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(xdot[:K], x[K:])
    np.testing.assert_array_equal(np.asarray(model.x0, dtype=float), ex.common_state(ex.q0, ex.v0))


def test_chain7_costs_agree_with_the_scoring():
    ex = EXAMPLES["block_chain7"]()
    ocp = ex.make(5)
    e0 = 10 * K * CHAIN7["shift"] ** 2  # every block 0.2 m off, at rest
    assert ex.integrand(np.zeros(1), ex.q0[None], ex.v0[None], np.zeros((1, 1)))[0] == pytest.approx(e0, rel=1e-14)
    assert ex.terminal(ex.q0, ex.v0) == pytest.approx(CHAIN7["P"] * e0, rel=1e-14)
    assert ex.terminal(np.concatenate([[x, 0.0] for x in X_EQ]), ex.v0) == 0.0
    # the transcription's stage cost over a step held at the start with u = 3: the integrand exactly
    from lcp.ocp.results import Step

    z = ca.DM.zeros(K, 1)
    step = Step(k=0, t0=0.0, t1=0.1, h=0.1, q0=ca.DM(ex.q0), q1=ca.DM(ex.q0), v0=ca.DM(ex.v0), v1=ca.DM(ex.v0),
                u0=ca.DM([3.0]), u1=ca.DM([3.0]), p_N=z, p_T=z)
    got = float(ocp.stage_cost(step))
    assert got == pytest.approx(ex.integrand(np.zeros(1), ex.q0[None], ex.v0[None], np.array([[3.0]]))[0], rel=1e-14)


def test_chain7_is_feasible_without_a_push():
    """No terminal constraint: any admissible control whose motion keeps the state box is feasible.
    u = 0 does (the wall spring brings the first block back and the chain stops, stuck), so the
    problem is feasible and its value is at most the cost of u = 0."""
    ex = EXAMPLES["block_chain7"]()
    T = CHAIN7["T"]
    sim = lcp.simulate(ex.system, T, method="event", control=ControlSchedule([0.0, T], np.zeros((1, 1))),
                       q0=ex.q0, v0=ex.v0)
    assert sim.success
    x, v = sim.q[:, 0::2], sim.v[:, 0::2]
    assert np.all(x >= -CHAIN7["q_box"]) and np.all(x <= X_EQ[-1] + CHAIN7["q_box"])
    assert np.all(np.abs(v) <= CHAIN7["v_max"])
    # every block stays or returns to rest short of the equilibrium: friction holds it (|k stretch| <= 0.4)
    assert np.all(np.abs(v[-1]) < 1e-12)
    assert np.all(x[-1] - X_EQ > 0)


@pytest.mark.slow
def test_chain7_is_solved_from_the_defaults_at_or_below_nosnoc():
    """At nosnoc's N = 50: a success (the replay within 1e-6), cheaper than doing nothing, and where
    nosnoc runs, at or below its objective and its J_replay (the cost of its control on the fine replay)."""
    from studies import ocp_examples as study

    ex = EXAMPLES["block_chain7"]()
    N, T = CHAIN7["N"], CHAIN7["T"]
    row, res = study._ours(ex, N)
    assert row["ours_success"] and row["ours_method"] == "event" and row["ours_miss"] <= study.REPLAY_TOL
    assert np.all(np.abs(res.u) <= CHAIN7["u_max"] + 1e-9)
    idle = study.score(ex, ControlSchedule(np.linspace(0.0, T, N + 1), np.zeros((N, 1))), N)
    assert row["ours_J_replay"] < idle
    # the transcription's trapezoid against the fine replay's quadrature: the same cost to 0.1 %
    assert row["ours_cost"] == pytest.approx(row["ours_J_replay"], rel=1e-3)
    if peers.available():
        nos, _ = study._nosnoc(ex, N)
        assert nos["nosnoc_status"].startswith("SUCCESS")
        assert row["ours_cost"] <= nos["nosnoc_objective"]
        assert row["ours_J_replay"] <= nos["nosnoc_J_replay"]
