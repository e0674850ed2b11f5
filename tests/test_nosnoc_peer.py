"""The nosnoc peer (studies._nosnoc_peer): its optima against the closed forms, its controls replayed exactly.

Skipped when nosnoc (the optional ``ocp-peers`` extra) is not installed.
"""
import math

import numpy as np
import pytest

from studies import _nosnoc_peer as peer
from studies.optimal_control import (
    _scene_constants,
    hold_bound,
    min_effort_bound,
    min_time_bound,
)

needs_nosnoc = pytest.mark.skipif(not peer.available(), reason="nosnoc is not installed (extra 'ocp-peers')")

#: the replayed final state against nosnoc's: IPOPT's tolerance (comp_tol / 100) accumulated over
#: the stick phase, where nosnoc's Stewart sliding mode lets v drift by ~1e-9
MISS_TOL = 1e-7


def test_filippov_constants_match_the_scene():
    """c = R (m+M) g, D+- = A (1 -+ kappa) as the study's scene has them (no nosnoc needed)."""
    sc, _, D_plus, _ = _scene_constants(0.5)
    k = peer.scene_dynamics()
    assert k["c"] == pytest.approx(0.5 * 2 * 9.81, rel=1e-15)
    assert k["D_plus"] == pytest.approx(sc.A * (1 - sc.kappa), rel=1e-15) == D_plus
    assert k["D_minus"] == pytest.approx(2.0 * 1.25, rel=1e-15)


def test_bad_input_is_rejected():
    with pytest.raises(ValueError, match="problem"):
        peer.solve_nosnoc("shock", 10)
    with pytest.raises(ValueError, match="N"):
        peer.solve_nosnoc("min_time", 1)
    with pytest.raises(ValueError, match="result"):
        peer.replay_nosnoc(None)


@needs_nosnoc
def test_hold_needs_a_multiple_of_six():
    with pytest.raises(ValueError, match="multiple of 6"):
        peer.solve_nosnoc("hold", 10)


@needs_nosnoc
def test_infeasible_hold_is_reported():
    res = peer.solve_nosnoc("hold", 6)
    assert not res.success and res.ipopt_status == "Infeasible_Problem_Detected"


def _solve_and_replay(problem, N):
    res = peer.solve_nosnoc(problem, N)
    rp = peer.replay_nosnoc(res, samples=20)
    assert res.success, (res.status, res.ipopt_status, res.log)
    assert res.complementarity_residual < 1e-8
    assert rp.final_miss < MISS_TOL and rp.target_miss < MISS_TOL
    return res, rp


@needs_nosnoc
def test_min_time_is_above_the_bang_bang_optimum_and_converges():
    r1, _ = _solve_and_replay("min_time", 6)
    r2, _ = _solve_and_replay("min_time", 12)
    ref = min_time_bound()
    # a piecewise-constant control on equal stages cannot switch at the bang-bang instant: above T*
    assert ref < r2.objective < r1.objective
    assert r2.rel_gap < 0.5 * r1.rel_gap
    assert r1.T == pytest.approx(r1.objective, rel=1e-12)
    assert np.all(np.abs(r1.control.values) <= 20.0 + 1e-8)


@needs_nosnoc
def test_min_effort_converges_to_the_closed_form():
    r1, _ = _solve_and_replay("min_effort", 6)
    r2, _ = _solve_and_replay("min_effort", 12)
    ref = min_effort_bound()
    assert ref < r2.objective < r1.objective
    assert r2.rel_gap < 0.5 * r1.rel_gap
    # int u^2 dt of the replayed control, independently of the result's own sum
    sched = r2.control
    assert r2.objective == pytest.approx(float(np.sum(sched.values[:, 0] ** 2 * np.diff(sched.times))), rel=1e-12)
    assert r2.T == pytest.approx(1.0, abs=1e-9)


@needs_nosnoc
def test_hold_is_held_and_converges():
    # N = 6 is infeasible (two 0.2 s stages cannot move the block 0.3 m and stop it), which nosnoc reports
    r1, rp1 = _solve_and_replay("hold", 12)
    r2, rp2 = _solve_and_replay("hold", 24)
    ref = hold_bound()
    assert ref < r2.objective < r1.objective
    assert r2.rel_gap < 0.5 * r1.rel_gap
    for rp in (rp1, rp2):
        assert rp.hold_violation < MISS_TOL
    # on the hold the control keeps the block stuck: |u| <= c
    c = peer.scene_dynamics()["c"]
    t = r2.control.times
    on_hold = (t[:-1] >= 0.4 - 1e-9) & (t[1:] <= 0.6 + 1e-9)
    assert np.all(np.abs(r2.control.values[on_hold, 0]) <= c + 1e-6)
    assert math.isclose(r2.T, 1.2, abs_tol=1e-9)


def test_the_study_adds_nosnoc_series_replayed_exactly():
    if not peer.available():
        pytest.skip("nosnoc is not installed (extra 'ocp-peers')")
    from studies.optimal_control import NOSNOC, nosnoc_rows

    rows = nosnoc_rows((6,), (12,))
    assert [r["problem"] for r in rows] == ["min_time", "min_effort", "hold"]
    for r in rows:
        assert r["method"] == NOSNOC and r["success"]
        assert r["rel_gap"] > 0 and r["final_miss"] <= 1e-7
