"""The numbers of the README's results section are what the commands it shows give.

Each number is parsed from README.md and recomputed from the package, by the function the README's
command runs, and must agree to the digits it is printed with: half a unit of its last digit
(``6.74e-5`` stands for [6.735e-5, 6.745e-5]; ``0`` for exactly 0). The rest of the section's
numbers are checked in tests/test_readme.py; measured times are timings, stated with their machine.
"""
from __future__ import annotations

import ast
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

import lcp
from studies import paper_figures, stability

README = Path(__file__).resolve().parents[1] / "README.md"
NUMBER = r"([0-9]+(?:\.[0-9]+)?(?:e[+-]?[0-9]+)?)"


def results_section() -> str:
    text = README.read_text()
    start = text.index("\n## Results")
    return text[start:text.index("\n## ", start + 1)]


def _flat(text: str) -> str:
    return " ".join(text.split())  # statements wrap across lines


def half_unit(token: str) -> float:
    """Half a unit of the last printed digit of a number written as ``token``."""
    mantissa, _, exponent = token.lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    return 0.5 * 10.0 ** (int(exponent or 0) - decimals)


def agrees(value: float, token: str) -> bool:
    """``value`` prints as ``token``; a value exactly between two printed ones may print as either."""
    if float(token) == 0:
        return value == 0
    return abs(value - float(token)) <= half_unit(token) * (1 + 1e-9)


def test_half_unit_and_agrees():
    assert half_unit("6.74e-5") == pytest.approx(5e-8) and half_unit("1.70") == pytest.approx(5e-3)
    assert half_unit("4") == 0.5
    assert agrees(6.7449e-5, "6.74e-5") and not agrees(6.7451e-5, "6.74e-5")
    assert agrees(8.175e-5, "8.17e-5") and agrees(8.175e-5, "8.18e-5")  # a tie prints either way
    assert agrees(0.0, "0") and not agrees(1e-300, "0")


def stated(pattern: str, text: str | None = None) -> list[str]:
    """The number tokens a README pattern captures ({N}: one number)."""
    m = re.search(pattern.replace("{N}", NUMBER), _flat(text if text is not None else results_section()))
    assert m, f"the README no longer states {pattern!r}"
    return list(m.groups())


# ----------------------------------------------------------------------------- the error table
def readme_table() -> dict[float, list[str]]:
    """h -> [max|x - exact|, B h^2/8, max|y|, worst residual] as printed."""
    rows = {}
    for line in results_section().splitlines():
        m = re.match(r"\|\s*(1e-\d+)\s*" + r"\|\s*" + NUMBER + r"\s*" + (r"\|\s*" + NUMBER + r"\s*") * 3 + r"\|", line)
        if m:
            rows[float(m.group(1))] = list(m.groups()[1:])
    return rows


@pytest.fixture(scope="module")
def table():
    """The table as `python -m studies.paper_figures` computes it (every solver, default scene)."""
    hs = sorted(readme_table(), reverse=True)
    return paper_figures.error_table(lcp.scenes.jean_pratt(), hs)


def test_table_rows_are_the_full_study_s():
    assert sorted(readme_table()) == [1e-5, 1e-4, 1e-3, 1e-2]
    intro = _flat(results_section().split("| h |")[0])
    assert "alpha = pi/4" in intro and "over [0, 0.3] s" in intro
    for solver in paper_figures.TABLE_SOLVERS:
        assert f"`{solver}`" in intro, solver


def test_table_every_column_every_solver(table):
    for h, (x, bound, y, residual) in readme_table().items():
        at = [r for r in table if r["h"] == h]
        assert {r["solver"] for r in at} == set(paper_figures.TABLE_SOLVERS)
        for r in at:  # "the same for every solver to the digits shown"
            assert agrees(r["x"], x), (h, r["solver"], r["x"], x)
        assert agrees(at[0]["bound"], bound), (h, at[0]["bound"], bound)
        # the rounding-level columns: the largest over the solvers
        assert agrees(max(r["y"] for r in at), y), (h, [r["y"] for r in at], y)
        assert agrees(max(r["residual"] for r in at), residual), (h, [r["residual"] for r in at], residual)
    # "the compiled path of `auto` and `enum` gives |y| = 0 exactly"
    assert "gives |y| = 0 exactly" in _flat(results_section())
    assert all(r["y"] == 0 for r in table if r["solver"] in ("auto", "enum"))


def test_the_study_prints_the_table(table):
    readme = readme_table()
    printed = paper_figures.table_lines(table)
    assert len(printed) == len(readme)
    for line in printed:
        h = float(re.search(r"h = (\S+)", line).group(1))
        x, bound, y, residual = readme[h]
        for label, token in (("max|x - exact| =", x), ("B h^2/8 =", bound), ("max|y| =", y),
                             ("worst residual =", residual)):
            got = re.search(re.escape(label) + r" (\S+)", line).group(1)
            assert float(got) == float(token), (line, label, token)


def test_quick_mode_is_labelled_and_prints_what_the_readme_says(tmp_path, capsys):
    """`--quick` prints the table's first two rows and the three-decade orders the README states."""
    paper_figures.main(["--out", str(tmp_path), "--quick"])
    out = capsys.readouterr().out
    assert "--quick" in out and "(`--quick` prints the first two rows only)" in _flat(results_section())
    readme = readme_table()
    for h in (1e-2, 1e-3):
        x = readme[h][0]
        line = next(ln for ln in out.splitlines() if re.match(rf"\s*h = {h:g}\s+max\|x - exact\| = ", ln))
        assert float(re.search(r"max\|x - exact\| = (\S+)", line).group(1)) == float(x)
    assert not any(re.match(r"\s*h = 0\.0001\s+max\|x - exact\| = ", ln) for ln in out.splitlines())
    half, one = stated(r"`--quick` fits three decades, h = 1.143e-2 … 1.143e-4, and prints {N} and {N}\)")
    m = re.search(r"three decades, --quick\): theta = 0.5: (\S+), theta = 1: (\S+)", out)
    assert m and (m.group(1), m.group(2)) == (half, one)


def test_quick_orders_recomputed(tmp_path):
    half, one = stated(r"`--quick` fits three decades, h = 1.143e-2 … 1.143e-4, and prints {N} and {N}\)")
    scene = lcp.scenes.jean_pratt(m=2.0, M=0.7, alpha=0.9, R=0.35, v0=1.7)
    orders, _ = paper_figures.convergence(scene, np.array([1e-2, 1e-3, 1e-4]) * (1 + 1 / 7), tmp_path)
    assert agrees(orders[0.5], half) and agrees(orders[1.0], one)


# ----------------------------------------------------------------------------- the example's scene
def test_the_example_scene_is_the_table_s_scene():
    """The README's first example builds the scene of the results table (alpha = pi/4, not 0.785)."""
    call = re.search(r"lcp\.scenes\.jean_pratt\(([^)]*)\)", README.read_text()).group(1)
    kwargs = {}
    for item in ast.parse(f"f({call})", mode="eval").body.keywords:
        kwargs[item.arg] = eval(compile(ast.Expression(item.value), "README", "eval"), {"math": __import__("math")})
    example, default = lcp.scenes.jean_pratt(**kwargs), lcp.scenes.jean_pratt()
    assert example.params == default.params
    (kappa,) = stated(r"alpha = pi/4, R = 0.5, v0 = 1, kappa = {N}\)")
    assert agrees(example.kappa, kappa)
    assert "0.785" not in README.read_text()


# ----------------------------------------------------------------------------- stability: the failures
def test_stability_failures_are_the_ones_the_readme_names():
    sec = _flat(results_section())
    (n,) = stated(r"{N} reported failures, 0 silently wrong")
    built = {(c.name, m) for c in stability.cases(False) if c.group == "must be reported" for m in c.methods}
    assert "alpha = pi/2 refused by each of the 5 methods" in sec and "OSQP capped at one iteration" in sec
    assert "`enum` forced on 3 contacts" in sec
    lem = {name: run for _, name, run in stability.lem_cases(False)}
    outcomes = {name: stability.run_lem_case("LEM", name, run) for name, run in lem.items()}
    failed = {name for name, row in outcomes.items() if row.outcome == "reported failure"}
    assert failed == {"y'' = tanh y, x = 2, N = 61, no restart", "y'' = tanh y, x = 1, N = 61"}
    assert len(built) + len(failed) == int(n) == 9
    assert "Eight of the failures are the cases built to fail" in sec
    assert outcomes["y'' = tanh y, x = 1, N = 61"].status == 1


def test_the_ninth_failure_s_numbers():
    from scipy.integrate import solve_ivp
    from lem import solve

    err_y, err_yd, est_yd = stated(r"the ninth is y'' = tanh y to x = 1 at N = 61 asked for rtol = 1e-9: y is "
                                   r"within {N}, but y' is off by {N} \(estimated {N}\), more than was asked")
    f = lambda _, y: [y[1], np.tanh(y[0])]  # noqa: E731
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = solve(f, (0.0, 1.0), [0.0, 1.0], degree=61, rtol=1e-9)  # as studies.stability runs it
    ref = solve_ivp(f, (0.0, 1.0), [0.0, 1.0], method="DOP853", rtol=2.3e-14, atol=1e-16).y[:, -1]
    err = np.abs(r.y[:, -1] - ref)
    assert r.status == 1 and r.success
    assert agrees(err[0], err_y) and agrees(err[1], err_yd) and agrees(r.error_estimate[1, -1], est_yd)
    assert err[1] > 1e-9 * abs(r.y[1, -1])  # y' really misses the tolerance asked: the report is right
    (lem_y, lem_yd) = stated(r"\({N} at N = 61; y' is off by {N} there, so asked for rtol = 1e-9 the engine returns "
                             r"status 1")
    assert agrees(err[0], lem_y) and agrees(err[1], lem_yd)


# ----------------------------------------------------------------------------- examples and the clone
def test_no_readme_example_names_a_file_in_the_working_copy():
    """Python examples write only into a temporary folder (the test of the blocks checks the folder
    they run in stays empty); the file example's path is made by tempfile."""
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(), flags=re.S)
    for b in blocks:
        for call in re.findall(r"(?:write_dat|write_hdf5|savefig|to_csv|open)\(\s*\"", b):
            pytest.fail(f"a README example writes to a literal relative path: {call}")
    assert any("tempfile.mkdtemp()" in b and "chain.dat" in b for b in blocks)


def test_timings_say_they_are_timings_and_where():
    sec = _flat(results_section())
    assert ("except times and speed ratios: those are timings, measured on a 2-core machine shared with "
            "other jobs") in sec


# ----------------------------------------------------------------------------- stated as equalities
def test_million_steps_to_the_printed_digits():
    """The stability study's long-horizon case (1e6 compiled steps, save_every=1000) as printed."""
    err, bound, y = stated(r"\|x − exact\| = {N} \(below B h²/8 = {N}\) and \|y\| = {N} exactly")
    scene, h = lcp.scenes.jean_pratt(), 0.3 / 1e6
    res = lcp.simulate(scene, 0.3, h=h, save_every=1000)
    assert agrees(float(np.max(np.abs(res.q[:, 0] - scene.exact(res.t)["x"]))), err)
    assert agrees(scene.B * h * h / 8, bound) and agrees(float(np.max(np.abs(res.q[:, 1]))), y)


def test_event_errors_to_the_printed_digits():
    default, reverse = stated(r"max \|x − exact\| = {N} / {N} at 1000 times")
    for scene, token in ((lcp.scenes.jean_pratt(), default), (lcp.scenes.jean_pratt(v0=-1.0), reverse)):
        res = lcp.simulate(scene, scene.t_end, method="event", n_eval=1000)
        assert agrees(float(np.max(np.abs(res.q[:, 0] - scene.exact(res.t)["x"]))), token)
        assert res.t_events[0] == scene.tau0  # "the stop time equal to tau0 to the last bit"
