"""The event method's ODE phases: the compiled right-hand side against the NumPy one.

    python benchmarks/event_compiled_rhs.py [--quick] [--out DIR]

Systems whose mass matrix, gaps or contacts depend on q (or t) integrate their smooth phases with
DOP853, which evaluates the phase's right-hand side at every stage of every step: by default one
compiled CasADi function per system and branch (:mod:`lcp.events.compiled_branch`); with
``rhs="numpy"`` the system's data, then :class:`lcp.events.modes.PhaseBranch` by NumPy. Each scene is simulated by both, in
alternating rounds (a change of load hits both alike); the table gives the median time per
simulation, the speed-up, the right-hand sides evaluated, and the largest difference of the
states at the output times between the two paths, against the difference of the NumPy path from
itself at rtol ten times tighter (the integration error at the tolerance used): the compiled path
must agree with the NumPy one far inside the integration error.

Writes ``benchmarks/out/event_compiled_rhs.csv`` (untracked; ``--out`` writes elsewhere).
"""
from __future__ import annotations

import argparse
import csv
import os
import statistics
import time
from pathlib import Path

import numpy as np

import lcp
from lcp.events.options import EventOptions
from lcp.scenes.bowl_rod import bowl, impacting_rod
from lcp.scenes.classical import painleve_rod, rocking_block
from lcp.scenes.moving import cam_follower
from lcp.scenes.slider_crank import slider_crank


def scenes():
    """(name, scene) of planar systems whose phases are integrated by DOP853."""
    return [("painleve_rod", painleve_rod()), ("rocking_block", rocking_block()), ("bowl", bowl()),
            ("impacting_rod", impacting_rod()), ("cam_follower", cam_follower()), ("slider_crank", slider_crank())]


def run(scene, compiled: bool, rtol: float | None = None):
    """(seconds, result) of one event simulation at 200 output times."""
    t = np.linspace(0.0, scene.t_end, 201)
    kw = ({} if rtol is None else {"rtol": rtol}) | {"rhs": "compiled" if compiled else "numpy"}
    t0 = time.perf_counter()
    r = lcp.simulate(scene, method="event", t_eval=t, **kw)
    return time.perf_counter() - t0, r


def states(r) -> np.ndarray:
    return np.hstack([r.q, r.v])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="3 rounds instead of 9")
    ap.add_argument("--out", default=str(Path(__file__).parent / "out"))
    args = ap.parse_args(argv)
    rounds = 3 if args.quick else 9
    rows = []
    print(f"load average {os.getloadavg()[0]:.2f}")
    print(f"{'scene':15s} {'NumPy s':>9s} {'compiled s':>10s} {'speed-up':>8s} {'rhs':>7s} "
          f"{'|compiled - NumPy|':>18s} {'NumPy at rtol/10':>17s} {'same events':>11s}")
    for name, sc in scenes():
        run(sc, True), run(sc, False)  # builds and first calls outside the clock
        times = {True: [], False: []}
        res = {}
        for _ in range(rounds):
            for compiled in (True, False):
                dt, res[compiled] = run(sc, compiled)
                times[compiled].append(dt)
        a, b = res[True], res[False]
        if not (a.success and b.success):
            raise SystemExit(f"{name}: a simulation failed: {a.message} / {b.message}")
        tight = run(sc, False, rtol=EventOptions().rtol / 10)[1]
        diff = float(np.max(np.abs(states(a) - states(b))))
        err = float(np.max(np.abs(states(tight) - states(b))))
        same = [(e.kind, e.contact) for e in a.events] == [(e.kind, e.contact) for e in b.events]
        tn, tc = statistics.median(times[False]), statistics.median(times[True])
        nfev = sum(p.nfev for p in a.phases)
        rows.append({"scene": name, "numpy_s": tn, "compiled_s": tc, "speedup": tn / tc, "rhs_evaluations": nfev,
                     "paths_differ_by": diff, "numpy_vs_tighter_rtol": err, "same_events": same,
                     "events": len(a.events), "load": os.getloadavg()[0]})
        print(f"{name:15s} {tn:9.4f} {tc:10.4f} {tn / tc:8.2f} {nfev:7d} {diff:18.2e} {err:17.2e} {str(same):>11s}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "event_compiled_rhs.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {out / 'event_compiled_rhs.csv'}")


if __name__ == "__main__":
    main()
