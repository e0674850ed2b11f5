"""The stability study in quick mode: no silently wrong cell, failures reported."""
import csv

import pytest

from studies import stability

# the whole quick run takes 15-50 s; tests/test_studies_pieces.py runs a few of its pieces by default
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = tmp_path_factory.mktemp("stability")
    return stability.run(out=out, quick=True), out


def test_no_silently_wrong_cell(result):
    res, _ = result
    wrong = [(r.case, r.method, r.reason) for r in res["rows"] if r.outcome == "silently wrong"]
    assert not wrong
    assert res["counts"]["correct"] > 100


def test_failures_are_reported_with_step_and_cause(result):
    res, _ = result
    rep = {(r.case, r.method): r for r in res["rows"] if r.outcome == "reported failure"}
    osqp = rep[("OSQP capped at 1 ADMM iteration, no fallback", "MJ osqp")]
    assert osqp.status == -1 and "Step 0" in osqp.message and "OSQP status" in osqp.message
    assert all("alpha" in r.reason for (case, _), r in rep.items() if case.startswith("alpha = pi/2"))


def test_checks_are_measured(result):
    res, out = result
    rows = [r for r in res["rows"] if r.outcome == "correct" and r.method != stability.LEM_METHOD]
    assert all(r.residual <= 1e-9 * 1e13 for r in rows)  # event residuals are in force units
    lem = {r.case: r for r in res["rows"] if r.method == stability.LEM_METHOD and r.outcome != "not applicable"}
    assert lem["y'' = tanh y, x = 2, N = 61, no restart"].status == -1  # divergence is flagged
    restarted = lem["y'' = tanh y, x = 2, N = 61, restarted"]
    assert restarted.outcome == "correct" and restarted.x_error <= 1e-10
    default = [r for r in rows if r.case == "h = 0.001" and r.method == "MJ compiled"][0]
    assert default.x_error <= default.x_tol and default.max_gap <= 1e-12 and default.energy_rise <= 0
    with open(out / "stability.csv") as fh:
        assert len(list(csv.DictReader(fh))) == len(res["rows"])
    assert (out / "stability.png").stat().st_size > 0
