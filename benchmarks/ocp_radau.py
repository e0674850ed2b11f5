"""Radau IIA collocation in the optimal-control transcription against the theta step and nosnoc.

Run: ``python benchmarks/ocp_radau.py [--out DIR] [example ...]``. For nosnoc's friction examples of
``studies/_ocp_models.py`` (motor N = 30, cart-pole N = 20, block chain K = 2 N = 20), in one run:
the example's own problem (the default theta transcription), the same problem with
``integrator="radau"``, ``steps="free"`` and s = 2, 3 stages, and nosnoc 0.2.0 where it is installed
and has the example. Per row: status, objective, ``J_replay`` (the example's continuous cost on a
Moreau-Jean replay of the control, :func:`studies.ocp_examples.score`), the final-state replay miss
(ours: ``result.replay``, the event method; nosnoc's: its control replayed by the package's event
method against its own final state) and the wall time (solve and replay check; nosnoc's total
time). Writes ``ocp_radau.csv`` into ``benchmarks/out/`` (untracked).
"""
from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path

import numpy as np

from lcp.ocp import OptimalControlProblem
from studies import ocp_examples as oe
from studies._ocp_models import EXAMPLES

CASES = (("motor", 30), ("cart_pole", 20), ("block_chain2", 20))
CONFIGS = (("theta (default)", None), ("radau s=2 free", {"integrator": "radau", "stages": 2, "steps": "free"}),
           ("radau s=3 free", {"integrator": "radau", "stages": 3, "steps": "free"}))


def _ours(ex, N, kw):
    pb0 = ex.make(N)
    pb = pb0 if kw is None else OptimalControlProblem(
        pb0.system, N, T=pb0.T, q0=pb0.q0, v0=pb0.v0, stage_cost=pb0.stage_cost, terminal_cost=pb0.terminal_cost,
        terminal_constraints=pb0.terminal_constraints, path_constraints=pb0.path_constraints, **kw)
    t0 = time.perf_counter()
    r = pb.solve(**ex.solve_kw)
    dt = time.perf_counter() - t0
    return {"status": r.status, "objective": r.cost, "J_replay": oe.score(ex, r.control, N),
            "miss": r.replay.final_miss if r.replay is not None else float("nan"), "time_s": dt}


def _nosnoc(ex, N):
    from studies import _nosnoc_examples as peers

    if ex.name not in peers.PEERS or not peers.available():
        return None
    pr = peers.solve_peer(ex.name, N)
    qf, vf, _ = oe.replay_control(ex, pr.control)
    return {"status": str(pr.status), "objective": pr.objective, "J_replay": oe.score(ex, pr.control, N),
            "miss": float(np.max(np.abs(ex.common_state(qf, vf) - pr.x_final))), "time_s": pr.total_time}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("examples", nargs="*", help="example names (default: motor, cart_pole, block_chain2)")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "out"))
    args = ap.parse_args(argv)
    rows = []
    print(f"{'example':>13} {'N':>3} {'transcription':>16} {'status':>8} {'objective':>12} {'J_replay':>12} "
          f"{'miss':>9} {'time[s]':>8}")
    for name, N in CASES:
        if args.examples and name not in args.examples:
            continue
        ex = EXAMPLES[name]()
        runs = [(label, _ours(ex, N, kw)) for label, kw in CONFIGS]
        peer = _nosnoc(ex, N)
        if peer is not None:
            runs.append(("nosnoc 0.2.0", peer))
        for label, row in runs:
            rows.append({"example": name, "N": N, "transcription": label, **row})
            print(f"{name:>13} {N:>3} {label:>16} {str(row['status'])[:8]:>8} {row['objective']:>12.6g} "
                  f"{row['J_replay']:>12.6g} {row['miss']:>9.2e} {row['time_s']:>8.2f}", flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "ocp_radau.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]) if rows else ["example"])
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {out / 'ocp_radau.csv'}")


if __name__ == "__main__":
    main()
