"""studies.shock_limit in quick mode: the numbers behind its figures."""
import csv
import math

import pytest

from studies import shock_limit


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    out = tmp_path_factory.mktemp("shock_limit")
    return shock_limit.run(out=out, quick=True), out


def test_files_written(study):
    res, out = study
    names = {p.name for p in res["files"]}
    assert {"sweep.csv", "sweep_v0_pos.png", "sweep_v0_neg.png", "convergence.csv", "convergence.png",
            "iterations.csv", "iterations.png", "series.csv", "series.png", "regimes.csv",
            "regimes.png"} <= names
    for p in res["files"]:
        assert (out / p.name).stat().st_size > 0
    rows = list(csv.DictReader((out / "sweep.csv").open()))
    assert len(rows) == len(res["sweep"])
    assert float(rows[0]["kappa"]) == res["sweep"][0]["kappa"]  # full precision in the CSV


def test_sweep_event_driven_is_exact(study):
    res, _ = study
    labels = [r["label"] for r in res["sweep"]]
    assert "1-1e-12" in labels and "1" in labels and "1.5" in labels
    for r in res["sweep"]:
        assert r["event_success"]
        assert r["event_x_error"] <= 1e-13
        if r["shock"]:
            assert r["v0"] > 0 and r["kappa"] >= 1
            assert r["tau0_event"] == 0.0
            assert abs(r["shock_PN_event"] - 1.0) <= 1e-12 and abs(r["shock_PT_event"] + 2.0) <= 1e-12
        else:
            assert abs(r["tau0_event"] - r["tau0_exact"]) <= 1e-14 * max(1.0, r["tau0_exact"]) + 1e-3 * r["tau0_exact"]
            assert math.isclose(r["N0_event"], r["N0_exact"], rel_tol=1e-3)
        # smooth or shock, the stop delivers the impulses (M tan(alpha) v0, -A v0)
        assert abs(r["excess_PN_event"] - r["v0"]) <= 1e-9
        assert abs(r["PT_event"] + 2.0 * r["v0"]) <= 1e-9
        assert abs(r["excess_PN_exact"] - r["v0"]) <= 1e-9
    # Moreau-Jean: error of order h at the stop, for every kappa
    for r in res["sweep"]:
        for h in res["hs"]:
            assert abs(r[f"x_stop_mj_{h:g}"] - r["x_stop_exact"]) <= h
    assert res["checks"]["event_tau0_rel_error_k_le_6"] <= 1e-14


def test_convergence_to_the_shock(study):
    res, _ = study
    rows = res["convergence"]
    for a, b in zip(rows, rows[1:]):
        ratio = b["one_minus_kappa"] / a["one_minus_kappa"]
        # tau0 = v0 A (1 - kappa) / (R (m+M) g) with R = 2 kappa; x* = v0 tau0 / 2
        kr = b["kappa"] / a["kappa"]
        assert math.isclose(b["tau0"] / a["tau0"] * kr, ratio, rel_tol=1e-3)
        assert math.isclose(b["sup_dist_to_shock"] / a["sup_dist_to_shock"] * kr, ratio, rel_tol=1e-3)
    for r in rows:
        assert abs(r["slide_PN_minus_shock"]) <= 1e-9 and abs(r["slide_PT_minus_shock"]) <= 1e-9
        assert r["event_x_error"] <= 1e-13


def test_iterations_and_plain_contraction(study):
    res, _ = study
    for r in res["iterations"]:
        assert r["enum_success"] and r["lemke_success"] and r["osqp_success"]
        assert r["osqp_max_iterations"] <= 5  # branch solves: no kappa^k crawl
        if r["kappa"] < 1:
            assert abs(r["plain_contraction"] - r["kappa"]) <= 1e-9
            if r["plain_converged"]:
                assert r["plain_iterations"] <= 1.2 * r["plain_predicted"] + 5
            else:
                assert r["plain_predicted"] > r["plain_iterations"]
        else:
            assert r["plain_converged"]  # the bound grows until it stops the block, then sticks
    at_one = next(r for r in res["iterations"] if r["kappa"] == 1.0)
    assert 20 <= at_one["plain_iterations"] <= 200  # grows linearly at kappa = 1


def test_printed_series_breakdown(study):
    res, _ = study
    ser = res["series"]["scaled"]
    assert math.isclose(ser[1.0]["q_at_tau0_printed"], 169 / 150, rel_tol=1e-12)  # docs/errata.md
    assert 0.05 < ser[1.0]["u_1pct"] < 0.5 and 0.05 < ser[-1.0]["u_1pct"] < 0.5
    assert ser[1.0]["min_speed_printed"] > 0.5  # the printed series never stops
    for r in res["series"]["rows"]:
        if r["v0"] > 0 and r["kappa"] >= 1:
            assert not r["printed_defined"]
        if r["printed_defined"]:
            assert math.isclose(r["t_1pct"] / r["tau0"], ser[r["v0"]]["u_1pct"], rel_tol=1e-12)


def test_regime_map(study):
    res, _ = study
    reg = res["regimes"]
    assert res["checks"]["regime_mismatches"] == 0
    assert res["checks"]["regime_points_checked"] >= 100
    # the paper's case: shock exactly beyond kappa = 1
    for r in reg["rows"]:
        if r["case"] == 0:
            assert (r["exact"] == "shock, then stick") == (r["kappa"] >= 1)
