"""Work-precision benchmark: wall time against error for every method on four Jean-Pratt scenes.

Run: ``python benchmarks/work_precision.py [--quick] [--out DIR] [--figures DIR] [--h-min-python H]``.
Prints one table per scene (markdown) and the summary, and writes into ``benchmarks/out/`` (untracked):
``work_precision_<scene>.csv`` (scenes: default, reverse, near_shock, loaded_stick),
``work_precision_summary.csv`` and ``work_precision_creep.csv``. ``--figures DIR`` also draws the
figures of ``python -m studies.work_precision`` (which runs the same measurements) into DIR.

What is measured, and how every error is defined, is documented in :mod:`studies.work_precision`.
Times are medians of repeats after a warm-up call, all in one run, so ratios between methods are
meaningful on a shared machine; the load average is printed with the results.
"""
from __future__ import annotations

import argparse
import math
import os
import platform
import sys
import time
from pathlib import Path

from studies import work_precision as wp
from studies._common import write_csv


def fmt(x, spec=".2e"):
    if x == "" or x is None:
        return ""
    try:
        v = float(x)
    except (TypeError, ValueError):
        return str(x)
    if math.isnan(v):
        return "never" if spec == "stop" else "n/a"
    return format(v, ".2e" if spec == "stop" else spec)


def table(rows, key) -> str:
    out = [f"#### {wp.SCENE_LABELS[key]}", "",
           "| method | parameters | time (s) | e_max | e_final | stop-time error (s) | max \\|y\\| | status |",
           "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if r["scene"] != key:
            continue
        params = r["params"].replace("|", "/")
        if r["family"] == "moreau-jean":
            params = f"h={r['h']:g}"
        out.append(f"| {r['method']} | {params} | {fmt(r['time_s'], '.3g')} | {fmt(r['e_max'])} | {fmt(r['e_final'])} "
                   f"| {fmt(r['stop_err'], 'stop')} | {fmt(r['max_y'], '.1e')} | {r['status']}"
                   + (f" ({r['note']})" if r["status"] not in (0, "0") or "SILENTLY" in str(r["note"]) else "") + " |")
    return "\n".join(out)


def summary_table(summary) -> str:
    out = ["| scene | best package e_max | best tanh-baseline e_max | package ahead at every accuracy < 1e-6 | "
           "smallest speed-up there | Moreau-Jean alone ahead | its smallest speed-up |", "|---|---|---|---|---|---|---|"]
    for k, s in summary.items():
        out.append(f"| {k} | {fmt(s['best_package_e_max'])} | {fmt(s['best_baseline_e_max'])} | "
                   f"{'yes' if s['package_ahead_below_target'] else 'NO'} | {fmt(s['min_speedup'], '.3g')} | "
                   f"{'yes' if s['moreau_jean_ahead_below_target'] else 'no'} | "
                   f"{fmt(s['moreau_jean_min_speedup'], '.3g')} |")
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the study's quick settings (about 30 s)")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "out")
    ap.add_argument("--figures", type=Path, default=None, help="also write the figures into this folder")
    ap.add_argument("--h-min-python", type=float, default=None,
                    help="smallest h for the Python-loop solvers (default 1e-5 for theta = 1/2, 1e-4 for theta = 1)")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    load0 = os.getloadavg()
    over = {}
    if args.h_min_python is not None:
        over["h_min_python"] = {0.5: args.h_min_python, 1.0: args.h_min_python}
    rows, messages = wp.sweep(args.quick, log=lambda m: print(m, file=sys.stderr, flush=True), **over)
    summary = wp.summarize(rows)
    cr = wp.creep(args.quick)
    load1 = os.getloadavg()
    args.out.mkdir(parents=True, exist_ok=True)
    files = wp.write_tables(rows, summary, args.out)
    files.append(write_csv(args.out / "work_precision_creep.csv", ["method", "eps", "t", "error", "drift"],
                           [[s["method"], s["eps"], float(t), float(e), float(d)]
                            for s in cr["series"] for t, e, d in zip(s["t"], s["err"], s["drift"])]))
    if args.figures is not None:
        args.figures.mkdir(parents=True, exist_ok=True)
        files.append(wp.figure(rows, summary, "e_max", args.figures / "work_precision.png", "e_max = max |x - exact|"))
        files.append(wp.figure(rows, summary, "e_final", args.figures / "work_precision_final.png",
                               "e_final = |x(T) - exact|"))
        files.append(wp.figure(rows, summary, "stop_err", args.figures / "work_precision_stop.png",
                               "stop-time error (s)"))
        files.append(wp.creep_figure(cr, args.figures / "creep.png"))
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; "
          f"load average (1, 5, 15 min) before {tuple(round(x, 2) for x in load0)}, "
          f"after {tuple(round(x, 2) for x in load1)}")
    for m in messages:
        print(m)
    for key in wp.SCENE_LABELS:
        print()
        print(table(rows, key))
    print()
    print(summary_table(summary))
    print()
    print(f"creep (loaded stick, T = {cr['T']:g} s): error at T and drift since t1 = tau0 + 0.05 s")
    for s in cr["series"]:
        print(f"  {s['method']:38s} eps={fmt(s['eps'], 'g'):8s} |x(T) - exact| = {fmt(s['err'][-1])}  "
              f"drift = {fmt(s['drift'][-1])}  predicted creep drift = "
              + (fmt(s['eps'] * cr['rate_per_eps'] * (cr['T'] - cr['t1'])) if s['eps'] != "" else "0"))
    print(f"\nwrote {len(files)} files to {args.out} in {time.perf_counter() - t0:.0f} s")
    return rows, summary, cr


if __name__ == "__main__":
    main()
