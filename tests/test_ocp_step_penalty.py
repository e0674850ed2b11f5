"""The step penalty of free steps (lcp.ocp.complementarity.step_penalty): its value, that the cost
reported is the problem's own, and the Jean-Pratt minimum time off the default friction geometry.

On free steps the split of a phase into steps is not unique; IPOPT sees a small penalty on uneven
steps, STEP_REGULARIZATION T mean (h / (T / N) - 1)^2, which must never enter the cost reported.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lcp.ocp import OptimalControlProblem
from lcp.ocp.complementarity import STEP_REGULARIZATION, step_penalty
from lcp.ocp.transcription import Transcription
from studies import optimal_control as so


def _min_time(N, R=0.5, **kw):
    sc, system = so.controlled_block(R=R)
    return OptimalControlProblem(system, N, q0=sc.q0, v0=sc.v0, T=0.5, free_time=True, T_bounds=(0.05, 5.0),
                                 terminal_cost=lambda T, q, v: T,
                                 terminal_constraints=lambda q, v: ca.vertcat(q[0] - so.REST["d"], v[0]), **kw)


@settings(max_examples=20, deadline=None)
@given(st.lists(st.floats(0.05, 4.0), min_size=6, max_size=6))
def test_the_penalty_is_the_mean_square_of_the_relative_steps(rel):
    pb = _min_time(6, steps="free")
    tr = Transcription(pb)
    fn = step_penalty(tr, {})
    x = np.random.default_rng(0).uniform(0.0, 1.0, tr.nlp["x"].numel())
    T = float(x[int(np.ravel(tr.ix["T"])[0])])  # free T: the variable's
    x[tr.ix["h"].ravel()] = np.asarray(rel) * T / pb.N
    want = STEP_REGULARIZATION * T * np.mean((np.asarray(rel) - 1.0) ** 2)
    assert float(fn(x)) == pytest.approx(want, rel=1e-12, abs=1e-300)


def test_no_penalty_on_uniform_steps():
    tr = Transcription(_min_time(6, steps="uniform"))
    assert step_penalty(tr, {}) is None


@pytest.mark.parametrize("method", ["homotopy", "phases"])
def test_the_cost_reported_is_the_problems_own(method):
    # minimum time: the cost is T itself, so any trace of the penalty (uneven free steps) would show
    r = _min_time(8, steps="free", hold="constant").solve(method=method)
    assert r.success, r.message
    # uneven steps (the bang-bang's two arcs): the penalty is far from zero there
    pen = STEP_REGULARIZATION * r.T * np.mean((r.steps / (r.T / 8) - 1.0) ** 2)
    assert pen > 1e-6 * 1e-6 * r.T
    assert r.cost == pytest.approx(r.T, rel=1e-14, abs=0.0)
    assert all(s.cost > 0 for s in r.homotopy if np.isfinite(s.cost))
    assert abs(r.T - so.min_time_bound()) <= 1e-6 * so.min_time_bound()


@pytest.mark.slow
@pytest.mark.parametrize("R", [0.3, 0.7])
def test_min_time_off_the_default_geometry_at_N40(R):
    # every default (free steps, affine hold); without the penalty R = 0.3 ended 1.4e-4 above T*
    # (a homotopy stage on free steps infeasible, the shooting finishing a worse phase sequence)
    # and R = 0.7 4.8e-7 above
    r = _min_time(40, R=R).solve()
    assert (r.problem.hold, r.problem.steps) == ("affine", "free")
    assert r.success, r.message
    ref = so.min_time_bound(R=R)
    assert abs(r.T - ref) <= 1e-6 * ref, (r.T, ref, r.message)
    assert r.replay.final_miss <= 1e-8
    assert np.max(np.abs(r.q[:, 1])) <= 1e-9
