"""The README is tested: its Python blocks run as written, and the numbers it states are recomputed."""
from pathlib import Path
import os
import re
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import lcp

README = Path(__file__).resolve().parents[1] / "README.md"


def python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def _guarded(block: str) -> bool:
    """A script of its own (``if __name__ == "__main__":``): it starts worker processes, which
    import the script again, so it cannot share one with the other blocks."""
    return block.lstrip().startswith('if __name__ == "__main__":')


def _run_script(tmp_path, name, script):
    (tmp_path / name).write_text(script)
    env = dict(os.environ, MPLBACKEND="Agg")
    out = subprocess.run([sys.executable, name], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, textwrap.shorten(out.stderr[-3000:], 3000)


def test_readme_python_blocks_run_in_order_in_one_fresh_interpreter(tmp_path):
    blocks = [b for b in python_blocks(README.read_text()) if not _guarded(b)]
    assert len(blocks) >= 3
    script = "\n".join(f"# --- README block {i}\n{b}" for i, b in enumerate(blocks, 1))
    _run_script(tmp_path, "readme_blocks.py", script)
    # no example writes into the folder it runs in (a user's clone)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["readme_blocks.py"]


def test_readme_cluster_blocks_run_as_scripts_of_their_own(tmp_path):
    pytest.importorskip("dask.distributed")
    blocks = [b for b in python_blocks(README.read_text()) if _guarded(b)]
    assert blocks, "the README lost its cluster example"
    for i, b in enumerate(blocks):
        _run_script(tmp_path, f"readme_cluster_{i}.py", b)


def _readme_error_table():
    """Rows of the README's Moreau-Jean table: h -> (max|x - exact|, B h^2/8)."""
    rows = {}
    for line in README.read_text().splitlines():
        m = re.match(r"\|\s*(1e-\d)\s*\|\s*([0-9.e+-]+)\s*\|\s*([0-9.e+-]+)\s*\|", line)
        if m:
            rows[float(m.group(1))] = (float(m.group(2)), float(m.group(3)))
    return rows


@pytest.mark.parametrize("h", [1e-2, 1e-3])
def test_readme_error_table_is_what_the_package_computes(h):
    rows = _readme_error_table()
    assert h in rows, "the README's Moreau-Jean error table lost its row"
    stated_err, stated_bound = rows[h]
    scene = lcp.scenes.jean_pratt()
    res = lcp.simulate(scene, 0.3, h=h)
    err = float(np.max(np.abs(res.q[:, 0] - scene.exact(res.t)["x"])))
    assert err == pytest.approx(stated_err, rel=5e-3)  # stated to three digits
    assert scene.B * h * h / 8 == pytest.approx(stated_bound, rel=5e-3)


def test_readme_per_step_timings_are_the_recorded_run():
    import csv
    rec = {r["path"]: float(r["us_per_step"]) for r in
           csv.DictReader(open(README.parent / "benchmarks" / "recorded" / "per_step.csv"))}
    text = README.read_text()
    stated = {"compiled (auto, fast=True)": r"compiled exact path costs ([0-9.]+) µs",
              "osqp (general path)": r"general OSQP path\s+costs ([0-9.]+) µs"}
    for path, pattern in stated.items():
        m = re.search(pattern, text)
        assert m, pattern
        assert float(m.group(1)) == pytest.approx(rec[path], rel=0.02), path


# ----------------------------------------------------------------------------- every stated number
# Each number the README states is either recomputed here or read from the file a benchmark or
# study writes (benchmarks/recorded/*.csv are the recorded runs behind benchmarks/README.md).
RECORDED = README.parent / "benchmarks" / "recorded"


def _text():
    return " ".join(README.read_text().split())  # one line: statements wrap across lines


NUMBER = r"([0-9]+(?:\.[0-9]+)?(?:e[+-]?[0-9]+)?)"  # what {N} stands for in the patterns below


def _stated(pattern):
    """The numbers a README pattern captures ({N}: one number; each group a float)."""
    m = re.search(pattern.replace("{N}", NUMBER), _text())
    assert m, f"the README no longer states {pattern!r}"
    return [float(g) for g in m.groups()]


def _rows(name):
    import csv
    with open(RECORDED / name) as fh:
        return list(csv.DictReader(line for line in fh if not line.startswith("#") and line.strip()))


# every column of the error table, for every solver: tests/test_readme_numbers.py


def test_readme_mean_normal_forces():
    n0, stick = _stated(r"in sliding \(N0 = {N} N\) and in stick \(\(m\+M\) g = {N} N\)")
    scene = lcp.scenes.jean_pratt()
    res = lcp.simulate(scene, 0.3, h=1e-3)
    n_mean = res.p_N[:, 0] / 1e-3
    exact = scene.exact(res.t[1:] - 5e-4)["N"]  # midpoints of the steps
    away = np.abs(res.t[1:] - scene.tau0) > 2e-3  # the stopping step mixes both forces
    assert np.max(np.abs(n_mean[away] - exact[away]) / exact[away]) < 1e-12
    assert scene.N0 == pytest.approx(n0, abs=0.005) and 2 * 9.81 == pytest.approx(stick, abs=0.005)


def test_readme_observed_orders(tmp_path):
    from studies import paper_figures
    o_half, o_one = _stated(r"{N} for theta = 1/2 .*? and {N} for theta = 1 \(`--quick`")
    scene = lcp.scenes.jean_pratt(m=2.0, M=0.7, alpha=0.9, R=0.35, v0=1.7)
    orders, _ = paper_figures.convergence(scene, np.array([1e-2, 1e-3, 1e-4, 1e-5]) * (1 + 1 / 7), tmp_path)
    assert orders[0.5] == pytest.approx(o_half, abs=0.005) and orders[1.0] == pytest.approx(o_one, abs=0.005)


def test_readme_errata_numbers():
    from studies import paper_figures
    printed, true, series, model, stick = _stated(
        r"q\(tau0\) = {N} v0²/B is {N} v0²/B \(the printed five-term series gives 169/150 = {N}, "
        r"its own model \(3.9\) {N}\).*?N = \(m\+M\) g = {N} N")
    rows = paper_figures.errata(lcp.scenes.jean_pratt(), lcp.scenes.jean_pratt(v0=-1.0))
    q_row = next(r for r in rows if r["claim"].startswith("q(tau0)"))
    assert float(q_row["printed"]) == printed
    computed = [float(x) for x in re.findall(r"([0-9.]+) \(", q_row["computed"])]
    assert computed[0] == true and computed[1] == pytest.approx(169 / 150, abs=1e-5)
    assert 169 / 150 == pytest.approx(series, abs=5e-4) and computed[2] == pytest.approx(model, abs=5e-4)
    assert 2 * 9.81 == pytest.approx(stick, abs=0.005)


def test_readme_event_errors():
    default, reverse, loaded = _stated(r"max \|x − exact\| = {N} / {N} at 1000 times.*?"
                                       r"Loaded stick, slip and reversal: ≤ {N}")
    for scene, bound in ((lcp.scenes.jean_pratt(), default), (lcp.scenes.jean_pratt(v0=-1.0), reverse),
                         (lcp.scenes.jean_pratt(phi=5.0, v0=-1.0), loaded), (lcp.scenes.jean_pratt(phi=-12.0), loaded),
                         (lcp.scenes.jean_pratt(phi=12.0), loaded)):
        res = lcp.simulate(scene, scene.t_end, method="event", n_eval=1000)
        assert np.max(np.abs(res.q[:, 0] - scene.exact(res.t)["x"])) <= bound * 1.05


def test_readme_million_steps():
    err, bound, y = _stated(r"\|x − exact\| = {N} \(below B h²/8 = {N}\) and \|y\| = {N} exactly")
    scene = lcp.scenes.jean_pratt()
    h = 0.3 / 1e6
    res = lcp.simulate(scene, 0.3, h=h, save_every=1000)
    assert len(res.t) == 1001
    assert float(np.max(np.abs(res.q[:, 0] - scene.exact(res.t)["x"]))) <= err * 1.05
    assert scene.B * h * h / 8 == pytest.approx(bound, rel=0.02)
    assert float(np.max(np.abs(res.q[:, 1]))) <= y * 1.05


def test_readme_lem_numbers():
    import warnings
    from fractions import Fraction
    from scipy.integrate import solve_ivp
    import lem
    from lem.series import tanh_ode_true_coefficients

    (at_61,) = _stated(r"\({N} at N = 61;")
    rec = next(r for r in _rows("lem_dimension.csv") if r["kind"] == "odd (needed)" and r["N"] == "61")
    assert float(rec["error"]) == pytest.approx(at_61, rel=0.02)
    (restarted,) = _stated(r"restarted \(degree 20, `restart=\"auto\"`\) it is accurate to {N}")
    f = lambda t, y: np.array([y[1], np.tanh(y[0])])  # noqa: E731
    ref = solve_ivp(f, (0, 2), [0, 1], method="DOP853", rtol=1e-14, atol=1e-16).y[0, -1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plain = lem.solve(f, (0.0, 2.0), [0.0, 1.0], degree=61)
        r = lem.solve(f, (0.0, 2.0), [0.0, 1.0], degree=20, restart="auto")
    assert plain.status == -1 and r.status >= 0 and abs(r.y[0, -1] - ref) <= restarted
    stated = re.search(r"0, 1, 0, 1/6, 0, −1/120, 0, −1/1008 for z0 = 1", _text())
    assert stated and tanh_ode_true_coefficients(1, 8)[:8] == [Fraction(x) for x in
                                                               ("0", "1", "0", "1/6", "0", "-1/120", "0", "-1/1008")]
    (slide,) = _stated(r"The qdd = −1 slide is exact \(≤ {N}\) at every N")
    te = np.linspace(0.0, 1.0, 11)
    for N in (3, 11, 31, 61):
        s = lem.solve(lambda t, y: np.array([y[1], -1.0 + 0.0 * y[0]]), (0.0, 1.0), [0.0, 1.0], degree=N, t_eval=te)
        assert np.max(np.abs(s.y[0] - (te - te * te / 2))) <= slide, N
    lo, hi = _stated(r"dimension ~2700 is built and solved in {N}–{N} s")
    big = [float(r["total_s"]) for r in _rows("lem_dimension.csv") if 2600 <= int(r["dimension"]) <= 2800]
    assert big and min(big) == pytest.approx(lo, abs=0.005) and max(big) == pytest.approx(hi, abs=0.005)


def test_readme_work_precision_numbers_are_the_recorded_run():
    summary = {r["scene"]: r for r in _rows("work_precision_summary.csv")}
    lo, hi = _stated(r"at every accuracy below 1e-6, {N}–{N}× faster")
    speedups = [float(r["min_speedup"]) for r in summary.values()]
    assert min(speedups) == pytest.approx(lo, abs=0.5) and max(speedups) == pytest.approx(hi, abs=0.5)
    assert all(r["package_ahead_below_1e-6"] == "True" for r in summary.values())
    best_lo, best_hi, base_lo, base_hi, base_loaded = _stated(
        r"reaching {N}–{N} where the baseline stops at {N}–{N} \({N} on")
    best = [float(r["best_package_e_max"]) for r in summary.values()]
    assert max(best) <= best_lo * 3 and min(best) == pytest.approx(best_hi, rel=0.5)
    base = [float(summary[k]["best_baseline_e_max"]) for k in ("default", "reverse", "near_shock")]
    assert min(base) == pytest.approx(base_lo, rel=0.1) and max(base) == pytest.approx(base_hi, rel=0.1)
    assert float(summary["loaded_stick"]["best_baseline_e_max"]) == pytest.approx(base_loaded, rel=0.02)
    assert [summary[k]["moreau_jean_ahead_below_1e-6"] for k in ("default", "reverse", "near_shock")] == ["False"] * 3
    rate, after = _stated(r"creeps at {N}·eps m/s \({N} m after 100 s at eps = 1e-6\)")
    assert np.arctanh(5.0 / (0.5 * 2 * 9.81)) == pytest.approx(rate, abs=0.005)
    last = [float(r["drift"]) for r in _rows("work_precision_creep.csv")
            if r["method"].startswith("tanh") and r["eps"] == "1e-06" and float(r["t"]) == 100.0]
    assert last and all(d == pytest.approx(after, rel=0.01) for d in last)


def test_readme_speed_numbers_are_the_recorded_runs():
    rec = {r["path"]: float(r["us_per_step"]) for r in _rows("per_step.csv")}
    (save_every,) = _stated(r"\({N} µs with `save_every=1000`")
    lean, enum, lemke = _stated(r"shows {N} µs is possible\), the Python enum loop {N} µs, "
                                r"the Python Lemke loop {N} µs")
    assert rec["compiled, save_every=1000"] == pytest.approx(save_every, rel=0.02)
    assert rec["osqp lean loop (prototype, not package code)"] == pytest.approx(lean, rel=0.02)
    assert rec["enum, Python loop (fast=False)"] == pytest.approx(enum, rel=0.02)
    assert rec["lemke, Python loop (fast=False)"] == pytest.approx(lemke, rel=0.02)
    osqp_target = _stated(r"target ≤ {N} µs: \*\*not met\*\*")[0]
    assert rec["osqp (general path)"] > osqp_target  # the README says the target is not met
    batch = {int(r["scenes"]): r for r in _rows("batch_throughput.csv")}
    rate, ratio = _stated(r"{N} scene-steps/s for 1e5 Jean–Pratt scenes on 2 cores \(target 3e7\),\s+{N}×")
    compiled = float(batch[100_000]["compiled"])
    assert compiled == pytest.approx(rate, rel=0.02) and compiled > 3e7
    assert float(batch[100_000]["ratio"]) == pytest.approx(ratio, rel=0.05)
    assert min(float(r["ratio_min"]) for r in batch.values()) >= 3  # the floor, in every round
    faster, lsoda_best = _stated(r"The event integrator is {N}× faster than LSODA on tanh friction at "
                                 r"LSODA's best error \(which is {N}")
    ev = next(r for r in _rows("event_vs_lsoda.csv") if r["method"].startswith("event") and "phi = 0" in r["scene"])
    ls = next(r for r in _rows("event_vs_lsoda.csv") if r["method"].startswith("LSODA") and "phi = 0" in r["scene"])
    assert float(ev["speedup"]) == pytest.approx(faster, abs=0.05)
    assert float(ls["max_x_error"]) == pytest.approx(lsoda_best, rel=0.1)


def test_readme_optimal_control_numbers_are_the_recorded_run():
    rows = {(r["problem"], r["method"], int(r["N"])): r for r in _rows("ocp.csv")}
    free, affine = "free steps, constant hold", "free steps, affine hold"
    value, ref, gap, gap_all, miss = _stated(r"free steps {N} s against the bang-bang optimum {N} s "
                                             r"\(gap {N}; ≤ {N} for N = 10 … 40\), replay miss {N} m")
    r = rows[("min_time", free, 40)]
    assert float(r["value"]) == pytest.approx(value, abs=1e-10)
    assert float(r["reference"]) == pytest.approx(ref, abs=1e-10)
    assert float(r["rel_gap"]) == pytest.approx(gap, rel=0.05) and float(r["final_miss"]) <= miss * 1.25
    gaps = [float(v["rel_gap"]) for k, v in rows.items() if k[0] == "min_time" and k[1] == free and k[2] <= 40]
    assert len(gaps) >= 3 and max(gaps) == pytest.approx(gap_all, rel=0.05)
    eff, eff_ref, eff_gap = _stated(r"minimum effort {N} against {N} \(gap {N} at N = 40")
    r = rows[("min_effort", affine, 40)]
    assert float(r["value"]) == pytest.approx(eff, abs=1e-9)
    assert float(r["reference"]) == pytest.approx(eff_ref, abs=1e-9)
    assert abs(float(r["rel_gap"])) <= eff_gap * 1.05
    assert all(abs(float(rows[("min_effort", affine, N)]["rel_gap"])) <= 1e-12 for N in (10, 20, 40))
    hold, hold_ref, n, hold_gap = _stated(r"return by 1.2 s: {N} against the closed form {N} at N = (\d+) "
                                          r"\(gap {N}\)")
    r = rows[("hold", affine, int(n))]
    assert float(r["value"]) == pytest.approx(hold, abs=1e-9)
    assert float(r["reference"]) == pytest.approx(hold_ref, abs=1e-9)
    assert float(r["rel_gap"]) == pytest.approx(hold_gap, rel=0.05)
    (stall,) = _stated(r"piecewise-constant hold stalls at gap {N} for minimum effort")
    assert float(rows[("min_effort", free, 40)]["rel_gap"]) == pytest.approx(stall, rel=0.05)
    assert stall == pytest.approx(1 / (4 * 33 ** 2), rel=0.01)
    lin_lo, lin_hi = _stated(r"The former linear hold missed by {N} m \(min time, N = 40\) to {N} m \(hold, N = 48\)")
    assert float(rows[("min_time", "uniform, linear hold", 40)]["final_miss"]) == pytest.approx(lin_lo, rel=0.05)
    assert float(rows[("hold", "uniform, linear hold", 48)]["final_miss"]) == pytest.approx(lin_hi, rel=0.05)
    lo, hi = _stated(r"from ([0-9]+)–([0-9]+) N uncontrolled")  # the sliding normal force (m+M) g / (1 - kappa)
    assert 2 * 9.81 / 0.05 == pytest.approx(lo, abs=0.5) and 2 * 9.81 / 0.01 == pytest.approx(hi, abs=0.5)


def test_readme_stability_counts_are_the_recorded_full_run():
    # the full study's summary.csv (figures/stability/, untracked) is recorded in benchmarks/recorded/
    correct, reported, wrong = _stated(r"{N} correct, {N} reported failures, {N} silently wrong")
    rows = _rows("stability_summary.csv")
    assert correct == sum(int(r["correct"]) for r in rows)
    assert reported == sum(int(r["reported failure"]) for r in rows)
    assert wrong == sum(int(r["silently wrong"]) for r in rows) == 0


def test_readme_shock_avoidance_bound():
    # the smallest possible peak normal force when stopping by T (the study's closed form)
    from studies import optimal_control

    (bound,) = _stated(r"normal force down to the bound {N} N")
    assert optimal_control.peak_bound() == pytest.approx(bound, abs=0.005)


def test_readme_fixed_phase_numbers_are_the_recorded_run():
    rows = {(r["problem"], r["method"], int(r["N"])): r for r in _rows("ocp.csv")}
    ph_a, ph_c = "fixed phases, affine hold", "fixed phases, constant hold"
    free_a, free_c = "free steps, affine hold", "free steps, constant hold"
    cases = [(r"minimum effort to a gap of {N} at N = (\d+) in {N} s \(the free-step homotopy with its "
              r"multi-start:\s+{N} s\)", "min_effort", ph_a, free_a),
             (r"the hold problem to {N} at N = (\d+) in {N} s \({N} s\)", "hold", ph_a, free_a),
             (r"minimum time to {N} at N = (\d+)\s+in {N} s \({N} s\)", "min_time", ph_c, free_c)]
    for pattern, problem, phases, homotopy in cases:
        gap, n, t_ph, t_h = _stated(pattern)
        r, h = rows[(problem, phases, int(n))], rows[(problem, homotopy, int(n))]
        assert abs(float(r["rel_gap"])) == pytest.approx(gap, rel=0.05)
        assert float(r["total_s"]) == pytest.approx(t_ph, abs=0.006)
        assert float(h["total_s"]) == pytest.approx(t_h, abs=0.006)
        assert r["success"] == "True" and float(r["final_miss"]) <= 1e-8


def test_readme_nosnoc_ratio_is_the_recorded_run():
    lo, hi = _stated(r"the cheapest package solve with an equal\s+or smaller gap and replay miss is {N}–{N} times faster")
    ratios = [float(r["time_ratio"]) for r in _rows("ocp_vs_nosnoc.csv")
              if r["solver"] == "nosnoc" and r["role"] == "sweep"]
    assert len(ratios) >= 6
    assert min(ratios) == pytest.approx(lo, abs=0.05) and max(ratios) == pytest.approx(hi, abs=0.5)
