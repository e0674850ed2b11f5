"""The event method's mode enumeration split by components of W's coupling, against the whole one.

    python benchmarks/mode_components.py [--quick] [--out DIR]

K unit blocks, each on its own floor contact (a stick candidate), pressed by its weight and pushed
sideways below the friction bound: W is block-diagonal, the contacts are K components. For K = 2 ..
7 (``--quick``: up to 5) one acceleration problem is enumerated by
:func:`lcp.events.modes.enumerate_branches` as it runs in the event method (per component) and
with the split switched off (the whole product of 4^K branches); the table gives the branches
solved, the time per enumeration (best of 3) and whether the two return the same solutions bit for
bit. A second case adds a third contact type: every other block slides (its branches are open or
closed), so the whole product is 4^(K/2) 2^(K/2).

Writes ``benchmarks/out/mode_components.csv`` (untracked; ``--out`` writes elsewhere).
"""
from __future__ import annotations

import argparse
import csv
import time
from pathlib import Path
from unittest import mock

import numpy as np

from lcp.events import modes
from lcp.events.model import StateData
from lcp.events.modes import AccelProblem, enumerate_branches

G = 9.81


def blocks(K: int, sliding: bool) -> AccelProblem:
    """K blocks (x, y each), one floor contact each: normal row e_y, tangent row e_x."""
    n = 2 * K
    H = np.zeros((2 * K, n))
    for j in range(K):
        H[j, 2 * j + 1] = 1.0
        H[K + j, 2 * j] = 1.0
    rng = np.random.default_rng(K)
    F = np.zeros(n)
    F[1::2] = -G
    F[0::2] = rng.uniform(-0.2, 0.2, K) * G  # below mu g: the stick candidates stick
    slide = np.where((np.arange(K) % 2 == 1) & sliding, 1.0, 0.0)
    data = StateData(np.eye(n), F, np.zeros((0, n)), np.zeros(0), H, np.zeros(2 * K), np.zeros(K))
    return AccelProblem(data, np.arange(K), slide, np.full(K, 0.4), flush=True)


def best_of(f, repeats: int = 3):
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = f()
        times.append(time.perf_counter() - t0)
    return min(times), out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="K up to 5")
    ap.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "out")
    args = ap.parse_args(argv)
    rows = []
    for sliding in (False, True):
        for K in range(2, 6 if args.quick else 8):
            acc = blocks(K, sliding)
            t_split, (sols, tried) = best_of(lambda: enumerate_branches(acc))
            with mock.patch.object(modes, "coupling_components", lambda a: [np.arange(a.k)]):
                t_whole, (ref, tried_whole) = best_of(lambda: enumerate_branches(acc))
            same = ([s.modes for s in sols] == [s.modes for s in ref]
                    and all(np.array_equal(s.p, r.p) and np.array_equal(s.qdd, r.qdd) for s, r in zip(sols, ref)))
            rows.append(dict(K=K, sliding="every other" if sliding else "none", branches_split=tried,
                             branches_whole=tried_whole, ms_split=1e3 * t_split, ms_whole=1e3 * t_whole,
                             solutions=len(sols), same_bits=same))
    print("| K | sliding | branches (split / whole) | ms (split / whole) | solutions | same bits |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['K']} | {r['sliding']} | {r['branches_split']} / {r['branches_whole']} | "
              f"{r['ms_split']:.2f} / {r['ms_whole']:.1f} | {r['solutions']} | {r['same_bits']} |")
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "mode_components.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


if __name__ == "__main__":
    main()
