"""The paper_figures study in quick mode: files written, numbers right."""
import csv

import pytest

from studies import paper_figures


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = tmp_path_factory.mktemp("paper_figures")
    return paper_figures.run(out=out, quick=True), out


def test_files(result):
    res, out = result
    for name in ("fig_2_1_system.png", "trajectories_forward.png", "trajectories_reverse.png", "error_vs_h.png",
                 "errata.csv", "convergence.csv", "trajectories_forward.csv", "exact_forward.csv",
                 "printed_series_forward.csv"):
        assert (out / name).stat().st_size > 0, name


def test_numbers(result):
    res, _ = result
    for key in ("errors_forward", "errors_reverse", "errors_other"):
        for h, e in res[key].items():
            assert e["x"] <= e["bound"] + 1e-12
            assert e["y"] <= 1e-12 and e["residual"] <= 1e-9
    assert res["orders"][1.0] == pytest.approx(1.0, abs=0.1)
    assert 1.5 <= res["orders"][0.5] <= 2.2


def test_errata(result):
    res, out = result
    rows = {r["claim"]: r for r in res["errata"]}
    q = rows["q(tau0) in units of v0^2/B (section 4)"]
    assert q["printed"] == "0.42" and q["computed"].startswith("0.5 (exact")
    assert "1.12667" in q["computed"]  # 169/150, the printed series at tau0
    assert "N = 19.62 N" in rows["for t > tau0: q, f, N (section 4)"]["computed"]
    with open(out / "errata.csv") as fh:
        assert len(list(csv.DictReader(fh))) == len(res["errata"])


def test_main_cli(tmp_path, capsys):
    paper_figures.main(["--out", str(tmp_path), "--quick"])
    printed = capsys.readouterr().out
    assert "Errata" in printed and "0.42" in printed
    assert (tmp_path / "errata.csv").exists()
