"""studies.lem_convergence in quick mode: the numbers behind its figures."""
import csv
import math

import pytest

from lem.troesch import TROESCH_REFERENCE
from studies import lem_convergence


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    out = tmp_path_factory.mktemp("lem_convergence")
    return lem_convergence.run(out=out, quick=True), out


def test_files_written(study):
    res, out = study
    names = {p.name for p in res["files"]}
    assert {"error_vs_degree.csv", "error_vs_degree.png", "cost_vs_degree.csv", "cost_vs_degree.png",
            "coefficients_3_20.csv", "series_3_20.png", "smooth_friction_coefficients.csv",
            "smooth_friction.png", "troesch.csv", "troesch.png"} <= names
    for p in res["files"]:
        assert (out / p.name).stat().st_size > 0
    rows = list(csv.DictReader((out / "error_vs_degree.csv").open()))
    assert len(rows) == len(res["error_vs_degree"])
    assert float(rows[0]["plain_error_y"]) == res["error_vs_degree"][0]["plain_error_y"]


def test_x1_geometric_to_1e10_by_N61(study):
    c = study[0]["checks"]
    assert c["x1_error_N61"] <= 1e-10
    assert c["x1_estimate_N61"] >= c["x1_error_N61"]
    errs = dict(c["x1_errors"])
    # geometric: each 10 degrees gain more than a decade, at a steady rate
    seq = [errs[N] for N in (11, 21, 31, 41, 51, 61)]
    ratios = [b / a for a, b in zip(seq, seq[1:])]
    assert all(r < 0.1 for r in ratios)
    assert max(ratios) / min(ratios) < 3.0


def test_x2_plain_flags_restarted_within_1e10(study):
    res, _ = study
    c = res["checks"]
    assert c["x2_plain_diverging_N61"] and c["x2_plain_status_N61"] == -1
    assert c["x2_restart_error_N61"] <= 1e-10
    auto = c["x2_auto_restart"]
    assert auto["status"] == 0 and auto["max_error"] <= 1e-10 and auto["n_restarts"] >= 3
    # every flagged point is a real failure, and every trusted plain point is accurate
    for r in res["error_vs_degree"]:
        if r["plain_diverging"]:
            assert r["plain_error_y_mp"] > 1e-3
        if r["plain_status"] == 0:
            assert r["plain_error_y_mp"] <= 1e-10


def test_cost_dimensions(study):
    rows = study[0]["cost"]
    dims = {(r["kind"][:3], r["N"]): r["dimension"] for r in rows}
    # odd degrees only: sum over odd d <= N of (d + 1); all moments: C(N + 2, 2) - 1
    assert dims[("nee", 61)] == sum(d + 1 for d in range(1, 62, 2)) == 992
    assert dims[("all", 30)] == math.comb(32, 2) - 1
    assert all(r["error_x1"] < 1e-3 for r in rows)


def test_coefficients_and_printed_series(study):
    res, _ = study
    assert res["checks"]["coefficients_equal"]
    rows = res["coefficients"]
    for r in rows:
        z0 = r["z0"]
        if r["k"] == 1:
            assert r["engine"] == r["printed_3_20"] == z0
        if r["k"] == 2:
            assert r["engine"] == 0.0 and r["printed_3_20"] == -0.5
        if r["k"] == 5:
            assert r["engine"] == pytest.approx(-z0 * (2 * z0**2 - 1) / 120, rel=1e-15)
            assert r["printed_3_20"] == pytest.approx(32 / (75 * z0**3), rel=1e-15)


def test_smooth_friction(study):
    res, _ = study
    assert res["checks"]["smooth_friction_max_error"] <= 1e-9
    for r in res["smooth_friction"]:
        if r["k"] == 1:
            assert r["engine"] == r["printed_4_1"] == r["coulomb"]
        if r["k"] == 2 and r["eps"] <= 0.1:
            assert r["engine"] == pytest.approx(r["coulomb"], rel=1e-6)  # tanh(10) ~ 1
        if r["k"] == 3:
            assert abs(r["engine"]) < abs(r["printed_4_1"]) / 10  # the printed t^3 term is not there


def test_troesch_against_reference(study):
    rows = study[0]["troesch"]
    by = {r["lam"]: r for r in rows}
    assert set(by) >= {0.5, 1.0, 5.0}
    for lam, rel in ((0.5, 1e-9), (1.0, 1e-9), (5.0, 1e-6)):
        assert by[lam]["status"] == 0
        assert by[lam]["reference"] == TROESCH_REFERENCE[lam]
        assert by[lam]["relative_error"] <= rel
