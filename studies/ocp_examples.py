"""Optimal control through contacts that open and close: examples, replay-checked, against nosnoc.

Run: ``python -m studies.ocp_examples [--out DIR] [--quick] [--examples NAME[:N,...] ...]
[--peer-blas one|default]`` (headless; PNG and CSV into ``figures/ocp_examples/``). The examples
(:mod:`studies._ocp_models`): a point steered on a plane through a spatial contact (closed form; over 1 s it slides throughout, over 2 s it sticks, slides and
sticks, on free steps), a two-block chain moved 0.3 m, nosnoc's seven friction blocks brought
back to their equilibrium, nosnoc_py's linear motor
with friction and cart-pole with friction, nosnoc_py's hopper and two discs, a box tipped over
an edge, and a ball (e = 0.5) bounced to a target height. For each, at N control intervals:

- ours: :meth:`lcp.ocp.OptimalControlProblem.solve` (the homotopy from the default starts: the
  Moreau-Jean guess, then under the gap law the event method's guess, then that guess from
  sigma0 = 1, each only when the one before failed; ``message`` names them; where the result
  fails, the exact-phase shooting on the phases of its control's event replay,
  :mod:`lcp.ocp.shooting`), its
  objective, its replay miss (``result.replay``: the event method, or Moreau-Jean where the event
  replay does not apply, and its method), its success (which requires the replay within 1e-6)
  and time (building and solving, replay check included; the modules it imports on first use,
  :data:`OURS_IMPORTS`, are imported before the clock starts, as nosnoc's import is before its own);
- nosnoc (optional peer, :mod:`studies._nosnoc_examples`, nosnoc_py's own model and options where it
  has the example, run like ours with CasADi's OpenBLAS on one thread, :mod:`lcp.ocp.blas`, and the
  C heap keeping the linear solver's workspace, :mod:`lcp.ocp.heap`, unless ``--peer-blas
  default``): its status, its time (building and solving), and the replay miss of its control
  through the package's event method (one integration over the horizon, Moreau-Jean at T / 20000
  if the event method fails), measured on the coordinates both models share;
- both controls scored by one measure, ``J_replay``: the example's continuous cost integrated
  (midpoint rule, 200 subintervals per control interval, the states at the midpoints from the event
  method's replay of the control over the horizon, or, where it fails, interpolated from a
  Moreau-Jean replay at T / (200 N)), plus the terminal cost at the replay's end (the objectives of
  the two transcriptions use different quadratures). The Moreau-Jean replay alone could not follow
  the cart-pole's swing-up to its unstable upright: it scored the control 8808.68 where the event
  replay, at rtol 1e-12 and 3e-14 alike, scores 692.66.

A row is a success only when the replay is within tolerance; where the replay misses, the numbers
are recorded as they are (``message`` says what the solver reported). The study runs without
nosnoc and says so. ``--quick``: six examples at one N each (what the test suite runs).

The motor, the two-block chain, the seven blocks, the box and the hopper end in the
shooting: replays within 1e-10 (the transcription's alone missed by 0.5 and 1e-2 on the first two).
The box rests on two stuck corners for part of its motion: four contact rows on three velocities,
which the shooting holds by an independent subset of them, the modes admissible for some split of
the forces (:mod:`lcp.ocp.phase_dynamics`). Not solved from the defaults (measured, ``message`` says
where): the cart-pole at N = 20 and 40 (the default theta solve converges to a control that never
swings the pole up, replayed exactly, so it counts as solved at cost 6472; a swing-up's open-loop
replay amplifies errors about 4.5e6 times, so no replay certifies 1e-6 on it, and the message says
so). The two discs are solved from the example's own start at N = 30 and 60 (at N = 60 once the
shooting prunes the phases that shrink to zero, :func:`lcp.ocp.plans.pruned_plan`). They start on one line
with swapped targets, but nosnoc's drag cv v / |v + eps| (eps added to both components) has no
mirror symmetry: the solves leave the line.
From rest the relaxed homotopy parks the pushed disc against the other (a local optimum, cost 8511
at N = 30) and its polishing solve stops at IPOPT's iteration limit; from starts that send it
around, the homotopy ends with Coulomb residuals of order one where the discs slide or strike, and
the shooting does not recover (iteration limit, or a replay missing by 4.3e-5). nosnoc's
discs (its time freezing; N = 30: objective 113.8 in 58 s) model the impact as a push over
physical time: the event replay of its control ends 3.9 from its final state.

nosnoc's seven friction blocks (N = 50, T = 5 s; no terminal constraint, so feasible: u = 0 keeps the
state box) are solved by both (measured): nosnoc in 67 s with objective 10.949, J_replay 10.934, its
control's replay 4.7e-5 from its final state; ours with Radau IIA (s = 2) and the exact-phase
shooting in 140 s at load 5-6 (nosnoc 55 s in the same run, both with CasADi's OpenBLAS on one
thread; on two threads ours took 184-204 s and ended on another phase sequence, objective 10.762),
objective 10.825, J_replay 10.818, replay miss 2.2e-10. From the theta step the shooting also succeeds (160 s loaded, replay 1.0e-9) but on a phase
sequence whose optimum is above nosnoc's (J_replay 10.957). (Those J_replay values came from the
Moreau-Jean scoring replay; scored by the event replay, the same optimum of ours is 10.8196 and
nosnoc's control 10.9355.)
"""
from __future__ import annotations

import contextlib
import importlib
import itertools
import time

import numpy as np

import lcp
from lcp.ocp.solve import solver_settings
from studies import _nosnoc_examples as peers
from studies._common import out_dir, parse_args, save, write_csv
from studies._ocp_models import EXAMPLES

NAME = "ocp_examples"
DESCRIPTION = "Optimal control examples through contact (spatial, chains, nosnoc's), replay-checked, with nosnoc."
QUICK = ("point_on_plane", "point_stick_slide", "block_chain2", "motor", "cart_pole", "ball_bounce")
REPLAY_TOL = 1e-6
#: Moreau-Jean steps per control interval of the replay that scores J_replay
SCORE_REFINE = 200

__all__ = ["main", "replay_control", "run", "score"]


def replay_control(ex, schedule):
    """The control replayed open loop from the example's start: (final q, final v, method). The event
    method over the whole horizon, else Moreau-Jean at T / 20000 (reported)."""
    T = float(schedule.times[-1])
    try:
        sim = lcp.simulate(ex.system, T, method="event", control=schedule, q0=ex.q0, v0=ex.v0)
        if sim.success:
            return sim.q[-1], sim.v[-1], "event"
    except (ValueError, RuntimeError):
        pass
    h = T / 20000
    sim = lcp.simulate(ex.system, T, h=h, control=schedule, q0=ex.q0, v0=ex.v0)
    return sim.q[-1], sim.v[-1], f"moreau-jean h={h:.3g}"


def score(ex, schedule, N):
    """J_replay: the example's cost along the event replay of the control (states at the midpoints of
    SCORE_REFINE subintervals per control interval), or, where that replay fails, along a
    Moreau-Jean replay at T / (SCORE_REFINE N)."""
    T = float(schedule.times[-1])
    # midpoint rule on SCORE_REFINE subintervals of every control interval (the control's jumps are
    # ends of subintervals, so a piecewise-constant control's effort is exact)
    nodes = np.asarray(schedule.times, dtype=float)
    edges = np.concatenate([np.linspace(a, b, SCORE_REFINE + 1)[:-1] for a, b in itertools.pairwise(nodes)]
                           + [nodes[-1:]])
    tm, dt = 0.5 * (edges[1:] + edges[:-1]), np.diff(edges)
    u = np.asarray(schedule(tm), dtype=float).reshape(len(tm), -1)
    try:
        sim = lcp.simulate(ex.system, T, method="event", control=schedule, q0=ex.q0, v0=ex.v0,
                           t_eval=np.concatenate([tm, [T]]))
        if sim.success:
            return float(np.sum(dt * ex.integrand(tm, sim.q[:-1], sim.v[:-1], u)) + ex.terminal(sim.q[-1], sim.v[-1]))
    except (ValueError, RuntimeError):
        pass
    sim = lcp.simulate(ex.system, T, h=T / (SCORE_REFINE * N), control=schedule, q0=ex.q0, v0=ex.v0)
    if not sim.success:
        return float("nan")
    t = np.asarray(sim.t)  # (the states interpolated linearly from the replay)
    qm = np.column_stack([np.interp(tm, t, sim.q[:, j]) for j in range(sim.q.shape[1])])
    vm = np.column_stack([np.interp(tm, t, sim.v[:, j]) for j in range(sim.v.shape[1])])
    return float(np.sum(dt * ex.integrand(tm, qm, vm, u)) + ex.terminal(sim.q[-1], sim.v[-1]))


#: modules that ``solve`` imports on first use (the simulation of the guess and the replay: the event
#: method, SciPy's integrators, numba): imported before our clock starts, as ``import nosnoc`` is before
#: nosnoc's (:func:`studies._nosnoc_examples.solve_peer`); loading compiled code stays on the clocks
OURS_IMPORTS = ("lcp.simulation", "lcp.timestepping.compiled_loop", "lcp.events.ode_phase", "scipy.integrate")


def _ours(ex, N):
    for name in OURS_IMPORTS:
        importlib.import_module(name)
    t0 = time.perf_counter()
    try:
        ocp = ex.make(N)
        res = ocp.solve(ex.start(ocp) if ex.start is not None else None, **ex.solve_kw)  # (the example's own start)
    except (ValueError, RuntimeError) as exc:
        return {"ours_success": False, "ours_cost": float("nan"), "ours_J_replay": float("nan"),
                "ours_miss": float("nan"), "ours_method": "", "ours_time": time.perf_counter() - t0,
                "ours_message": f"error: {exc}"}, None
    elapsed = time.perf_counter() - t0
    rp = res.replay
    J = score(ex, res.control, N) if np.all(np.isfinite(res.u)) else float("nan")
    return {"ours_success": bool(res.success), "ours_cost": float(res.cost), "ours_J_replay": J,
            "ours_miss": rp.final_miss if rp is not None else float("nan"),
            "ours_method": rp.method if rp is not None else "", "ours_time": elapsed,
            "ours_residual": float(res.complementarity_residual), "ours_iterations": int(res.iterations),
            "ours_message": res.message}, res


def _nosnoc(ex, N, blas: str = "one"):
    empty = {"nosnoc_status": "", "nosnoc_objective": float("nan"), "nosnoc_J_replay": float("nan"),
             "nosnoc_miss": float("nan"), "nosnoc_method": "", "nosnoc_time": float("nan"), "nosnoc_note": ""}
    if ex.name not in peers.PEERS:
        return {**empty, "nosnoc_note": peers.NO_PEER.get(ex.name, "no peer")}, None
    if not peers.available():
        return {**empty, "nosnoc_note": "nosnoc is not installed (optional peer)"}, None
    # under the settings ours solves with (lcp.ocp.solve.solver_settings: both gain alike, the seven
    # blocks 23-26 % from the heap), unless asked for the libraries' defaults
    with solver_settings() if blas == "one" else contextlib.nullcontext():
        pr = peers.solve_peer(ex.name, N)
    try:
        qf, vf, method = replay_control(ex, pr.control)
        miss = float(np.max(np.abs(ex.common_state(qf, vf) - pr.x_final)))
    except (ValueError, RuntimeError) as exc:
        miss, method = float("nan"), f"replay failed: {exc}"
    return {"nosnoc_status": f"{pr.status} ({pr.ipopt_status})", "nosnoc_objective": pr.objective,
            "nosnoc_J_replay": score(ex, pr.control, N), "nosnoc_miss": miss, "nosnoc_method": method,
            "nosnoc_time": pr.total_time, "nosnoc_blas": blas, "nosnoc_note": ""}, pr


def _figure(rows, path):
    import matplotlib.pyplot as plt

    from studies._common import legend

    names = list(dict.fromkeys(r["example"] for r in rows))
    fig, axes = plt.subplots(1, 2, figsize=(12, 4))
    x = np.arange(len(names))
    for ax, key, label in ((axes[0], "miss", "replay miss (final state)"), (axes[1], "time", "time [s]")):
        for who, mk, dx in (("ours", "o", -0.1), ("nosnoc", "s", 0.1)):
            color = "tab:blue" if who == "ours" else "tab:red"
            for ok in (True, False):
                # ours: filled where the solve is a success, hollow where it is not (its iterate replayed)
                sel = [r for r in rows if who == "nosnoc" or bool(r["ours_success"]) == ok]
                if who == "nosnoc" and not ok:
                    continue
                xs = [names.index(r["example"]) + dx for r in sel if np.isfinite(r[f"{who}_{key}"])]
                ys = [max(r[f"{who}_{key}"], 1e-17) for r in sel if np.isfinite(r[f"{who}_{key}"])]
                lab = {("ours", True): "lcp.ocp, success", ("ours", False): "lcp.ocp, not a success",
                         ("nosnoc", True): "nosnoc (its replay by our event method)"}[(who, ok)]
                ax.scatter(xs, ys, marker=mk, facecolors=color if ok else "none", edgecolors=color, label=lab)
        ax.set_yscale("log")
        ax.set_xticks(x, names, rotation=30, ha="right")
        ax.set_ylabel(label)
        if key == "miss":
            ax.axhline(REPLAY_TOL, color="0.5", ls="--", lw=0.8)
        legend(ax)
    fig.suptitle("optimal control examples: replay miss and time (every N)")
    return save(fig, path)


def _trajectory_figure(ex, res, path):
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5))
    for j, nm in enumerate(ex.system.names or [f"q{j}" for j in range(ex.system.n)]):
        ax.plot(res.t, res.q[:, j], marker=".", label=nm)
    ax.set_xlabel("t [s]")
    ax.set_title(f"{ex.title}: optimizer nodes (N = {len(res.t) - 1}), success = {res.success}")
    from studies._common import legend

    legend(ax)
    return save(fig, path)


def run(out=None, quick: bool = False, examples=None, sizes: dict | None = None, peer_blas: str = "one") -> dict:
    """Solve every example (ours and nosnoc's), replay both, write the CSV and figures.

    ``examples``: names (all, or the quick six, by default); ``sizes``: name -> the N to run (the
    example's own by default); ``peer_blas``: "one" runs nosnoc with CasADi's OpenBLAS on one thread
    and the C heap kept between factorizations, as ours solves (:mod:`lcp.ocp.blas`,
    :mod:`lcp.ocp.heap`: the same libraries and settings for both), "default" leaves nosnoc on the
    libraries' defaults (``nosnoc_blas`` in the CSV says which).
    Returns ``rows`` (one dict per example and N), ``nosnoc`` (whether the peer ran) and ``files``.
    """
    if peer_blas not in ("one", "default"):
        raise ValueError(f"peer_blas must be 'one' or 'default', got {peer_blas!r}")
    path = out_dir(out, NAME)
    names = examples or (QUICK if quick else tuple(EXAMPLES))
    unknown = sorted(set(names) - set(EXAMPLES)) + sorted(set(sizes or {}) - set(names))
    if unknown:
        raise ValueError(f"unknown or unselected examples: {unknown} (examples: {sorted(EXAMPLES)})")
    rows, files = [], []
    for name in names:
        ex = EXAMPLES[name]()
        own = (ex.N_quick,) if quick else ex.N_full
        for N in (sizes or {}).get(name, own):
            row = {"example": name, "title": ex.title, "N": N, "reference": ex.reference}
            ours, res = _ours(ex, N)
            row.update(ours)
            row.update(_nosnoc(ex, N, peer_blas)[0])
            row["time_ratio"] = row["nosnoc_time"] / row["ours_time"]
            rows.append(row)
            if res is not None and N == own[0] and np.all(np.isfinite(res.q)):
                files.append(_trajectory_figure(ex, res, path / f"trajectory_{name}.png"))
    cols = []
    for r in rows:
        cols += [c for c in r if c not in cols]
    files.append(write_csv(path / "examples.csv", cols, [[r.get(c, "") for c in cols] for r in rows]))
    files.append(_figure(rows, path / "summary.png"))
    return {"rows": rows, "nosnoc": peers.available(), "files": files}


def _selection(specs):
    """``name`` or ``name:N1,N2`` items -> (names, sizes)."""
    names, sizes = [], {}
    for spec in specs or ():
        name, _, ns = spec.partition(":")
        names.append(name)
        if ns:
            try:
                sizes[name] = tuple(int(n) for n in ns.split(","))
            except ValueError:
                raise ValueError(f"--examples: {spec!r} is not name or name:N1,N2") from None
    return names or None, sizes or None


def _extra(parser):
    parser.add_argument("--examples", nargs="+", metavar="NAME[:N,...]",
                        help="only these examples (and these N), e.g. motor:30 block_chain2:20")
    parser.add_argument("--peer-blas", choices=("one", "default"), default="one",
                        help="nosnoc's OpenBLAS threads and C heap: as ours (one thread, the heap kept; "
                             "default), or the libraries' defaults")


def main(argv=None):
    args = parse_args(NAME, DESCRIPTION, argv, extra=_extra)
    names, sizes = _selection(args.examples)
    out = run(args.out, quick=args.quick, examples=names, sizes=sizes, peer_blas=args.peer_blas)
    if not out["nosnoc"]:
        print("nosnoc (optional peer, pip install 'lcp-lem[ocp-peers]') is not installed: its columns are empty")
    print(f"{'example':>15} {'N':>4} | {'ok':>3} {'objective':>12} {'J_replay':>12} {'miss':>9} {'method':>18} "
          f"{'time[s]':>7} | {'nosnoc':>8} {'J_replay':>12} {'miss':>9} {'time[s]':>7} {'ratio':>6}")
    for r in out["rows"]:
        print(f"{r['example']:>15} {r['N']:>4} | {'yes' if r['ours_success'] else 'no':>3} {r['ours_cost']:>12.6g} "
              f"{r['ours_J_replay']:>12.6g} {r['ours_miss']:>9.2e} {r['ours_method'][:18]:>18} {r['ours_time']:>7.2f} | "
              f"{r['nosnoc_status'][:8]:>8} {r['nosnoc_J_replay']:>12.6g} {r['nosnoc_miss']:>9.2e} "
              f"{r['nosnoc_time']:>7.2f} {r['time_ratio']:>6.2f}")
    for r in out["rows"]:
        if r["nosnoc_note"]:
            print(f"{r['example']}: no nosnoc row: {r['nosnoc_note']}")
        if not r["ours_success"]:
            print(f"{r['example']} N={r['N']}: not a success: {r['ours_message'][:400]}")
    print("wrote", ", ".join(str(f) for f in out["files"]))
    return out


if __name__ == "__main__":
    main()
