"""Optimal control through frictional contact (lcp.ocp): solve time and iterations per problem and N.

Run: ``python benchmarks/ocp.py [--quick]``. Prints a table and writes ``benchmarks/results/ocp.csv``.
The problems are those of ``studies/optimal_control.py`` (Jean-Pratt scene): rest to rest in minimum
time and with minimum effort, and shock avoidance at kappa = 0.95. Each solve starts from the
documented guess (the simulation of u = 0). ``build_s`` is building the NLP and IPOPT once per
problem; ``solve_s`` is the median over repeats of the whole homotopy plus the polishing solve
(the NLP is reused); ``first_call_s`` is the first ``solve`` call, building included. Times are
wall-clock on a shared machine: compare rows within one run.
"""
from __future__ import annotations

import argparse
import csv
import statistics
import time
from pathlib import Path

from lcp.ocp import replay
from studies.optimal_control import (min_effort_bound, min_time_bound, peak_bound, rest_to_rest_problem,
                                     shock_problem)

PROBLEMS = {
    "rest_to_rest_min_time": (lambda N: rest_to_rest_problem(N, "time"), lambda r: r.T, min_time_bound),
    "rest_to_rest_min_effort": (lambda N: rest_to_rest_problem(N, "effort"), lambda r: r.cost, min_effort_bound),
    "shock_avoidance_kappa_0.95": (shock_problem, lambda r: r.peak, peak_bound),
}


def measure(name: str, N: int, repeats: int = 3) -> dict:
    make, value, reference = PROBLEMS[name]
    t0 = time.perf_counter()
    ocp = make(N)
    guess = ocp.guess(u=0.0)
    t_guess = time.perf_counter() - t0
    times, res, first = [], None, None
    for _ in range(repeats):
        t1 = time.perf_counter()
        res = ocp.solve(guess)
        first = time.perf_counter() - t1 if first is None else first
        times.append(res.solve_time)  # the homotopy and polishing solves, without building
    solve = statistics.median(times)
    ref = reference()
    return dict(problem=name, N=N, value=value(res), reference=ref, rel_gap=(value(res) - ref) / ref,
                build_s=ocp.build_time, guess_s=t_guess, first_call_s=first, solve_s=solve,
                ipopt_iterations=res.iterations,
                homotopy_steps=res.homotopy_steps,
                relaxed_residual=[s.residual for s in res.homotopy if s.sigma > 0][-1],
                final_sigma=[s.sigma for s in res.homotopy if s.sigma > 0][-1],
                residual=res.complementarity_residual,
                replay_same_h=replay(res, refine=1).max_error_q, status=res.status)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="N = 10, 20, 40 and one repeat")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = ap.parse_args(argv)
    Ns = (10, 20, 40) if args.quick else (10, 20, 30, 40, 50, 80, 160)
    rows = [measure(name, N, repeats=1 if args.quick else 3) for name in PROBLEMS for N in Ns]
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "ocp.csv"
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(f"{'problem':28s} {'N':>4s} {'value':>9s} {'rel_gap':>9s} {'build(s)':>8s} {'solve(s)':>8s} "
          f"{'IPOPT it':>8s} {'homotopy':>8s} {'sigma':>7s} {'relaxed':>9s} {'residual':>9s} {'replay':>8s} "
          f"{'status':>6s}")
    for r in rows:
        print(f"{r['problem']:28s} {r['N']:4d} {r['value']:9.5g} {r['rel_gap']:9.2e} {r['build_s']:8.3f} "
              f"{r['solve_s']:8.3f} {r['ipopt_iterations']:8d} {r['homotopy_steps']:8d} {r['final_sigma']:7.0e} "
              f"{r['relaxed_residual']:9.1e} {r['residual']:9.1e} "
              f"{r['replay_same_h']:8.1e} {r['status']:6d}")
    print(f"written to {path}")


if __name__ == "__main__":
    main()
