"""studies.optimal_control in quick mode: the numbers behind its figures."""
import numpy as np
import pytest

from studies import optimal_control as study


@pytest.fixture(scope="module")
def out(tmp_path_factory):
    return study.run(out=tmp_path_factory.mktemp("optimal_control"), quick=True)


def _rows(out, problem):
    rr = [r for r in out["rows"] if r["problem"] == problem]
    return sorted(rr, key=lambda r: r["N"])


def test_references():
    assert study.min_time_bound() == pytest.approx(0.4444342756, rel=1e-9)
    # effort optimum 4/3 c^2 L*, u from 2c down to 0 over L* = 0.6773 s
    assert study.min_effort_bound() == pytest.approx(86.9057, rel=1e-5)
    assert study.peak_bound() == pytest.approx(2 * 9.81 + 5.0, rel=1e-12)
    with pytest.raises(ValueError):
        study.min_effort_bound(T=0.5)  # the free slide would not fit


def test_files(out):
    names = {f.name for f in out["files"]}
    for name in ("rest_to_rest.png", "shock_avoidance.png", "convergence.png", "shock_sweep.png",
                 "convergence.csv", "shock_sweep.csv", "trajectory_min_time.csv", "homotopy_shock.csv"):
        assert name in names
    for f in out["files"]:
        assert f.exists() and f.stat().st_size > 0


def test_every_solve_meets_the_residual_target(out):
    for r in out["rows"]:
        assert r["success"], r
        assert r["residual"] <= 1e-8 and r["lcp_residual"] <= 1e-8
        assert r["dynamics_residual"] <= 1e-10
        # replayed at the optimizer's own step, Moreau-Jean repeats its trajectory
        assert r["err_same_h"] <= 1e-10


def test_optimal_values_against_references(out):
    for r in _rows(out, "min_time"):
        assert 0 <= r["rel_gap"] <= 0.1 / r["N"]
    for r in _rows(out, "min_effort"):
        assert 0 <= r["rel_gap"] <= 1.0 / r["N"]
    for r in _rows(out, "shock"):
        assert abs(r["rel_gap"]) <= 1e-8
        assert r["peak_N_opt"] <= r["reference"] * (1 + 1e-8)


def test_replay_mismatch_converges(out):
    for prob in ("min_time", "min_effort", "shock"):
        err = [r["err_mj"] for r in _rows(out, prob)]
        assert err[0] > err[1] > err[2], (prob, err)
        assert err[0] / err[2] > 8, (prob, err)  # at least first order over a factor 4 in N
    # event-driven replay, when available, at the figure's N, agrees with Moreau-Jean's fine replay
    if out["event_available"]:
        for r in out["rows"]:
            if r["N"] == out["N_figure"]:
                assert r["err_event"] == pytest.approx(r["err_mj"], rel=0.2, abs=1e-8)


def test_rest_to_rest_under_one_second(out):
    # generous: the benchmark measures it properly; this catches a tenfold regression
    assert min(r["solve_time"] for r in _rows(out, "min_time")) < 2.0


def test_shock_sweep(out):
    sw = out["sweep"]
    assert [round(r["kappa"], 2) for r in sw] == [0.9, 0.95, 0.99]
    for r in sw:
        assert r["residual"] <= 1e-8
        assert r["peak_opt"] == pytest.approx(r["bound"], rel=1e-8)
        assert r["peak_replay"] <= r["bound"] * 1.01
        assert r["peak_uncontrolled"] == pytest.approx(r["N0"], rel=0.02)
    assert sw[-1]["peak_uncontrolled"] / sw[-1]["peak_opt"] > 75
    # the control pushes forward, just below the friction force: further below as kappa drops
    u = [r["u_mean"] for r in sw]
    assert np.all(np.array(u) > 30)
