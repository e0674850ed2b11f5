"""Planar friction-contact problem files solved by every applicable solver, with performance profiles.

``python -m studies.fc_benchmark DIR [--out OUT] [--quick]`` reads every problem file in DIR
(FCLib HDF5 or Siconos ``.dat``, local or global form; :mod:`lcp.fclib`), checks it, solves it with
each applicable one-step solver and writes into OUT (default ``figures/fc_benchmark/``):

- ``results.csv``: file, contacts, nnz(W), solver, status, time (s), iterations, the independent
  natural-map error (:func:`lcp.friction_contact.natural_map_error`, normalised as Siconos
  normalises its fc2d error) and the package's residual;
- ``profile_time.png``, ``profile_accuracy.png``: Dolan-More performance profiles (fraction of
  problems a solver solves within a factor tau of the best time; of the best error), a problem
  counting as solved at error <= 1e-10.

When Siconos's Python module is installed for the system's own Python (``/usr/bin/python3``, e.g.
Debian's ``python3-siconos``), its fc2d NSGS and Lemke solve the same files in a subprocess and
join the table as ``siconos-nsgs`` and ``siconos-lemke``; otherwise a note says they were skipped.
``--quick`` keeps files of at most 500 contacts and caps iterations.

Example
-------
>>> from studies import fc_benchmark
>>> res = fc_benchmark.run("problems", out=None, quick=True)     # doctest: +SKIP
>>> res["rows"][0]["error"] <= 1e-10                              # doctest: +SKIP
True
"""
from __future__ import annotations

import json
import os
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

from lcp.fclib import read_problem, write_dat
from lcp.friction_contact import natural_map_error
from lcp.solvers import make_solver
from studies._common import out_dir, parse_args, save, write_csv

import matplotlib.pyplot as plt  # noqa: E402  (studies._common selects the Agg backend first)

NAME = "fc_benchmark"
SOLVED = 1e-10
SYSTEM_PYTHON = "/usr/bin/python3"

#: solver name -> largest number of contacts it is tried on (dense Lemke and OSQP grow fast)
SOLVER_LIMITS = {"auto": None, "newton": None, "nsgs": None, "lemke": 400, "osqp": 250}

_SICONOS_FILES = r'''
import json, sys, time
import numpy as np
import siconos.numerics as sn
paths, tol, max_iter = json.loads(sys.argv[1])
out = []
for path in paths:
    for name, sid in (("siconos-nsgs", sn.SICONOS_FRICTION_2D_NSGS), ("siconos-lemke", sn.SICONOS_FRICTION_2D_LEMKE)):
        try:
            pb = sn.frictionContact_new_from_filename(path)
            n = 2 * pb.numberOfContacts
            if name == "siconos-lemke" and n > 800:
                continue
            so = sn.SolverOptions(sid)
            so.dparam[sn.SICONOS_DPARAM_TOL] = tol
            so.iparam[sn.SICONOS_IPARAM_MAX_ITER] = max_iter
            r, u = np.zeros(n), np.zeros(n)
            t0 = time.perf_counter()
            info = sn.fc2d_driver(pb, r, u, so)
            dt = time.perf_counter() - t0
            out.append(dict(path=path, solver=name, info=int(info), time=dt,
                            iterations=int(so.iparam[sn.SICONOS_IPARAM_ITER_DONE]),
                            siconos_error=float(so.dparam[sn.SICONOS_DPARAM_RESIDU]), r=r.tolist()))
        except Exception as exc:  # a peer's failure is reported, not fatal
            out.append(dict(path=path, solver=name, info=-99, error_text=str(exc)))
print(json.dumps(out))
'''


def siconos_available() -> bool:
    """Whether the system Python can import Siconos's numerics module."""
    if not os.path.exists(SYSTEM_PYTHON):
        return False
    try:
        res = subprocess.run([SYSTEM_PYTHON, "-c", "import siconos.numerics"], capture_output=True, timeout=60,
                             check=False)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return res.returncode == 0


def run_siconos_script(script: str, args, timeout: float = 3600):
    """Run a Siconos script (written to a temporary folder) with the system Python; parsed JSON."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "peer.py"
        path.write_text(script)
        res = subprocess.run([SYSTEM_PYTHON, str(path), json.dumps(args)], capture_output=True, text=True,
                             timeout=timeout, check=False)
    if res.returncode != 0:
        raise RuntimeError(f"Siconos peer failed: {res.stderr[-2000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def problem_files(folder) -> list[Path]:
    """The problem files of a folder (.dat, .hdf5, .h5), sorted."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"{folder}: not a folder")
    return sorted(p for p in folder.iterdir() if p.suffix in (".dat", ".hdf5", ".h5"))


def solve_file(path, solvers=("auto", "newton", "nsgs", "lemke", "osqp"), quick: bool = False):
    """Solve one file with each applicable solver: list of result dicts (see the module doc)."""
    cf = read_problem(path)
    rep = cf.check()
    base = dict(file=Path(path).name, contacts=cf.n_contacts, nnz=int(cf.W.nnz), form=cf.form,
                warnings="; ".join(rep.warnings))
    if rep.errors:
        return [dict(base, solver="-", status=-9, message="; ".join(rep.errors), time=np.nan, iterations=0,
                     error=np.nan, residual=np.nan)]
    if cf.n_contacts == 0:
        return [dict(base, solver="-", status=0, message="no contacts", time=0.0, iterations=0, error=0.0,
                     residual=0.0)]
    pb = cf.problem(check=False)
    rows = []
    for name in solvers:
        limit = SOLVER_LIMITS.get(name)
        if limit is not None and cf.n_contacts > limit:
            continue
        # the iterative solvers also meet Siconos's normalised error (the same tolerance as its run)
        opts = {"error_tol": SOLVED} if name in ("auto", "newton", "nsgs") else {}
        if quick and name == "nsgs":
            opts["max_sweeps"] = 2000
        solver = make_solver(name, **opts)
        t0 = time.perf_counter()
        sol = solver.solve(pb)
        dt = time.perf_counter() - t0
        err = natural_map_error(pb.W, pb.q, pb.mu, sol.p)
        rows.append(dict(base, solver=name, status=sol.status, message=sol.message, time=dt,
                         iterations=sol.iterations, error=err, residual=sol.residual))
    return rows


def performance_profile(table: dict, taus: np.ndarray) -> dict:
    """Dolan-More profile: table[solver] = array of costs per problem (inf = not solved)."""
    costs = np.array(list(table.values()), dtype=float)
    best = np.min(costs, axis=0)
    out = {}
    for name, c in zip(table, costs):
        with np.errstate(invalid="ignore", divide="ignore"):  # unsolved problems: inf / inf
            ratio = np.where(np.isfinite(c) & np.isfinite(best), c / np.where(best > 0, best, 1.0), np.inf)
        out[name] = np.array([np.mean(ratio <= t) for t in taus])
    return out


def run(folder, out=None, quick: bool = False, siconos: bool = True) -> dict:
    """Solve every problem of ``folder``; write the CSV and profiles into ``out`` (None: no files)."""
    t_start = time.perf_counter()
    files = problem_files(folder)
    rows = []
    for path in files:
        try:
            if quick and read_problem(path).n_contacts > 500:
                continue
            rows.extend(solve_file(path, quick=quick))
        except ValueError as exc:  # a bad file is a row of the table, not the end of the study
            rows.append(dict(file=path.name, contacts=0, nnz=0, form="-", warnings="", solver="-", status=-9,
                             message=str(exc), time=np.nan, iterations=0, error=np.nan, residual=np.nan))
    note = ""
    if siconos and siconos_available():
        todo = [p for p in files if any(r["file"] == p.name and r["solver"] != "-" for r in rows)]
        with tempfile.TemporaryDirectory() as tmp:
            # Siconos's fc2d solvers take dense or sparse-block storage of the local form: other
            # files (CSparse storage, global form) are handed over as the same local problem
            # rewritten in sparse-block storage
            given = {}
            for p in todo:
                cf = read_problem(p)
                if cf.form == "global" or cf.storage not in ("dense", "sparse-block"):
                    q = Path(tmp) / p.name
                    write_dat(q, cf, storage="sparse-block")
                    given[str(q)] = p
                else:
                    given[str(p)] = p
            try:
                peer = run_siconos_script(_SICONOS_FILES, [list(given), SOLVED, 2000 if quick else 100000])
            except (RuntimeError, subprocess.TimeoutExpired) as exc:
                peer, note = [], f"Siconos peer failed: {exc}"
        for rec in peer:
            if rec.get("info") == -99:
                continue
            rec["path"] = str(given[rec["path"]])
            cf = read_problem(rec["path"])
            r = np.asarray(rec["r"])
            err = natural_map_error(cf.W, cf.q, cf.mu, r, order="interleaved")
            rows.append(dict(file=Path(rec["path"]).name, contacts=cf.n_contacts, nnz=int(cf.W.nnz), form=cf.form,
                             warnings="", solver=rec["solver"], status=0 if rec["info"] == 0 else -1,
                             message=f"info {rec['info']}, Siconos error {rec['siconos_error']:.3g}",
                             time=rec["time"], iterations=rec["iterations"], error=err, residual=np.nan))
    elif siconos:
        note = "Siconos's Python module is not importable by the system Python: peers skipped"
    res = dict(rows=rows, note=note, files=[])
    if out is not None:
        d = out_dir(out, NAME)
        header = ["file", "contacts", "nnz", "form", "solver", "status", "time", "iterations", "error",
                  "residual", "message", "warnings"]
        res["files"].append(write_csv(d / "results.csv", header, ([r[h] for h in header] for r in rows)))
        res["files"].extend(_profiles(rows, d))
    res["seconds"] = time.perf_counter() - t_start
    return res


def _profiles(rows, d):
    solved = [r for r in rows if r["solver"] != "-"]
    files = sorted({r["file"] for r in solved})
    solvers = sorted({r["solver"] for r in solved})
    out = []
    for what, key in (("time", "time"), ("accuracy", "error")):
        table = {}
        for s in solvers:
            cost = []
            for f in files:
                hit = [r for r in solved if r["file"] == f and r["solver"] == s]
                ok = hit and np.isfinite(hit[0]["error"]) and hit[0]["error"] <= SOLVED
                val = hit[0][key] if hit else np.inf
                if key == "error" and hit:
                    val = max(val, 1e-17) if np.isfinite(val) else np.inf
                cost.append(val if (ok or key == "error") else np.inf)
            table[s] = cost
        taus = np.logspace(0, 4, 200)
        prof = performance_profile(table, taus)
        fig, ax = plt.subplots(figsize=(6, 4))
        for s, y in prof.items():
            ax.step(taus, y, where="post", label=s)
        ax.set_xscale("log")
        ax.set_xlabel(f"tau (within tau times the best {what})")
        ax.set_ylabel("fraction of problems")
        ax.set_title(f"performance profile: {what}" + (" (solved: error <= 1e-10)" if key == "time" else ""))
        ax.legend(fontsize=8)
        out.append(save(fig, d / f"profile_{what}.png"))
    return out


def main(argv=None):
    def extra(p):
        p.add_argument("folder", type=Path, help="folder of problem files (.dat, .hdf5)")
        p.add_argument("--no-siconos", action="store_true", help="do not run the Siconos peer")

    args = parse_args(NAME, __doc__.splitlines()[0], argv, extra)
    res = run(args.folder, args.out, args.quick, siconos=not args.no_siconos)
    print(f"{'file':44s} {'k':>5s} {'solver':14s} {'st':>3s} {'time (s)':>9s} {'iter':>6s} {'error':>9s}")
    for r in res["rows"]:
        print(f"{r['file'][:44]:44s} {r['contacts']:5d} {r['solver']:14s} {r['status']:3d} {r['time']:9.4f} "
              f"{r['iterations']:6d} {r['error']:9.2e}")
    if res["note"]:
        print(res["note"])
    print(f"wrote {len(res['files'])} files to {args.out} in {res['seconds']:.1f} s")
    return res


if __name__ == "__main__":
    main()
