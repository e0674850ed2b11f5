"""Optimal control through frictional contact (lcp.ocp): solve time at equal accuracy, per transcription.

Run: ``python benchmarks/ocp.py [--quick]``. Prints two tables and writes ``benchmarks/out/ocp.csv`` (untracked; pass ``--out`` to write elsewhere).
The problems are those of ``studies/optimal_control.py`` (Jean-Pratt block): rest to rest in minimum
time and with minimum effort, and move-and-hold. Each transcription (``studies.optimal_control.METHODS``:
uniform steps with a linear or a piecewise-constant control, free steps with cross complementarity
and a piecewise-constant or a piecewise-affine control) is solved over a range of N as the study does (uniform steps from the u = 0 simulation, free steps
by the multi-start from it and from the uniform-step solution, whose time is included). The first
table lists every solve (value, relative gap to the closed-form optimum, replay miss of the final
state, success, ``solve_s`` = the homotopy and polishing solves, building excluded, ``total_s`` =
everything the study's solve takes: building, guesses, the multi-start and the replay check that
every solve carries, no further replay). The second, for each
accuracy target, the cheapest successful solve (replay within tolerance) whose gap meets it.
The hold problem at N = 40 (not a multiple of 6) is solved with free steps only, from the uniform
solution at N = 42. Times are wall-clock on a shared machine: compare rows within one run.
"""
from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

from studies.optimal_control import (ALL_METHODS, METHODS, PHASE_METHODS, hold_bound, hold_problem,
                                     min_effort_bound, min_time_bound, rest_to_rest_problem, solve)

PROBLEMS = {
    "min_time": (lambda N, kw: rest_to_rest_problem(N, "time", **kw), lambda r: r.T, min_time_bound),
    "min_effort": (lambda N, kw: rest_to_rest_problem(N, "effort", **kw), lambda r: r.cost, min_effort_bound),
    "hold": (lambda N, kw: hold_problem(N, **kw), lambda r: r.cost, hold_bound),
}
TARGETS = (1e-2, 1e-3, 1e-4, 1e-6)


def measure(name: str, Ns) -> list[dict]:
    make, value, reference = PROBLEMS[name]
    ref = reference()
    rows, uniform = [], {}
    for N in Ns:
        for meth, kw in ALL_METHODS.items():
            if meth in PHASE_METHODS:  # its own first pass on the uniform grid (the hold's ends on it)
                if name == "hold" and N % 6:
                    continue
                t0 = time.perf_counter()
                res = solve(make(N, kw), phases=True)
                rows.append(_bench_row(name, meth, N, value(res), ref, res, time.perf_counter() - t0))
                continue
            free = kw["steps"] == "free"
            if name == "hold" and N % 6:  # the hold's ends are not nodes of the uniform grid: free steps
                if not free:              # only, from the uniform solution at the nearest multiple of 6
                    continue
                if N not in uniform:
                    uniform[N] = solve(make(6 * round(N / 6), METHODS["uniform, constant hold"]))
            t0 = time.perf_counter()
            res = solve(make(N, kw), multistart=free, guess=uniform[N] if free else None)
            total = time.perf_counter() - t0
            if meth == "uniform, constant hold":
                uniform[N] = res
            if free:  # the multi-start needs the uniform-step solve first
                total += uniform[N].solve_time
            rows.append(_bench_row(name, meth, N, value(res), ref, res, total))
    return rows


def _bench_row(name, meth, N, value, ref, res, total) -> dict:
    return dict(problem=name, method=meth, N=N, value=value, reference=ref, rel_gap=(value - ref) / ref,
                final_miss=res.replay.final_miss, replay=res.replay.method, success=res.success,
                solve_s=res.solve_time, build_s=res.build_time, total_s=total, ipopt_iterations=res.iterations)



def _load() -> str:
    try:
        return " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return "n/a"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="fewer N")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "out")
    args = ap.parse_args(argv)
    load0 = _load()
    rows = []
    for name in PROBLEMS:
        if name == "hold":
            Ns = (12, 24, 40, 48) if args.quick else (12, 24, 40, 48, 96)
        else:
            Ns = (10, 20, 40) if args.quick else (10, 20, 40, 80)
        rows += measure(name, Ns)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "ocp.csv"
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(f"{'problem':>10} {'method':>26} {'N':>4} {'value':>12} {'rel_gap':>9} {'miss':>8} {'ok':>3} "
          f"{'solve(s)':>8} {'total(s)':>8} {'IPOPT it':>8}")
    for r in rows:
        print(f"{r['problem']:>10} {r['method']:>26} {r['N']:>4} {r['value']:>12.9g} {r['rel_gap']:>9.2e} "
              f"{r['final_miss']:>8.1e} {'yes' if r['success'] else 'no':>3} {r['solve_s']:>8.3f} "
              f"{r['total_s']:>8.3f} {r['ipopt_iterations']:>8d}")
    print("\nequal accuracy: the cheapest successful solve (replay within tolerance) with |gap| <= target")
    print(f"{'problem':>10} {'target':>7} " + " ".join(f"{m:>28}" for m in ALL_METHODS))
    for name in PROBLEMS:
        for tgt in TARGETS:
            cells = []
            for meth in ALL_METHODS:
                ok = [r for r in rows if r["problem"] == name and r["method"] == meth and r["success"]
                      and abs(r["rel_gap"]) <= tgt]
                best = min(ok, key=lambda r: r["total_s"]) if ok else None
                cells.append(f"N={best['N']:<3d} {best['total_s']:7.2f} s" if best else "not reached")
            print(f"{name:>10} {tgt:>7.0e} " + " ".join(f"{c:>28}" for c in cells))
    print(f"load average before / after: {load0} / {_load()}")
    print(f"written to {path}")


if __name__ == "__main__":
    main()
