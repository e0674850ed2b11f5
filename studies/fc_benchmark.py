"""Friction-contact problem files solved by every applicable solver, with performance profiles.

``python -m studies.fc_benchmark [DIR] [--out OUT] [--quick]`` reads every problem file in DIR
(FCLib HDF5 or Siconos ``.dat``, local or global form, planar or spatial; :mod:`lcp.fclib`), checks
it, solves it with each applicable one-step solver and writes into OUT (default
``figures/fc_benchmark/``). Without DIR it runs on its built-in problems (:func:`builtin_problems`:
random planar and spatial problems of known structure, local and global forms, in each ``.dat``
storage), written into ``OUT/problems/`` first so that the file readers are part of the run.
It writes:

- ``results.csv``: file, dimension, contacts, nnz(W), solver, status, time (s), iterations, the
  independent natural-map error (:func:`lcp.contact.law.natural_map_error`, normalised as
  Siconos normalises its fc2d error; the disk cone for spatial files) and the package's residual;
- ``profile_time.png``, ``profile_accuracy.png``: Dolan-More performance profiles (fraction of
  problems a solver solves within a factor tau of the best time; of the best error), a problem
  counting as solved at error <= 1e-10 whatever the solver's status.

Every file gets at least one row: a file the reader rejects (:func:`lcp.fclib.read_problem`'s
ValueError names the file and what is wrong), a problem that fails its checks, or a solver that
raises is a row of status -9 (:data:`FAILED`) with the message, a file left out by ``--quick`` one
of status 2 (:data:`SKIPPED`); the study goes on to the next file and always writes its table.

Planar files (dimension 2) go to :func:`lcp.contact.solvers.make_solver`'s solvers (:data:`SOLVER_LIMITS`),
spatial files (dimension 3, the Coulomb disk) to :func:`lcp.contact.spatial_solvers.make_cone_solver`'s
(:data:`CONE_SOLVER_LIMITS`). The faceted solver replaces each disk by a polygon: its rows are
named ``faceted (approx.)``, keep its status 1 ("approximate") and count as solved only where the
disk law's error meets the threshold.

When Siconos's Python module is installed for the system's own Python (``/usr/bin/python3``, e.g.
Debian's ``python3-siconos``), its NSGS (fc2d and Lemke for planar files, fc3d for spatial ones)
solves the same files in a subprocess and joins the table as ``siconos-nsgs`` (and
``siconos-lemke``); otherwise a note says they were skipped. ``--quick`` keeps files of at most
500 contacts and caps iterations.

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

from lcp.contact.spatial_solvers import make_cone_solver
from lcp.fclib import ContactFile, read_problem, write_dat
from lcp.contact.law import natural_map_error
from lcp.contact.solvers import make_solver
from studies._common import out_dir, parse_args, save, write_csv

import matplotlib.pyplot as plt  # noqa: E402  (studies._common selects the Agg backend first)

NAME = "fc_benchmark"
SOLVED = 1e-10
SYSTEM_PYTHON = "/usr/bin/python3"

#: solver name -> largest number of contacts it is tried on (dense Lemke and OSQP grow fast)
SOLVER_LIMITS = {"auto": None, "newton": None, "nsgs": None, "lemke": 400, "osqp": 250}
#: spatial files: cone solver name -> largest number of contacts (the local solve takes one contact;
#: Tresca's SOCP sequence and the faceted dense Lemke grow fast)
CONE_SOLVER_LIMITS = {"auto": None, "local": 1, "newton": None, "nsgs": None, "tresca": 300, "faceted": 60}
#: the name of an approximate solver's rows
APPROXIMATE = {"faceted": "faceted (approx.)"}
#: a spatial solve shorter than SHORT seconds is repeated (REPEATS runs in all, cold each time) and
#: timed by its fastest run, ours and Siconos's alike: single sub-millisecond runs are mostly noise
REPEATS, SHORT = 3, 0.1
#: status of a row whose file could not be read or whose solver raised; of a file left out by --quick
FAILED, SKIPPED = -9, 2

_SICONOS_FILES = r'''
import json, sys, time
import numpy as np
import siconos.numerics as sn
paths, tol, max_iter = json.loads(sys.argv[1])
REPEATS, SHORT = 3, 0.1
out = []
PLANAR = (("siconos-nsgs", sn.SICONOS_FRICTION_2D_NSGS), ("siconos-lemke", sn.SICONOS_FRICTION_2D_LEMKE))
SPATIAL = (("siconos-nsgs", sn.SICONOS_FRICTION_3D_NSGS),)
for path in paths:
    try:
        dim = sn.frictionContact_new_from_filename(path).dimension
    except Exception as exc:  # a peer's failure is reported, not fatal
        out.append(dict(path=path, solver="siconos-nsgs", info=-99, error_text=str(exc)))
        continue
    for name, sid in (PLANAR if dim == 2 else SPATIAL):
        try:
            pb = sn.frictionContact_new_from_filename(path)
            n = dim * pb.numberOfContacts
            if name == "siconos-lemke" and n > 800:
                continue
            so = sn.SolverOptions(sid)
            so.dparam[sn.SICONOS_DPARAM_TOL] = tol
            so.iparam[sn.SICONOS_IPARAM_MAX_ITER] = max_iter
            r, u = np.zeros(n), np.zeros(n)
            t0 = time.perf_counter()
            info = (sn.fc2d_driver if dim == 2 else sn.fc3d_driver)(pb, r, u, so)
            dt = time.perf_counter() - t0
            for _ in range(REPEATS - 1 if dim == 3 and dt < SHORT else 0):  # short spatial runs: the fastest
                r2, u2 = np.zeros(n), np.zeros(n)
                t0 = time.perf_counter()
                sn.fc3d_driver(pb, r2, u2, so)
                dt = min(dt, time.perf_counter() - t0)
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


def builtin_problems(folder, seed: int = 0) -> list[Path]:
    """Write the study's built-in problems into ``folder`` (created if needed) and return their paths.

    Each is one step of random bodies of positive masses (W = H M^-1 H', positive definite, so every
    problem has a solution), pressed into their contacts: planar local problems of 5, 40 and 120
    contacts in dense, sparse-block and CSparse storage, a planar global one of 20 contacts, and
    spatial (Coulomb disk) local and global ones of 10 and 20 contacts. Seeded: the same files on
    every run.
    """
    rng = np.random.default_rng(seed)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)

    def bodies(k, dim):
        """Masses and a contact Jacobian H (velocities x contact rows, contact-by-contact order):
        each contact row on its own body coordinate plus random couplings to others."""
        n = dim * k + 3
        H = np.zeros((n, dim * k))
        H[np.arange(dim * k), np.arange(dim * k)] = 1.0
        mask = rng.random((n, dim * k)) < min(1.0, 3.0 / n)
        H[mask] += rng.normal(size=mask.sum())
        return rng.uniform(0.5, 2.0, n), H

    def pressing(k, dim):
        """Free velocities per contact: approaching normals, random tangents."""
        u = rng.normal(size=(k, dim))
        u[:, 0] = -rng.uniform(0.1, 1.0, k)
        return u.ravel()

    paths = []
    for k, storage in ((5, "dense"), (40, "sparse-block"), (120, "csparse")):
        m, H = bodies(k, 2)
        W = H.T @ (H / m[:, None])
        path = folder / f"planar_local_{k}.dat"
        write_dat(path, ContactFile(W, pressing(k, 2), rng.uniform(0.1, 0.9, k), name=path.stem), storage=storage)
        paths.append(path)
    for k, dim, form in ((20, 2, "global"), (10, 3, "local"), (20, 3, "global")):
        m, H = bodies(k, dim)
        mu = rng.uniform(0.1, 0.9, k)
        # global form M v = H r + f, u = H' v + w: the free velocity H' M^-1 f + w presses
        cf = ContactFile.from_global(np.diag(m), H, m * rng.normal(scale=0.1, size=m.size), pressing(k, dim), mu,
                                     dim=dim)
        if form == "local":
            cf = ContactFile(cf.W, cf.q, mu, dim=dim)
        path = folder / f"{'planar' if dim == 2 else 'spatial'}_{form}_{k}.dat"
        write_dat(path, cf, storage="sparse-block", form=form)
        paths.append(path)
    return paths


def problem_files(folder) -> list[Path]:
    """The problem files of a folder (.dat, .hdf5, .h5), sorted."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"{folder}: not a folder")
    return sorted(p for p in folder.iterdir() if p.suffix in (".dat", ".hdf5", ".h5"))


def solve_file(path, solvers=None, quick: bool = False, cf=None):
    """Solve one file with each applicable solver: list of result dicts (see the module doc).

    ``solvers``: names to try (None: every solver of :data:`SOLVER_LIMITS` for a planar file, of
    :data:`CONE_SOLVER_LIMITS` for a spatial one); names of the other family are skipped. ``cf``:
    the file already read (None: read here; a malformed file raises ValueError). A solver that
    raises gives a row of status -9 with the exception as its message.
    """
    if cf is None:
        cf = read_problem(path)
    rep = cf.check()
    base = dict(file=Path(path).name, dim=cf.dim, contacts=cf.n_contacts, nnz=int(cf.W.nnz), form=cf.form,
                warnings="; ".join(rep.warnings))
    if rep.errors:
        return [dict(base, solver="-", status=FAILED, message="; ".join(rep.errors), time=np.nan, iterations=0,
                     error=np.nan, residual=np.nan)]
    if cf.n_contacts == 0:
        return [dict(base, solver="-", status=0, message="no contacts", time=0.0, iterations=0, error=0.0,
                     residual=0.0)]
    pb = cf.problem(check=False)
    spatial = cf.dim == 3
    limits = CONE_SOLVER_LIMITS if spatial else SOLVER_LIMITS
    (warm_up_cone_solvers if spatial else warm_up_planar_solvers)()
    if solvers is None:
        solvers = tuple(limits)
    rows = []
    for name in solvers:
        if spatial and name not in CONE_SOLVER_LIMITS:
            continue
        limit = limits.get(name)
        if limit is not None and cf.n_contacts > limit:
            continue
        if spatial:
            # the cone solvers stop on their own residual (impulse units, tolerance 1e-10 of the
            # problem's scale); the table's error is measured independently all the same
            opts = {"max_sweeps": 2000} if quick and name == "nsgs" else {}
            solver = make_cone_solver(name, **opts)
            # a fresh problem per solver: none inherits the operators another one cached on it
            pb = cf.problem(check=False)
        else:
            # the iterative solvers also meet Siconos's normalised error (the same tolerance as its run)
            opts = {"error_tol": SOLVED} if name in ("auto", "newton", "nsgs") else {}
            if quick and name == "nsgs":
                opts["max_sweeps"] = 2000
            solver = make_solver(name, **opts)
            pb = cf.problem(check=False)  # fresh: no branch factorization cached by another solver
        label = APPROXIMATE.get(name, name) if spatial else name
        try:
            t0 = time.perf_counter()
            sol = solver.solve(pb)
            dt = time.perf_counter() - t0
            for _ in range(REPEATS - 1 if spatial and dt < SHORT else 0):
                # a fresh solver and problem: no warm start nor cached operator from the first run
                again, pb_again = make_cone_solver(name, **opts), cf.problem(check=False)
                t0 = time.perf_counter()
                again.solve(pb_again)
                dt = min(dt, time.perf_counter() - t0)
            err = natural_map_error(pb.W, pb.q, pb.mu, sol.p, dims=pb.dims if spatial else None)
        except Exception as exc:  # noqa: BLE001 - one solver's crash is its row, not the end of the table
            rows.append(dict(base, solver=label, status=FAILED, message=f"{type(exc).__name__}: {exc}", time=np.nan,
                             iterations=0, error=np.nan, residual=np.nan))
            continue
        rows.append(dict(base, solver=label, status=sol.status,
                         message=sol.message, time=dt, iterations=sol.iterations, error=err,
                         residual=sol.residual))
    return rows


def _failed_row(path, solver, exc, cf=None) -> dict:
    """The row of a file (or a solver on it) that failed: status -9, the exception as message."""
    msg = str(exc) if isinstance(exc, ValueError) else f"{type(exc).__name__}: {exc}"
    info = dict(dim=cf.dim, contacts=cf.n_contacts, nnz=int(cf.W.nnz), form=cf.form) if cf is not None else \
        dict(dim=0, contacts=0, nnz=0, form="-")
    return dict(file=Path(path).name, **info, warnings="", solver=solver, status=FAILED, message=msg, time=np.nan,
                iterations=0, error=np.nan, residual=np.nan)


_WARM: list = []


def warm_up_planar_solvers():
    """Solve small sparse planar problems (a few contacts, then more than the sparse threshold) with
    every planar solver once, so that numba's compilation or cache loading and the first imports
    are not timed on the first file. Once per process."""
    if _WARM_PLANAR:
        return
    _WARM_PLANAR.append(True)
    import scipy.sparse as sp

    from lcp.contact.problem import ContactProblem

    for k in (2, 150):
        W = sp.csr_matrix(np.kron(np.eye(k), np.array([[2.0, 0.3], [0.3, 1.0]])))
        W = W[:, np.r_[0:2 * k:2, 1:2 * k:2]][np.r_[0:2 * k:2, 1:2 * k:2]]  # normals first
        q = np.concatenate([-np.ones(k), np.full(k, 0.5)])
        pb = ContactProblem(W, q, np.full(k, 0.3))
        for name, limit in SOLVER_LIMITS.items():
            if limit is None or k <= limit:
                make_solver(name).solve(pb)


_WARM_PLANAR: list = []


def warm_up_cone_solvers():
    """Solve small spatial problems as the files give them (sparse W: one contact, a few, more than
    ``auto``'s NSGS limit) with every cone solver once, so that numba's compilation or cache
    loading is not timed on the first file. Once per process."""
    if _WARM:
        return
    _WARM.append(True)
    import scipy.sparse as sp

    from lcp.contact.spatial_problem import ConeContactProblem

    for k in (1, 4, 50):
        W = sp.csr_matrix(np.kron(np.eye(k), np.diag([2.0, 1.0, 1.0])) + 0.1 * np.eye(3 * k, k=3))
        W = W + W.T
        q = np.tile([-1.0, 0.5, -0.2], k)
        pb = ConeContactProblem.from_interleaved(W, q, np.full(k, 0.3), np.full(k, 2))
        for name, limit in CONE_SOLVER_LIMITS.items():
            if limit is None or k <= limit:
                make_cone_solver(name).solve(pb)


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


def run(folder=None, out=None, quick: bool = False, siconos: bool = True) -> dict:
    """Solve every problem of ``folder``; write the CSV and profiles into ``out`` (None: no files).

    ``folder`` None: the built-in problems (:func:`builtin_problems`), written into ``out``'s
    ``problems/`` (a temporary folder when ``out`` is None).
    """
    t_start = time.perf_counter()
    if folder is None:
        if out is None:
            with tempfile.TemporaryDirectory() as tmp:
                return run(builtin_problems(Path(tmp) / "problems")[0].parent, None, quick, siconos)
        folder = builtin_problems(out_dir(out, NAME) / "problems")[0].parent
    files = problem_files(folder)
    rows = []
    for path in files:
        # a bad file is a row of the table, not the end of the study: the reader's ValueError (it
        # names the file and what is wrong) and anything else raised on the way
        try:
            cf = read_problem(path)
        except Exception as exc:  # noqa: BLE001
            rows.append(_failed_row(path, "-", exc))
            continue
        if quick and cf.n_contacts > 500:
            rows.append(dict(file=path.name, dim=cf.dim, contacts=cf.n_contacts, nnz=int(cf.W.nnz), form=cf.form,
                             warnings="", solver="-", status=SKIPPED,
                             message=f"skipped: {cf.n_contacts} contacts > 500 (--quick)", time=np.nan,
                             iterations=0, error=np.nan, residual=np.nan))
            continue
        try:
            rows.extend(solve_file(path, quick=quick, cf=cf))
        except Exception as exc:  # noqa: BLE001
            rows.append(_failed_row(path, "-", exc, cf))
    note = ""
    if siconos and siconos_available():
        todo = [p for p in files if any(r["file"] == p.name and r["solver"] != "-" for r in rows)]
        with tempfile.TemporaryDirectory() as tmp:
            # Siconos's fc2d/fc3d solvers take dense or sparse-block storage of the local form: other
            # files (CSparse storage, global form) are handed over as the same local problem
            # rewritten in sparse-block storage
            given = {}
            for p in todo:
                cf = read_problem(p)  # read above without error
                if cf.form == "global" or cf.storage not in ("dense", "sparse-block"):
                    # Siconos takes a file named .hdf5 for FCLib's format: the text copy ends in .dat
                    q = Path(tmp) / (p.name if p.suffix == ".dat" else p.name + ".dat")
                    write_dat(q, cf, storage="sparse-block")
                    given[str(q)] = p
                else:
                    given[str(p)] = p
            try:
                peer = run_siconos_script(_SICONOS_FILES, [list(given), SOLVED, 2000 if quick else 100000])
            except (RuntimeError, subprocess.TimeoutExpired) as exc:
                peer, note = [], f"Siconos peer failed: {exc}"
        for rec in peer:
            if rec.get("info") == -99:  # the peer could not take the file: its row says so
                path = Path(given.get(rec["path"], rec["path"]))
                rows.append(dict(_failed_row(path, rec["solver"], RuntimeError(rec.get("error_text", "")))))
                continue
            rec["path"] = str(given[rec["path"]])
            cf = read_problem(rec["path"])
            r = np.asarray(rec["r"])
            try:
                err = natural_map_error(cf.W, cf.q, cf.mu, r, order="interleaved",
                                        dims=None if cf.dim == 2 else cf.dims)
            except ValueError:  # e.g. a wrong-sized answer
                err = np.nan
            rows.append(dict(file=Path(rec["path"]).name, dim=cf.dim, contacts=cf.n_contacts, nnz=int(cf.W.nnz),
                             form=cf.form,
                             warnings="", solver=rec["solver"], status=0 if rec["info"] == 0 else -1,
                             message=f"info {rec['info']}, Siconos error {rec['siconos_error']:.3g}",
                             time=rec["time"], iterations=rec["iterations"], error=err, residual=np.nan))
    elif siconos:
        note = "Siconos's Python module is not importable by the system Python: peers skipped"
    res = dict(rows=rows, note=note, files=[])
    if out is not None:
        d = out_dir(out, NAME)
        header = ["file", "dim", "contacts", "nnz", "form", "solver", "status", "time", "iterations", "error",
                  "residual", "message", "warnings"]
        res["files"].append(write_csv(d / "results.csv", header, ([r[h] for h in header] for r in rows)))
        if any(r["solver"] != "-" for r in rows):  # no profile of nothing (every file failed)
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


def print_rows(rows):
    """The table of :func:`run`'s rows on standard output."""
    print(f"{'file':44s} {'d':>1s} {'k':>5s} {'solver':17s} {'st':>3s} {'time (s)':>9s} {'iter':>6s} {'error':>9s}")
    for r in rows:
        print(f"{r['file'][:44]:44s} {r['dim']:1d} {r['contacts']:5d} {r['solver']:17s} {r['status']:3d} "
              f"{r['time']:9.4f} {r['iterations']:6d} {r['error']:9.2e}")


def main(argv=None):
    def extra(p):
        p.add_argument("folder", type=Path, nargs="?", default=None,
                       help="folder of problem files (.dat, .hdf5); default: the built-in problems, "
                            "written into OUT/problems/")
        p.add_argument("--no-siconos", action="store_true", help="do not run the Siconos peer")

    args = parse_args(NAME, __doc__.splitlines()[0], argv, extra)
    if args.folder is None:
        print(f"no folder given: solving the built-in problems, written into {args.out / 'problems'}")
    res = run(args.folder, args.out, args.quick, siconos=not args.no_siconos)
    print_rows(res["rows"])
    if res["note"]:
        print(res["note"])
    print(f"wrote {len(res['files'])} files to {args.out} in {res['seconds']:.1f} s")
    return res


if __name__ == "__main__":
    main()
