"""studies.fc_benchmark keeps going past bad files and failing solvers: a row for every file."""
import csv

import numpy as np
import pytest

from lcp.fclib import ContactFile, write_dat, write_hdf5
from studies import fc_benchmark

h5py = pytest.importorskip("h5py")


def good():
    return ContactFile(np.array([[2.0, 0.5], [0.5, 1.0]]), [-1.0, 0.3], [0.4])


def test_every_file_gets_a_row_and_the_table_is_written(tmp_path):
    folder = tmp_path / "problems"
    folder.mkdir()
    write_dat(folder / "a_good.dat", good())
    # mu = inf (once an IndexError that stopped the study before it wrote anything)
    write_dat(folder / "b_mu_inf.dat", ContactFile(good().W, good().q, [np.inf]))
    write_hdf5(folder / "c_neg_index.hdf5", good())
    with h5py.File(folder / "c_neg_index.hdf5", "a") as fh:
        i = fh["fclib_local/W/i"][()]
        i[0] = -1
        del fh["fclib_local/W/i"]
        fh["fclib_local/W/i"] = i
    (folder / "d_junk.hdf5").write_bytes(b"\x89HDF\r\n\x1a\n" + b"\1" * 100)
    (folder / "e_empty.dat").write_text("")
    res = fc_benchmark.run(folder, out=tmp_path / "out", quick=True, siconos=False)
    by_file = {}
    for r in res["rows"]:
        by_file.setdefault(r["file"], []).append(r)
    assert sorted(by_file) == ["a_good.dat", "b_mu_inf.dat", "c_neg_index.hdf5", "d_junk.hdf5", "e_empty.dat"]
    assert all(r["status"] == 0 and r["error"] <= 1e-10 for r in by_file["a_good.dat"])
    for name, words in (("b_mu_inf.dat", "mu"), ("c_neg_index.hdf5", "negative row index"),
                        ("d_junk.hdf5", "HDF5"), ("e_empty.dat", "empty")):
        (row,) = by_file[name]
        assert row["status"] == fc_benchmark.FAILED and name in row["message"] and words in row["message"], row
    with open(tmp_path / "out" / "results.csv") as fh:
        table = list(csv.DictReader(fh))
    assert {r["file"] for r in table} == set(by_file)
    assert (tmp_path / "out" / "profile_time.png").exists()


def test_a_folder_of_bad_files_still_writes_its_table(tmp_path):
    folder = tmp_path / "problems"
    folder.mkdir()
    (folder / "x.dat").write_text("2\n1\n")
    res = fc_benchmark.run(folder, out=tmp_path / "out", quick=True, siconos=False)
    assert [r["status"] for r in res["rows"]] == [fc_benchmark.FAILED]
    with open(tmp_path / "out" / "results.csv") as fh:
        table = list(csv.DictReader(fh))
    assert [(r["file"], r["status"]) for r in table] == [("x.dat", str(fc_benchmark.FAILED))]
    assert "truncated" in table[0]["message"]


def test_a_solver_that_raises_is_a_row(tmp_path, monkeypatch):
    write_dat(tmp_path / "p.dat", good())

    class Broken:
        def solve(self, pb):
            raise RuntimeError("solver blew up")

    real = fc_benchmark.make_solver
    monkeypatch.setattr(fc_benchmark, "make_solver",
                        lambda name, **kw: Broken() if name == "nsgs" else real(name, **kw))
    rows = fc_benchmark.solve_file(tmp_path / "p.dat", solvers=("auto", "nsgs", "newton"))
    status = {r["solver"]: (r["status"], r["message"]) for r in rows}
    assert status["nsgs"] == (fc_benchmark.FAILED, "RuntimeError: solver blew up")
    assert status["auto"][0] == 0 and status["newton"][0] == 0
