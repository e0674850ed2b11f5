"""studies.fc_benchmark with no folder: its built-in problems (seeded files of every form)."""
import numpy as np

from lcp.fclib import read_problem
from studies import fc_benchmark


def test_builtin_problems_are_seeded_files_of_every_form_that_solve(tmp_path):
    paths = fc_benchmark.builtin_problems(tmp_path / "a")
    again = fc_benchmark.builtin_problems(tmp_path / "b")
    assert [p.read_bytes() for p in paths] == [p.read_bytes() for p in again]
    files = [read_problem(p) for p in paths]
    assert {(cf.dim, cf.form) for cf in files} == {(2, "local"), (2, "global"), (3, "local"), (3, "global")}
    assert {cf.storage for cf in files if cf.dim == 2 and cf.form == "local"} >= {"dense", "sparse-block"}
    for path, cf in zip(paths, files):
        assert not cf.check().errors, path.name
        rows = fc_benchmark.solve_file(path, solvers=("auto",))
        assert len(rows) == 1 and rows[0]["status"] == 0, rows
        assert rows[0]["error"] <= fc_benchmark.SOLVED, (path.name, rows[0]["error"])
        if cf.dim == 2 and cf.form == "local":  # every contact pressed: the normals approach
            assert np.all(cf.problem().q[:cf.n_contacts] < 0), path.name


def test_main_without_a_folder_runs_on_the_builtin_problems(tmp_path, monkeypatch, capsys):
    seen = {}

    def fake_run(folder, out, quick, siconos):
        seen.update(folder=folder, out=out, quick=quick)
        return dict(rows=[], note="", files=[], seconds=0.0)

    monkeypatch.setattr(fc_benchmark, "run", fake_run)
    fc_benchmark.main(["--quick", "--out", str(tmp_path)])
    assert seen == dict(folder=None, out=tmp_path, quick=True)
    assert "built-in problems" in capsys.readouterr().out


def test_run_without_a_folder_writes_the_problems_beside_the_results(tmp_path, monkeypatch):
    # one cheap solver per family keeps this a test of the default path, not a benchmark
    monkeypatch.setattr(fc_benchmark, "SOLVER_LIMITS", {"auto": None})
    monkeypatch.setattr(fc_benchmark, "CONE_SOLVER_LIMITS", {"auto": None})
    res = fc_benchmark.run(None, out=tmp_path, quick=True, siconos=False)
    written = sorted(p.name for p in (tmp_path / "problems").iterdir())
    assert written == sorted({r["file"] for r in res["rows"]})
    assert all(r["status"] == 0 and r["error"] <= fc_benchmark.SOLVED for r in res["rows"]), res["rows"]
