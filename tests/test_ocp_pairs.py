"""User complementarity path constraints (lcp.ocp.pairs): OptimalControlProblem(..., complementarity=...)."""
import casadi as ca
import numpy as np
import pytest

import lcp
from lcp.ocp import OptimalControlProblem, effort, tangential_push


def _kw():
    sc = lcp.scenes.jean_pratt(v0=0.0)
    return sc, {"control_matrix": tangential_push(sc.system), "u_min": -20, "u_max": 20, "T": 1.0,
                "stage_cost": effort, "terminal_constraints": lambda q, v: ca.vertcat(q[0] - 0.5, v[0]),
                "hold": "constant", "steps": "uniform"}


def test_pair_window_equals_the_equalities_it_implies():
    """0 <= x perp max(0.5 - t0, 0) >= 0 holds the block at x = 0 at the end of every step that starts
    before t = 0.5: the same NLP optimum as the path equalities x_{k+1} = 0 for k < N/2."""
    sc, kw = _kw()
    N = 20
    eq = OptimalControlProblem(sc, N, path_equalities=lambda s: s.q1[0] if s.k < N // 2 else ca.SX.zeros(0, 1),
                               **kw).solve()
    pr = OptimalControlProblem(sc, N, complementarity=[(lambda s: s.q1[0], lambda s: ca.fmax(0.5 - s.t0, 0))],
                               **kw).solve()
    assert eq.success and pr.success
    assert abs(pr.cost - eq.cost) <= 1e-8 * eq.cost
    assert np.max(np.abs(pr.q[1:N // 2 + 1, 0])) <= 1e-8
    assert pr.replay.final_miss <= 1e-9 and pr.replay.path_violation <= 1e-9
    assert pr.cost > 100.0  # the unconstrained optimum (86.9) moves earlier: the pair binds


def test_pair_violation_on_replay_is_measured():
    from lcp.ocp.pairs import pair_violation
    from lcp.ocp.results import Step

    st = Step(0, 0.0, 0.1, 0.1, np.zeros(2), np.array([0.2, 0.0]), np.zeros(2), np.zeros(2), np.zeros(1),
              np.zeros(1), np.zeros(1), np.zeros(1))
    assert pair_violation([(lambda s: s.q1[0], lambda s: 0.5 - s.t0)], st) == pytest.approx(0.2)
    assert pair_violation([(lambda s: s.q1[1], lambda s: -1.0 + 0 * s.t0)], st) == pytest.approx(1.0)


@pytest.mark.parametrize("bad", [3, [(1.0, 2.0)], [(lambda s: s.q1[0],)]])
def test_bad_pairs_are_refused_by_name(bad):
    sc, kw = _kw()
    with pytest.raises(ValueError, match="complementarity"):
        OptimalControlProblem(sc, 4, complementarity=bad, **kw)


def test_pairs_of_changing_length_are_refused():
    sc, kw = _kw()
    ocp = OptimalControlProblem(sc, 4, complementarity=[(lambda s: s.q1[:1 + (s.k > 0)],
                                                         lambda s: s.v1[:1 + (s.k > 0)])], **kw)
    with pytest.raises(ValueError, match="same length at every step"):
        ocp.solve()
