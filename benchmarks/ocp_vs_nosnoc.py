"""Optimal control through frictional contact: lcp.ocp against nosnoc (FESD, IPOPT) at equal accuracy.

Run: ``python benchmarks/ocp_vs_nosnoc.py [--quick] [--out DIR]``. Prints three tables and writes
``benchmarks/out/ocp_vs_nosnoc.csv`` (untracked). Needs nosnoc (``pip install "lcp-lem[ocp-peers]"``);
without it the script says so and exits 0.

The problems are those of ``studies/optimal_control.py`` (Jean-Pratt block, |u| <= 20 N): rest to rest
in minimum time and with minimum effort, and move-and-hold. nosnoc poses them as a two-region Filippov
system in (x, v) (``studies/_nosnoc_peer.py``): N equal control stages with u constant on each, RADAU IIA
with n_s = 2 and 2 free finite elements per stage (FESD), Scholtes homotopy from sigma = 1 by factors
of 0.1 to a complementarity tolerance 1e-10, IPOPT at 1e-12. Each nosnoc control is replayed open loop
by the package's event-driven integrator on the study's System (one call over the horizon), giving the
final-state miss (replay against nosnoc's own final state, the study's ``final_miss``) and the hold's
violation. The package's solves are those of ``benchmarks/ocp.py`` (its ``measure``: every transcription
and solve of ``studies.optimal_control.ALL_METHODS``, including the fixed-phase solves, at nosnoc's N and
at N = 4, 6 (6 for the hold)).

Tables: (1) every solve; (2) for each nosnoc solve, the cheapest successful package solve whose |gap| to
the closed-form optimum AND replay miss are both at most nosnoc's (gaps within 1e-9 of each other and
misses below 1e-10 count as equal: solver tolerance and round-off), and the time ratio nosnoc / package
(> 1: the package is faster); (3) nosnoc from three control guesses (u = -20, 0, 20 N) at one N, to see
whether it lands on distinct optima while reporting SUCCESS. Times: nosnoc ``total_s`` = building
(model, NLP, IPOPT set-up) + the homotopy, replay excluded; the package's ``total_s`` = everything its
study solve takes (building, guesses, multi-start, and its own replay check). Wall-clock on a shared
machine: compare within one run; the load average is printed.

(4) the examples of ``studies/ocp_examples.py`` (a point on a plane through a spatial contact,
two- and seven-block chains (nosnoc_py has no seven-block example: ``studies/_nosnoc_examples.py``
writes it in the Stewart form of its two-block one), nosnoc_py's motor and cart-pole with friction,
nosnoc_py's hopper and two discs, a box tipped over an edge, a ball bounced to a height):
per example and N, the package's objective, replay miss (and method), success
and time, nosnoc's status, replay miss of its control through the package's event method and time,
both controls scored by the same continuous cost on a replay (``J_replay``), and the time ratio
nosnoc / package within the run. Written to ``ocp_vs_nosnoc_examples.csv``. ``--only-examples`` runs
this table alone.
"""
from __future__ import annotations

import argparse
import csv
import importlib.util
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
METHOD = "nosnoc FESD, RADAU IIA n_s=2, 2 FE/stage"
STARTS = (-20.0, 0.0, 20.0)
#: "equal" accuracy up to the solvers' tolerances: relative gaps within GAP_TOL of each other, and
#: replay misses below MISS_FLOOR (round-off and IPOPT's tolerance) counted as equal
GAP_TOL = 1e-9
MISS_FLOOR = 1e-10
#: the speed-up asked of the package over nosnoc at equal or better accuracy
TARGET_RATIO = 5.0


def _load() -> str:
    try:
        return " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return "n/a"


def _package_measure():
    """``measure`` of benchmarks/ocp.py (loaded from its file: benchmarks is not a package)."""
    spec = importlib.util.spec_from_file_location("benchmarks_ocp", HERE / "ocp.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod.measure


def _nosnoc_row(peer, problem, N, u_guess=0.0, role="sweep"):
    return {"solver": "nosnoc", "method": METHOD, "role": role, **peer.solve_and_replay(problem, N, u_guess)}


def _match(row, package_rows):
    """The cheapest successful package solve with |gap| and replay miss both <= the nosnoc row's
    (up to GAP_TOL and MISS_FLOOR)."""
    ok = [r for r in package_rows if r["problem"] == row["problem"] and r["success"]
          and abs(r["rel_gap"]) <= abs(row["rel_gap"]) + GAP_TOL
          and r["final_miss"] <= max(row["final_miss"], MISS_FLOOR)]
    return min(ok, key=lambda r: r["total_s"]) if ok else None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer N")
    ap.add_argument("--out", type=Path, default=HERE / "out")
    ap.add_argument("--only-examples", action="store_true", help="only table (4), the examples of studies/ocp_examples.py")
    args = ap.parse_args(argv)
    if args.only_examples:
        return examples_table(args)
    from studies import _nosnoc_peer as peer

    if not peer.available():
        print("nosnoc is not installed (pip install 'lcp-lem[ocp-peers]'): nothing to compare")
        return 0
    from importlib.metadata import version as _version

    from studies.optimal_control import rest_to_rest_problem, solve

    measure = _package_measure()
    version = _version("nosnoc")
    Ns = {"min_time": (10, 20) if args.quick else (10, 20, 40),
          "min_effort": (10, 20) if args.quick else (10, 20, 40),
          "hold": (12, 24) if args.quick else (12, 24, 48)}
    load0 = _load()
    # warm-up of both (imports, first CasADi/IPOPT set-up, the event integrator), not recorded
    peer.replay_nosnoc(peer.solve_nosnoc("min_time", 4))
    solve(rest_to_rest_problem(4, "time"))
    nos, pkg, starts = [], [], []
    for problem, Ns_p in Ns.items():
        for N in Ns_p:
            nos.append(_nosnoc_row(peer, problem, N))
        # the package also at smaller N: its fixed-phase and free-step solves are exact from there
        Ns_pkg = ((6,) if problem == "hold" else (4, 6)) + tuple(Ns_p)
        pkg += [{"solver": "lcp.ocp", "role": "sweep", **r} for r in measure(problem, Ns_pkg)]
        N_start = Ns_p[1]
        for ug in STARTS:
            starts.append(_nosnoc_row(peer, problem, N_start, u_guess=ug, role="start"))
    load1 = _load()
    for r in nos:
        m = _match(r, pkg)
        r.update(match_method=m["method"] if m else "", match_N=m["N"] if m else "",
                 match_rel_gap=m["rel_gap"] if m else float("nan"), match_final_miss=m["final_miss"] if m else float("nan"),
                 match_total_s=m["total_s"] if m else float("nan"),
                 time_ratio=r["total_s"] / m["total_s"] if m else float("nan"))

    rows = nos + starts + pkg
    cols = []
    for r in rows:
        cols += [c for c in r if c not in cols]
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "ocp_vs_nosnoc.csv"
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=cols + ["load_before", "load_after", "nosnoc_version"], restval="")
        w.writeheader()
        for r in rows:
            w.writerow({**r, "load_before": load0, "load_after": load1, "nosnoc_version": version})

    print(f"(1) every solve ({METHOD}; lcp.ocp: the study's transcriptions)")
    print(f"{'problem':>10} {'solver / method':>42} {'N':>3} {'value':>13} {'rel_gap':>9} {'miss':>8} {'hold':>8} "
          f"{'status':>8} {'total(s)':>8} {'IPOPT it':>8}")
    for r in nos + pkg:
        meth = r["method"] if r["solver"] == "lcp.ocp" else "nosnoc"
        ok = r["status"] if r["solver"] == "nosnoc" else ("yes" if r["success"] else "no")
        hv = r.get("hold_violation", float("nan"))
        print(f"{r['problem']:>10} {meth:>42} {r['N']:>3} {r['value']:>13.10g} {r['rel_gap']:>9.2e} "
              f"{r['final_miss']:>8.1e} {hv:>8.1e} {ok:>8} {r['total_s']:>8.3f} {r['ipopt_iterations']:>8d}")
    print(f"\n(2) equal accuracy: the cheapest successful lcp.ocp solve with |gap| <= nosnoc's (+{GAP_TOL:g}) "
          f"and miss <= max(nosnoc's, {MISS_FLOOR:g})")
    print(f"{'problem':>10} {'N':>3} {'nosnoc gap':>10} {'miss':>8} {'time(s)':>8} | {'lcp.ocp method':>26} {'N':>3} "
          f"{'gap':>9} {'miss':>8} {'time(s)':>8} {'nosnoc/lcp':>10}")
    for r in nos:
        if r["match_method"]:
            rhs = (f"{r['match_method']:>26} {r['match_N']:>3} {r['match_rel_gap']:>9.2e} {r['match_final_miss']:>8.1e} "
                   f"{r['match_total_s']:>8.3f} {r['time_ratio']:>10.2f}")
        else:
            rhs = f"{'none at these N':>26}"
        print(f"{r['problem']:>10} {r['N']:>3} {r['rel_gap']:>10.2e} {r['final_miss']:>8.1e} {r['total_s']:>8.3f} | {rhs}")
    print(f"\n    per problem, the smallest ratio over nosnoc's solves (target >= {TARGET_RATIO:g}):")
    for problem in Ns:
        ratios = [r["time_ratio"] for r in nos if r["problem"] == problem]
        worst = min(ratios) if ratios else float("nan")
        print(f"{problem:>14}: {worst:6.2f}x  ({'met' if worst >= TARGET_RATIO else 'NOT met'}); "
              f"all: {', '.join(f'{x:.1f}' for x in ratios)}")
    print("\n(3) nosnoc from three control guesses (SUCCESS at distinct optima would show here)")
    for problem in Ns:
        rr = [r for r in starts if r["problem"] == problem]
        vals = ", ".join(f"u0={r['u_guess']:+g}: {r['value']:.10g} {r['status']} ({r['ipopt_status']})" for r in rr)
        spread = max(r["value"] for r in rr) - min(r["value"] for r in rr)
        print(f"{problem:>10} N={rr[0]['N']}: {vals}; spread {spread:.1e}")
    errors = [r for r in nos + starts if r["replay_error"]]
    for r in errors:
        print(f"replay failed: {r['problem']} N={r['N']}: {r['replay_error']}")
    print(f"load average before / after: {load0} / {load1}")
    print(f"written to {path}")
    return examples_table(args)


def examples_table(args) -> int:
    """Table (4): the examples of studies/ocp_examples.py, ours against nosnoc in one run."""
    from studies import ocp_examples

    load0 = _load()
    out = ocp_examples.run(out=args.out / "ocp_examples", quick=args.quick)
    load1 = _load()
    rows = out["rows"]
    path = args.out / "ocp_vs_nosnoc_examples.csv"
    cols = list(dict.fromkeys(c for r in rows for c in r))
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=cols + ["load_before", "load_after"], restval="")
        w.writeheader()
        for r in rows:
            w.writerow({**r, "load_before": load0, "load_after": load1})
    print(f"\n(4) the examples of studies/ocp_examples.py; success needs the replay within "
          f"{ocp_examples.REPLAY_TOL:g}; J_replay: one continuous cost on a replay of each control")
    print(f"{'example':>15} {'N':>4} | {'ok':>3} {'J_replay':>12} {'miss':>9} {'time(s)':>7} | {'nosnoc':>8} "
          f"{'J_replay':>12} {'miss':>9} {'time(s)':>7} | {'nosnoc/lcp':>10}")
    for r in rows:
        print(f"{r['example']:>15} {r['N']:>4} | {'yes' if r['ours_success'] else 'no':>3} {r['ours_J_replay']:>12.6g} "
              f"{r['ours_miss']:>9.2e} {r['ours_time']:>7.2f} | {r['nosnoc_status'][:8] or 'n/a':>8} "
              f"{r['nosnoc_J_replay']:>12.6g} {r['nosnoc_miss']:>9.2e} {r['nosnoc_time']:>7.2f} | {r['time_ratio']:>10.2f}")
    for r in rows:
        if r["nosnoc_note"] and r["N"] == min(x["N"] for x in rows if x["example"] == r["example"]):
            print(f"{r['example']}: no nosnoc row: {r['nosnoc_note']}")
    print(f"load average before / after: {load0} / {load1}")
    print(f"written to {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
