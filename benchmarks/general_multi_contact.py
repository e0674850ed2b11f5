"""Per-step cost of steps with several active planar contacts in the compiled general loop.

Run: ``python benchmarks/general_multi_contact.py [--repeats N]``. Prints a table and writes
``benchmarks/recorded/general_multi_contact.csv``.

Scenes (non-constant planar systems whose steps have two or more active contacts): Housner's
rocking block (``lcp.classical.rocking_block``) while it rocks (1.5 s from its release; few
two-contact steps) and at rest on both corners (2000 steps from its state at t = 3 s: two active
contacts every step, Newton's matrix singular), the box pushed on its two corners
(``box_on_corners``, 1.2 s, sliding), the slider-crank with clearance (0.05 s, h = 1e-5, four
corners). For each: the Python loop (``fast=False``), the compiled general loop as it was before
these steps ran in its kernel (every step with two or more active planar contacts handed to the
Python contact step: the kernel switched off by ``general_loop._planar_multi`` returning zeros)
and the compiled loop now (``lcp.timestepping.planar_multi_kernels``), each warm (kernel and C
library cached) and the median of ``--repeats`` runs; then the counts of steps solved in the
kernel and handed back to Python, and the largest difference of q from the Python loop's
(relative to max |q|; 0 means the same bits).
"""
from __future__ import annotations

import argparse
import csv
import os
from pathlib import Path
import statistics
import sys
import time

import numpy as np

# this script times the compiled loops: its short runs must not take the Python loop while a
# kernel is not loaded yet (lcp.timestepping.first_compile)
os.environ.setdefault("LCP_COMPILE", "always")


ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def scenes():
    """name -> (system, q0, v0, h, steps)."""
    import lcp
    from lcp.scenes.classical import box_on_corners, rocking_block
    from lcp.scenes.slider_crank_clearance import slider_crank_clearance

    rb = rocking_block()
    rest = lcp.simulate(rb, 3.0, h=1e-3)  # the start of the resting phase (compiled: quick)
    box, scc = box_on_corners(), slider_crank_clearance()
    return {
        "rocking block, rocking": (rb.system, rb.q0, rb.v0, 1e-3, 1500),
        "rocking block, at rest": (rb.system, rest.q[-1].copy(), rest.v[-1].copy(), 1e-3, 2000),
        "box on corners": (box.system, box.q0, box.v0, 1e-3, 1200),
        "slider-crank clearance": (scc.system, scc.q0, scc.v0, 1e-5, 5000),
    }


def timed(system, q0, v0, h, steps, fast):
    import lcp

    t0 = time.perf_counter()
    res = lcp.simulate(system, steps * h, h=h, q0=q0, v0=v0, fast=fast)
    return time.perf_counter() - t0, res


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    from lcp.timestepping import general_loop

    now = general_loop._planar_multi

    def before(solver, asm):
        return np.zeros(4, dtype=np.int64)

    rows = []
    print(f"{'scene':24s} {'steps':>6s} {'python us':>10s} {'before us':>10s} {'now us':>8s} {'vs before':>9s} "
          f"{'vs python':>9s} {'kernel':>7s} {'python':>7s} {'max rel dq':>10s}")
    for name, (system, q0, v0, h, steps) in scenes().items():
        t_py, ref = timed(system, q0, v0, h, steps, False)
        out = {}
        for label, choice in (("before", before), ("now", now)):
            general_loop._planar_multi = choice
            timed(system, q0, v0, h, 10, True)  # warm: library and kernel cached
            ts = [timed(system, q0, v0, h, steps, True) for _ in range(args.repeats)]
            out[label] = (statistics.median(t for t, _ in ts), ts[-1][1])
        general_loop._planar_multi = now
        res = out["now"][1]
        dq = float(np.max(np.abs(res.q - ref.q)) / np.max(np.abs(ref.q)))
        py, bf, nw = (t / steps * 1e6 for t in (t_py, out["before"][0], out["now"][0]))
        st = res.stats
        print(f"{name:24s} {steps:6d} {py:10.1f} {bf:10.1f} {nw:8.2f} {bf / nw:9.1f} {py / nw:9.0f} "
              f"{st.kernel_multi_steps:7d} {st.python_steps:7d} {dq:10.2e}")
        rows.append(dict(scene=name, steps=steps, h=h, python_us_per_step=f"{py:.2f}",
                         before_us_per_step=f"{bf:.2f}", now_us_per_step=f"{nw:.3f}",
                         speedup_vs_before=f"{bf / nw:.1f}", speedup_vs_python=f"{py / nw:.0f}",
                         kernel_multi_steps=st.kernel_multi_steps, python_steps=st.python_steps,
                         before_python_steps=out["before"][1].stats.python_steps, max_rel_dq=f"{dq:.2e}"))
    path = ROOT / "benchmarks" / "recorded" / "general_multi_contact.csv"
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    print(f"wrote {path.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
