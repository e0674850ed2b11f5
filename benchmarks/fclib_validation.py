"""Cost of validating a problem file against solving it: 1000-contact problems, FCLib HDF5 and .dat.

    python benchmarks/fclib_validation.py [--contacts 1000] [--repeats 5]

For a planar disk packing (``many_contacts.disk_packing``, W = H M^-1 H') and a spatial problem of
the same kind (3 rows per contact: every block of W's normal-tangent rows coupled to its
neighbours), written as FCLib HDF5 and as ``.dat`` (sparse-block storage), the table gives the
fastest of ``--repeats`` runs of:

- ``read (structure)``: ``read_problem(path, check=False)``: sizes, indices, dtypes;
- ``read (checked)``: ``read_problem(path)``: also finite data, mu, W symmetric and positive
  semi-definite by a shifted sparse LDL' (``lcp.io.fclib_checks``);
- ``ContactFile.check()``: the problem checks a study makes before solving (now the same sparse
  factorization test, at tolerance 1e-9 of max |W|);
- ``dense eigenvalue check``: ``check_problem`` with its dense ``eigvalsh`` (what ``check()`` did
  before, up to 4096 rows);
- ``solve (auto)``: the planar or cone ``auto`` solver on the problem.

Writes ``benchmarks/out/fclib_validation.csv``.
"""
from __future__ import annotations

import argparse
import csv
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

from lcp.contact.spatial_solvers import make_cone_solver
from lcp.fclib import ContactFile, read_problem, write_dat, write_hdf5
from lcp.contact.law import check_problem, interleave
from lcp.contact.solvers import make_solver

sys.path.insert(0, str(Path(__file__).resolve().parent))
from many_contacts import disk_packing  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "out"


def planar_file(k):
    pb = disk_packing(k)
    perm = interleave(pb.k)
    return ContactFile(pb.W[perm][:, perm], pb.q[perm], pb.mu)


def spatial_file(k, seed=0):
    """k spatial contacts between balls in a chain (6 velocities each), W = H M^-1 H'."""
    rng = np.random.default_rng(seed)
    nb = k + 1
    rows, cols, vals = [], [], []
    for c in range(k):
        a, b = c, c + 1
        frame = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        for r in range(3):
            for body, sign in ((a, -1.0), (b, 1.0)):
                for d in range(3):
                    rows.append(3 * c + r)
                    cols.append(6 * body + d)
                    vals.append(sign * frame[r, d])
                rows.append(3 * c + r)
                cols.append(6 * body + 3 + r)
                vals.append(0.3)
    H = sp.csr_matrix((vals, (rows, cols)), shape=(3 * k, 6 * nb))
    minv = rng.uniform(0.5, 2.0, 6 * nb)
    W = (H @ sp.diags(minv) @ H.T).tocsr()
    q = H @ rng.normal(size=6 * nb)
    q[0::3] = -np.abs(q[0::3])
    return ContactFile(W, q, np.full(k, 0.3), dim=3)


def fastest(fn, repeats):
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--contacts", type=int, default=1000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, cf in (("planar", planar_file(args.contacts)), ("spatial", spatial_file(args.contacts))):
            spatial = cf.dim == 3
            make = make_cone_solver if spatial else make_solver

            def solve(cf=cf, make=make):
                return make("auto").solve(cf.problem(check=False))

            solve()  # compilation and imports out of the timing
            t_solve = fastest(solve, args.repeats)
            t_dense = fastest(lambda cf=cf: check_problem(cf.W, cf.q, cf.mu, dims=cf.dims if cf.dim == 3 else None),
                              max(1, args.repeats // 2))
            t_check = fastest(cf.check, args.repeats)
            for fmt in ("hdf5", "dat"):
                path = Path(tmp) / f"{label}.{fmt}"
                (write_hdf5 if fmt == "hdf5" else lambda p, c: write_dat(p, c, storage="sparse-block"))(path, cf)
                t_struct = fastest(lambda path=path: read_problem(path, check=False), args.repeats)
                t_read = fastest(lambda path=path: read_problem(path), args.repeats)
                row = dict(problem=label, format=fmt, contacts=cf.n_contacts, rows=cf.W.shape[0], nnz=cf.W.nnz,
                           read_structure=t_struct, read_checked=t_read, value_checks=t_read - t_struct,
                           check=t_check, dense_check=t_dense, solve=t_solve)
                rows.append(row)
                print(f"{label:8s} {fmt:5s} k {cf.n_contacts} nnz {cf.W.nnz:7d}  read {t_struct * 1e3:8.1f} ms  "
                      f"read+checks {t_read * 1e3:8.1f} ms (checks {(t_read - t_struct) * 1e3:6.1f} ms)  "
                      f"check() {t_check * 1e3:6.1f} ms  dense check {t_dense * 1e3:8.1f} ms  "
                      f"solve {t_solve * 1e3:7.1f} ms", flush=True)
    RESULTS.mkdir(exist_ok=True)
    with open(RESULTS / "fclib_validation.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
