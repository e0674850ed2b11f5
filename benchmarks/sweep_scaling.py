"""A sweep of many parameter sets of the event method: serial, and on a LocalCluster of 2 workers.

Run: ``python benchmarks/sweep_scaling.py [--n 100000] [--workers 2] [--quick] [--out DIR]``.
Prints the wall times and writes ``sweep_scaling.csv`` into ``--out`` (default
``benchmarks/out/``, untracked).

The sweep is a grid over the Jean-Pratt parameters (R, v0, phi) with ``lcp.sweep(...,
method="event", n_eval=2)`` (the table keeps the final state; a sweep has no use for 1000 output
times per set). The serial run and the cluster run are timed in the same process, one after the
other; the cluster's start-up (worker processes importing the package) is timed apart and not
counted in the sweep time, since a cluster serves many sweeps. The two tables are compared bit for
bit. Target: the cluster's time within 1.3x of half the serial time.
"""
from __future__ import annotations

import argparse
import csv
import os
import time
from pathlib import Path

import numpy as np

import lcp


def grid(n: int) -> dict:
    k = max(1, round(n ** (1 / 3)))
    return {"R": np.linspace(0.05, 2.5, k), "v0": np.linspace(-2.0, 2.0, k),
            "phi": np.linspace(-15.0, 15.0, max(1, n // (k * k)))}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100_000, help="parameter sets (about)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="2,000 sets")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "out"))
    args = ap.parse_args(argv)
    n = 2000 if args.quick else args.n
    params = grid(n)
    options = dict(t_end=0.5, method="event", n_eval=2, progress=False)
    load0 = os.getloadavg()[0]

    lcp.sweep(lcp.scenes.jean_pratt, grid(200), **options)  # warm, as the cluster is
    t0 = time.perf_counter()
    serial = lcp.sweep(lcp.scenes.jean_pratt, params, **options)
    t_serial = time.perf_counter() - t0

    from dask.distributed import Client, LocalCluster

    import dask

    t0 = time.perf_counter()
    # the cluster lcp.sweep(workers=N) starts: no statistical profiler on the workers
    with dask.config.set({"distributed.worker.profile.enabled": False}), \
            LocalCluster(n_workers=args.workers, threads_per_worker=1, processes=True,
                         dashboard_address=None) as cluster, Client(cluster) as client:
        # a running cluster has imported the package and taken both paths before: warm it the same way
        lcp.sweep(lcp.scenes.jean_pratt, grid(200), client=client, **options)
        t_start = time.perf_counter() - t0
        t0 = time.perf_counter()
        dist = lcp.sweep(lcp.scenes.jean_pratt, params, client=client, **options)
        t_dist = time.perf_counter() - t0
    load1 = os.getloadavg()[0]
    same = serial.equals(dist)
    floats = serial.select_dtypes(float).to_numpy().tobytes() == dist.select_dtypes(float).to_numpy().tobytes()
    ratio = t_dist / (t_serial / args.workers)
    rows = [("serial", len(serial), t_serial, 1.0, ""),
            (f"LocalCluster, {args.workers} workers", len(dist), t_dist, t_serial / t_dist,
             f"{ratio:.2f}x half the serial time (target <= 1.3); cluster start-up {t_start:.1f} s apart")]
    print(f"sweep of {len(serial)} event runs (Jean-Pratt, grid over R, v0, phi), load {load0:.2f} -> {load1:.2f}")
    print(f"{'how':32s} {'rows':>7s} {'wall':>9s} {'speed-up':>9s}  note")
    for how, k, t, s, note in rows:
        print(f"{how:32s} {k:7d} {t:8.2f}s {s:8.2f}x  {note}")
    print(f"tables identical: {same} (floats bit for bit: {floats}); failed rows: {int((~serial.success).sum())}; "
          f"chunk size {dist.attrs['chunk_size']}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "sweep_scaling.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["how", "rows", "seconds", "speedup", "note", "identical", "load_before", "load_after"])
        for how, k, t, s, note in rows:
            w.writerow([how, k, f"{t:.3f}", f"{s:.3f}", note, same and floats, f"{load0:.2f}", f"{load1:.2f}"])
    print(f"wrote {out / 'sweep_scaling.csv'}")


if __name__ == "__main__":
    main()
