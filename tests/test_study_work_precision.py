"""studies.work_precision in quick mode: the errors behind its figures (never its timings)."""
import csv
import math

import numpy as np
import pytest

from studies import work_precision as wp

# the whole quick run takes 15-50 s; tests/test_studies_pieces.py runs a few of its pieces by default
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    out = tmp_path_factory.mktemp("work_precision")
    return wp.run(out=out, quick=True), out


def rows_of(res, scene=None, family=None, **match):
    return [r for r in res["rows"] if (scene is None or r["scene"] == scene) and (family is None or r["family"] == family)
            and all(r[k] == v for k, v in match.items())]


def test_files_written(study):
    res, out = study
    names = {p.name for p in res["files"]}
    assert {f"work_precision_{k}.csv" for k in wp.SCENE_LABELS} <= names
    assert {"work_precision_summary.csv", "creep.csv", "work_precision.png", "work_precision_final.png",
            "work_precision_stop.png", "creep.png"} <= names
    for p in res["files"]:
        assert (out / p.name).stat().st_size > 0
    rows = list(csv.DictReader((out / "work_precision_default.csv").open()))
    assert len(rows) == len(rows_of(res, "default"))
    assert float(rows[0]["e_max"]) == rows_of(res, "default")[0]["e_max"]  # full precision in the CSV


def test_every_family_on_every_scene(study):
    res, _ = study
    for key in wp.SCENE_LABELS:
        fams = {r["family"] for r in rows_of(res, key)}
        assert {"moreau-jean", "event", "lem-series", "tanh-ivp"} <= fams
        solvers = {r["solver"] for r in rows_of(res, key, "moreau-jean")}
        assert {"auto (compiled)", "enum", "lemke", "osqp"} <= solvers
        methods = {r["method"] for r in rows_of(res, key, "tanh-ivp")}
        assert methods == {f"tanh law + solve_ivp {m}" for m in ("RK45", "LSODA", "Radau")}
    assert rows_of(res, "default", "lem-engine")


def test_moreau_jean_errors_are_what_it_claims(study):
    res, _ = study
    for r in rows_of(res, family="moreau-jean"):
        assert r["success"], r
        # theta = 1/2: |a| h^2 / 8 at every grid point; theta = 1: first order, |v0| h / 2 + |a| h^2/8
        assert r["e_max"] <= r["claim"] * (1 + 1e-9) + 1e-12, r
        assert r["max_y"] <= 1e-12, r           # no lift-off, no sinking
        assert r["stop_err"] <= r["h"] * (1 + 1e-9), r  # the stop is found within one step
    # every one-step solver gives the same trajectory
    for key in wp.SCENE_LABELS:
        for r in rows_of(res, key, "moreau-jean"):
            same = [s for s in rows_of(res, key, "moreau-jean") if s["h"] == r["h"] and s["theta"] == r["theta"]]
            for s in same:
                assert abs(s["e_max"] - r["e_max"]) <= 1e-12
                assert abs(s["e_final"] - r["e_final"]) <= 1e-12


def test_event_driven_is_exact(study):
    res, _ = study
    for r in rows_of(res, family="event"):
        assert r["success"]
        assert r["e_max"] <= r["claim"] and r["e_final"] <= 1e-12
        assert r["stop_err"] <= 1e-12
        assert r["max_y"] <= 1e-12


def test_printed_series_is_reported_wrong(study):
    res, _ = study
    for r in rows_of(res, family="lem-series"):
        sc, _T = wp.make_scenes()[r["scene"]]
        # it is wrong from t^3 on (docs/errata.md): on [0, tau0] alone it misses by more than
        # half the exact stop distance, and by far more than Moreau-Jean does
        assert r["e_max"] > 0.5 * abs(sc.x_stop), r
        assert r["e_max"] > 1e2 * min(s["e_max"] for s in rows_of(res, r["scene"], "moreau-jean"))
    default = rows_of(res, "default", "lem-series")[0]
    assert math.isnan(default["stop_err"])  # its velocity has no zero: it never stops by itself


def test_lem_engine_fixed_restart_meets_its_estimate(study):
    res, _ = study
    fixed = [r for r in rows_of(res, family="lem-engine") if r["restart"] == "fixed"]
    assert fixed
    for r in fixed:
        assert r["success"], r
        # against its own model (the regularized law) it is as good as it says ...
        assert r["err_vs_reg"] <= 10 * r["error_estimate"] + 1e-9, r
        # ... and against exact Coulomb friction it carries the regularization's model error
        tanh_same_eps = [t for t in rows_of(res, r["scene"], "tanh-ivp") if t["eps"] == r["eps"] and t["success"]]
        for t in tanh_same_eps:
            assert abs(r["e_max"] - t["e_max"]) <= 1e-3 * t["e_max"] + r["err_vs_reg"]


def test_lem_engine_auto_restart_is_never_silently_wrong(study):
    res, _ = study
    auto = [r for r in rows_of(res, family="lem-engine") if r["restart"] == "auto"]
    assert auto
    for r in auto:
        if r["success"]:
            assert r["err_vs_reg"] <= 10 * r["error_estimate"] + 1e-9, r


def test_regularized_baseline_cannot_lift_off_and_is_error_limited(study):
    res, _ = study
    for r in rows_of(res, family="tanh-ivp"):
        assert r["max_y"] == 0.0  # reduced 1-DOF model: y = 0 by construction
        if r["success"] and r["scene"] in ("default", "reverse"):
            # phi = 0: the regularization error is about 0.17 eps^2 (m, eps in m/s) on these scenes
            assert r["e_max"] >= 0.05 * r["eps"] ** 2


def test_package_reaches_errors_the_baseline_cannot(study):
    res, _ = study
    for key, s in res["summary"].items():
        assert s["best_package_e_max"] <= 1e-15, key
        assert s["best_package_e_max"] < 1e-2 * s["best_baseline_e_max"], key
    # on the loaded stick the smoothed law's best error is its creep over the stick: eps-limited
    loaded = res["summary"]["loaded_stick"]
    eps_min = min(r["eps"] for r in rows_of(res, "loaded_stick", "tanh-ivp"))
    assert loaded["best_baseline_e_max"] >= 0.3 * eps_min


def test_loaded_stick_creeps_only_when_regularized(study):
    res, _ = study
    cr = res["creep"]
    T, t1 = cr["T"], cr["t1"]
    for s in cr["series"]:
        if s["method"].startswith("tanh"):
            eps = s["eps"]
            predicted = eps * cr["rate_per_eps"] * (s["t"] - t1)
            # the creep velocity is eps atanh(phi / (R N)): the drift grows linearly with t
            assert np.allclose(s["drift"][-1], predicted[-1], rtol=2e-2), (s["method"], eps)
            late, early = s["err"][-1], s["err"][np.searchsorted(s["t"], T / 10)]
            assert late > 5 * early, (s["method"], eps)
        else:
            # Moreau-Jean (compiled and OSQP) and the event integrator hold the stick exactly
            assert np.max(s["drift"]) <= 1e-15, s["method"]
            assert np.ptp(s["err"]) <= 1e-15, s["method"]
