"""Cold start: what a parameter study pays per new parameter set, and what `import lcp` costs.

Run: ``python benchmarks/cold_start.py [--quick] [--out DIR]``. Prints a table and writes
``cold_start.csv`` into ``--out`` (default ``benchmarks/out/``, untracked).

``--first-compile`` measures instead what a user's first short run of a non-constant system costs
on a machine where the compiled general loop's numba kernel was never compiled
(:mod:`lcp.timestepping.first_compile`): fresh interpreters with empty compiled-code and numba
caches (temporary folders), a point in a circular bowl (``benchmarks/general_compiled.py``'s
``bowl``, h = 1e-3, ``--steps`` steps, 300 by default). Timed, each from the ``simulate`` call:
(1) ``LCP_COMPILE=always`` (the compiled loop waits for the compilation: the behaviour before);
(2) the default: the Python loop, the kernel compiled in a background process, whose wall time
to its end is reported too; then fresh interpreters: (3) the same short run (the kernel cached
but not loaded: the Python loop), (4) a run of ``--long`` steps (5,000: the kernel loaded from
numba's cache, the bowl's C code compiled, a new structure), (5) the same (everything cached),
(6) the same by the Python loop (``fast=False``). Writes ``first_compile.csv``.

Per parameter set a study builds a new scene and runs it once, so the cost that matters is the
cold one: scene construction plus a run on that new scene. Measured here, on the Jean-Pratt scene
with a new friction coefficient every call (R = 0.5 + 1e-6 i, so nothing can be reused from an
earlier set):

- ``import lcp`` in a fresh interpreter (median of several subprocesses; the interpreter's own
  start-up is measured alone and subtracted);
- a new scene, alone;
- a new scene plus an event-driven run of 0.3 s (1000 output times), with its error against the
  exact solution;
- the tanh-regularized LSODA run of the same scene (eps = 1e-12, rtol = 1e-13, atol = 1e-16: the
  setting ``event_vs_lsoda.py`` found to reach LSODA's best error) with its error;
- a new scene plus a Moreau-Jean run of 0.3 s at h = 1e-3;
- the same runs on a scene reused (warm), for reference.

The timed calls alternate in rounds, one block of ``BLOCK`` consecutive calls of each kind per round
(a sweep runs the same code back to back, so each kind is timed with its code and data in the
caches, as it would be there), and each figure is the median over the rounds of the time per call,
so a change of load on the shared machine hits all of them alike; ratios are within one run. On a
busy machine a long block (LSODA: 10 calls of about 2 ms) is preempted more often than a short
one (10 event runs of 0.2 ms), which flatters the short one's ratio; the ratio of the fastest
blocks (least disturbed) is printed beside the ratio of the medians, and the load before and after.

The target's own measure is call by call: ``CALLS`` pairs (a new scene plus an event run, then the
LSODA run of that scene), each call timed alone, alternating, so that each call finds the caches
as the other kind left them (the harder case for the short call). Reported: the fastest call and
the 10th percentile of each kind, in wall-clock time and in CPU time of the thread
(``time.thread_time``, which a preemption by another process does not inflate), with the ratios.
"""
from __future__ import annotations

import argparse
import csv
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import lcp

sys.path.insert(0, str(Path(__file__).resolve().parent))
from event_vs_lsoda import lsoda_tanh  # noqa: E402  (the same baseline as the event benchmark)

T = 0.3
EPS, RTOL = 1e-12, 1e-13
#: consecutive calls of one kind per timed block (a sweep runs the same code back to back)
BLOCK = 10
#: alternating pairs (event, LSODA) timed call by call
CALLS = 400


def import_time(repeats: int) -> tuple[float, float]:
    """(median seconds of `import lcp` beyond the bare interpreter, median bare start-up)."""
    code = "import time; t = time.perf_counter(); import lcp; print(time.perf_counter() - t)"
    inner = []
    for _ in range(repeats):
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
        inner.append(float(out.stdout))
    bare = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "pass"], check=True)
        bare.append(time.perf_counter() - t0)
    return statistics.median(inner), statistics.median(bare)


_FIRST_RUN = """
import sys, time
sys.path.insert(0, sys.argv[1])
from general_compiled import scene
import lcp
s, q0, v0, h = scene("bowl")
t0 = time.perf_counter()
r = lcp.simulate(s, int(sys.argv[2]) * h, h=h, q0=q0, v0=v0, fast=sys.argv[3] == "1")
print(time.perf_counter() - t0, "Python loop" in r.message, r.status, sep="|")
"""


def first_compile(steps: int, long: int):
    """The rows of ``--first-compile`` (module docstring): (what, seconds, note)."""
    import tempfile

    from lcp.timestepping.first_compile import ENV_VAR, MARKER

    bench = str(Path(__file__).resolve().parent)
    root = str(Path(__file__).resolve().parents[1])
    rows = []

    def run(env, what, n=steps, fast=True):
        t0 = time.perf_counter()
        out = subprocess.run([sys.executable, "-c", _FIRST_RUN, bench, str(n), "1" if fast else "0"], env=env,
                             capture_output=True,
                             text=True, check=True).stdout.strip().splitlines()[-1]
        wall = time.perf_counter() - t0
        secs, python, status = out.split("|")
        loop = "Python loop" if python == "True" else "compiled loop" if fast else "Python loop (fast=False)"
        note = f"{loop}, status {status}; interpreter wall {wall:.2f} s"
        rows.append((what, float(secs), note))
        print(f"{what:62s} {float(secs):9.3f} s  {note}", flush=True)
        return t0

    base = {k: v for k, v in os.environ.items() if k not in (ENV_VAR, "NUMBA_CACHE_DIR", "LCP_CACHE_DIR")}
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(base, LCP_CACHE_DIR=os.path.join(tmp, "c"), NUMBA_CACHE_DIR=os.path.join(tmp, "numba"),
                   PYTHONPATH=root, **{ENV_VAR: "always"})
        run(env, f"first run, {ENV_VAR}=always (waits for the compilation)")
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(base, LCP_CACHE_DIR=os.path.join(tmp, "c"), NUMBA_CACHE_DIR=os.path.join(tmp, "numba"),
                   PYTHONPATH=root)
        t0 = run(env, "first run, default (Python loop, compiled in the background)")
        marker = Path(tmp) / "numba" / MARKER
        while marker.exists():
            time.sleep(0.5)
        rows.append(("background compilation, from the first run's start", time.perf_counter() - t0, "wall time"))
        print(f"{rows[-1][0]:62s} {rows[-1][1]:9.3f} s", flush=True)
        run(env, "next short run, fresh interpreter (kernel cached, not loaded)")
        run(env, f"{long} steps, fresh interpreter (kernel loaded; the bowl's C code compiled)", long)
        run(env, f"{long} steps, fresh interpreter (everything cached)", long)
        run(env, f"{long} steps, fresh interpreter, fast=False", long, False)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer rounds")
    ap.add_argument("--first-compile", action="store_true",
                    help="the first short run of a non-constant system on fresh caches (module docstring)")
    ap.add_argument("--steps", type=int, default=300, help="steps of that run")
    ap.add_argument("--long", type=int, default=5000, help="steps of the long runs of --first-compile")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "out"))
    args = ap.parse_args(argv)
    if args.first_compile:
        print(f"first compilation of the general loop's kernel, load {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores")
        rows = first_compile(args.steps, args.long)
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        with open(out / "first_compile.csv", "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["what", "seconds", "note", "load_after"])
            for what, t, note in rows:
                w.writerow([what, f"{t:.4f}", note, f"{os.getloadavg()[0]:.2f}"])
        print(f"wrote {out / 'first_compile.csv'} (load {os.getloadavg()[0]:.2f} after)")
        return
    rounds = 10 if args.quick else 60
    t_eval = np.linspace(0.0, T, 1000)
    load = os.getloadavg()[0]

    times = {k: [] for k in ("scene", "scene+event", "lsoda", "scene+mj", "warm event", "warm mj")}
    err = {}
    warm = lcp.scenes.jean_pratt()
    lcp.simulate(warm, T, method="event", t_eval=t_eval)
    lcp.simulate(warm, T, h=1e-3)
    count = [0]

    def next_R():  # a new friction coefficient for every scene ever built here
        count[0] += 1
        return 0.5 + 1e-7 * count[0]

    def block(name, call):
        """BLOCK consecutive calls, timed together: the time per call of this block."""
        t0 = time.perf_counter()
        for _ in range(BLOCK):
            out = call()
        times[name].append((time.perf_counter() - t0) / BLOCK)
        return out

    def event_run():
        sc = lcp.scenes.jean_pratt(R=next_R())
        return sc, lcp.simulate(sc, T, method="event", t_eval=t_eval)

    def mj_run():
        sc = lcp.scenes.jean_pratt(R=next_R())
        return sc, lcp.simulate(sc, T, h=1e-3)

    for _ in range(rounds):
        block("scene", lambda: lcp.scenes.jean_pratt(R=next_R()))
        sc, res = block("scene+event", event_run)
        exact = sc.exact(t_eval)["x"]
        err["scene+event"] = max(err.get("scene+event", 0.0), float(np.max(np.abs(res.q[:, 0] - exact))))
        ls = block("lsoda", lambda sc=sc: lsoda_tanh(sc, t_eval, EPS, RTOL))
        err["lsoda"] = max(err.get("lsoda", 0.0), float(np.max(np.abs(ls.y[0] - exact))))
        sc2, mj = block("scene+mj", mj_run)
        err["scene+mj"] = max(err.get("scene+mj", 0.0), float(np.max(np.abs(mj.q[:, 0] - sc2.exact(mj.t)["x"]))))
        block("warm event", lambda: lcp.simulate(warm, T, method="event", t_eval=t_eval))
        block("warm mj", lambda: lcp.simulate(warm, T, h=1e-3))

    # call by call, alternating: wall-clock and thread CPU time of each call
    calls = {k: [] for k in ("event wall", "event cpu", "lsoda wall", "lsoda cpu")}
    wall, cpu = time.perf_counter, time.thread_time
    for _ in range(CALLS // 4 if args.quick else CALLS):
        w0, c0 = wall(), cpu()
        sc = lcp.scenes.jean_pratt(R=next_R())
        lcp.simulate(sc, T, method="event", t_eval=t_eval)
        w1, c1 = wall(), cpu()
        lsoda_tanh(sc, t_eval, EPS, RTOL)
        w2, c2 = wall(), cpu()
        calls["event wall"].append(w1 - w0)
        calls["event cpu"].append(c1 - c0)
        calls["lsoda wall"].append(w2 - w1)
        calls["lsoda cpu"].append(c2 - c1)
    fast = {k: min(v) for k, v in calls.items()}
    p10 = {k: float(np.percentile(v, 10)) for k, v in calls.items()}

    imp, bare = import_time(5 if args.quick else 15)
    med = {k: statistics.median(v) for k, v in times.items()}
    best = {k: min(v) for k, v in times.items()}
    load_after = os.getloadavg()[0]
    rows = [("import lcp (fresh interpreter)", imp, None, f"bare interpreter start-up {bare * 1e3:.1f} ms")]
    rows += [("new scene", med["scene"], None, "")]
    rows += [("new scene + event run 0.3 s", med["scene+event"], err["scene+event"],
              f"{med['lsoda'] / med['scene+event']:.1f}x faster than LSODA (medians; fastest blocks: "
              f"{best['lsoda'] / best['scene+event']:.1f}x; target >= 10x)")]
    rows += [("tanh + LSODA, same scene", med["lsoda"], err["lsoda"], f"eps = {EPS:g}, rtol = {RTOL:g}")]
    rows += [("new scene + Moreau-Jean 0.3 s, h = 1e-3", med["scene+mj"], err["scene+mj"], "target <= 3 ms")]
    for clock in ("wall", "cpu"):
        ev, ls = f"event {clock}", f"lsoda {clock}"
        rows += [(f"call by call ({clock}): new scene + event run", fast[ev], None,
                  f"fastest call; 10th percentile {p10[ev] * 1e3:.3f} ms")]
        rows += [(f"call by call ({clock}): LSODA", fast[ls], None,
                  (f"fastest call; 10th percentile {p10[ls] * 1e3:.3f} ms; ratio {fast[ls] / fast[ev]:.1f}x "
                   f"(fastest), {p10[ls] / p10[ev]:.1f}x (10th percentiles); target >= 10x"))]
    rows += [("warm event run (scene reused)", med["warm event"], None, "")]
    rows += [("warm Moreau-Jean run (scene reused)", med["warm mj"], None, "")]
    print(f"cold start, Jean-Pratt scene, {rounds} rounds, load {load:.2f} before, {load_after:.2f} after")
    print(f"{'what':50s} {'time':>11s} {'max |x err|':>12s}  note")
    for what, t, e, note in rows:
        es = f"{e:.1e}" if e is not None else "-"
        print(f"{what:50s} {t * 1e3:8.3f} ms {es:>12s}  {note}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / "cold_start.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["what", "seconds", "max_abs_x_error", "note", "load", "rounds"])
        for what, t, e, note in rows:
            w.writerow([what, f"{t:.6e}", "" if e is None else f"{e:.3e}", note, f"{load:.2f}-{load_after:.2f}",
                        rounds])
    print(f"wrote {out / 'cold_start.csv'}")


if __name__ == "__main__":
    main()
