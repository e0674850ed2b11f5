"""studies.fc_benchmark on a folder of small problem files (the Siconos peer is not run here)."""
import numpy as np

from lcp.fclib import ContactFile, write_dat
from lcp.contact.law import interleave
from studies import fc_benchmark
from tests.test_fc_solvers import random_problem


def test_fc_benchmark_solves_a_folder_and_writes_profiles(tmp_path):
    folder = tmp_path / "problems"
    folder.mkdir()
    for k, seed in ((5, 0), (30, 1)):
        pb = random_problem(k, seed)
        perm = interleave(k)
        W = pb.W[perm][:, perm] if hasattr(pb.W, "tocsr") else pb.W[np.ix_(perm, perm)]
        write_dat(folder / f"p{k}.dat", ContactFile(W, pb.q[perm], pb.mu), storage="sparse-block")
    (folder / "broken.dat").write_text("2\n3\n1\n")
    res = fc_benchmark.run(folder, out=tmp_path / "out", quick=True, siconos=False)
    rows = res["rows"]
    broken = [r for r in rows if r["file"] == "broken.dat"]
    assert broken and broken[0]["status"] < 0 and "truncated" in broken[0]["message"]
    solved = [r for r in rows if r["file"] != "broken.dat"]
    assert {r["solver"] for r in solved} >= {"auto", "newton", "nsgs", "lemke", "osqp"}
    for r in solved:
        assert r["status"] == 0 and r["error"] <= 1e-10, r
    assert (tmp_path / "out" / "results.csv").exists()
    assert (tmp_path / "out" / "profile_time.png").exists()
    prof = fc_benchmark.performance_profile({"a": [1.0, 2.0], "b": [2.0, np.inf]}, np.array([1.0, 2.0]))
    assert list(prof["a"]) == [1.0, 1.0] and list(prof["b"]) == [0.0, 0.5]
