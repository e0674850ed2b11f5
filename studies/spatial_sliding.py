"""Spatial sliding: a block sliding in a plane under the Coulomb disk law, by every method.

``python -m studies.spatial_sliding [--out DIR] [--quick]``

Scenes (:mod:`lcp.scenes.spatial_systems`), each with its exact solution (:mod:`lcp.scenes.spatial_exact`):

- an oblique launch on a horizontal plane (a straight path, a stop, then stick),
- a horizontal launch across an incline with mu = tan(theta) (a curved path; v (1 + cos phi) is
  constant, the speed tends to v0/2),
- a constant lateral force smaller than mu m g (a curved path that turns toward the force and
  ends in stick at a finite time),

and the spatial Jean-Pratt system (the Painleve coupling through the normal force) launched
obliquely, where the event method serves as the reference, and along x, where it must equal the
planar scene.

Methods: the exact solution, the event-driven method (``method="event"``), Moreau-Jean
(theta = 1/2, several h) and the LEM engine on the sliding branch made polynomial
(:mod:`lem.spatial_sliding`). The incline is also checked against a high-accuracy integration of
the reduced equations (:func:`lcp.scenes.spatial_exact.reduced_reference`).

Writes ``paths.png`` (trajectories in the plane), ``speed_incline.png`` (speed against time, with
v0 (1 + cos phi0) / (1 + cos phi) from the invariant), ``work_precision.png`` (error against run
time), ``no_creep.csv`` (velocity after the stop, up to 1e4 s), ``jean_pratt_along_x.csv`` and the
CSV data behind every figure.
"""
from __future__ import annotations

import math
import time

import matplotlib.pyplot as plt
from matplotlib.ticker import LogLocator, NullFormatter
import numpy as np

import lcp
from lcp.scenes.spatial_systems import incline_slide, jean_pratt_spatial, lateral_force_slide, plane_slide

from ._common import floored, legend, out_dir, parse_args, save, write_csv

NAME = "spatial_sliding"
FLOOR = 1e-16


def scenes() -> dict:
    """The scenes of the study, by label."""
    return {
        "plane": plane_slide(m=1.0, mu=0.4, v0=1.3, beta=0.7),
        "incline": incline_slide(theta=0.35, v0=1.0, t_end=2.0),
        "lateral": lateral_force_slide(m=1.0, mu=0.5, F=(2.0, 1.0), v0=(-0.5, 1.5)),
    }


def _timed(fn, repeats: int):
    """(result, best wall time in seconds) over ``repeats`` calls."""
    best, out = math.inf, None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return out, best


def _lem(sc, t):
    """The LEM engine on the scene's sliding branch (point mass, constant normal force)."""
    from lem.spatial_sliding import solve_spatial_sliding

    m = sc.system.mass(sc.q0)[0, 0]
    F = sc.system.force(sc.q0, sc.v0)
    accel = F[:2] / m
    decel = float(sc.system.mu[0]) * (-F[2]) / m
    return solve_spatial_sliding(sc.v0[:2], float(t[-1]), accel=accel, decel=decel, t_eval=t)


def _error(x, z, ex):
    return float(np.max(np.hypot(np.asarray(x) - ex["x"], np.asarray(z) - ex["z"])))


def compare(sc, hs, repeats: int) -> list[dict]:
    """Error (max distance in the plane from the exact path at the output times) and run time of
    every method on one scene."""
    t_end = sc.t_end
    rows = []
    t_grid = np.linspace(0.0, t_end, 201)
    # warm-up (not timed): numba kernels compile, and the LEM engine builds its structures, on first use
    lcp.simulate(sc, 0.05, method="event")
    lcp.simulate(sc, 0.05, h=1e-3)
    _lem(sc, np.array([0.0, 0.05]))
    ex = sc.exact(t_grid)
    res, dt = _timed(lambda: lcp.simulate(sc, t_end, method="event", t_eval=t_grid), repeats)
    rows.append(dict(method="event", h=0.0, error=_error(res.q[:, 0], res.q[:, 1], ex) if res.success else math.nan,
                     seconds=dt, success=res.success, message=res.message))
    for h in hs:
        every = max(1, int(round((t_end / 200) / h)))
        res, dt = _timed(lambda h=h, every=every: lcp.simulate(sc, t_end, h=h, save_every=every), 1)
        exh = sc.exact(res.t)
        rows.append(dict(method="moreau-jean", h=h, error=_error(res.q[:, 0], res.q[:, 1], exh) if res.success
                         else math.nan, seconds=dt, success=res.success, message=res.message))
    lem_res, dt = _timed(lambda: _lem(sc, t_grid), repeats)
    rows.append(dict(method="lem", h=0.0, error=_error(lem_res.x, lem_res.y, ex) if lem_res.success else math.nan,
                     seconds=dt, success=lem_res.success, message=lem_res.message))
    return rows


def incline_reference_check(sc) -> dict:
    """The incline against the high-accuracy reduced integration (and the closed form against it)."""
    t = np.linspace(0.0, 2.0, 401)
    ref = sc.solution.reference(t)
    ex = sc.exact(t)
    ev = lcp.simulate(sc, 2.0, method="event", t_eval=t)
    lem_res = _lem(sc, t)
    return dict(closed_form=float(np.max(np.hypot(ex["x"] - ref["x"], ex["z"] - ref["y"]))),
                event=float(np.max(np.hypot(ev.q[:, 0] - ref["x"], ev.q[:, 1] - ref["y"]))) if ev.success else math.nan,
                lem=float(np.max(np.hypot(lem_res.x - ref["x"], lem_res.y - ref["y"]))))


def no_creep(sc, t_end: float) -> list[dict]:
    """Largest speed after the stop (+ 1 ms) up to ``t_end``, by every method: exactly 0 expected."""
    t_stop = sc.solution.t_stop
    out = []
    ev = lcp.simulate(sc, t_end, method="event", t_eval=np.array([t_stop + 1e-3, t_end / 2, t_end]))
    out.append(dict(method="event", h=0.0, max_speed=float(np.max(np.abs(ev.v[:, :2]))), success=ev.success))
    h = 0.1 if t_end > 10 else 1e-3
    mj = lcp.simulate(sc, t_end, h=h, save_every=max(1, int(t_end / h / 100)))
    after = mj.t > t_stop + h
    out.append(dict(method="moreau-jean", h=h, max_speed=float(np.max(np.abs(mj.v[after, :2]))), success=mj.success))
    lem_res = _lem(sc, np.array([0.0, t_stop + 1e-3, t_end]))
    out.append(dict(method="lem", h=0.0, max_speed=float(np.max(np.abs([lem_res.vx[1:], lem_res.vy[1:]]))),
                    success=lem_res.success))
    return out


def jean_pratt_along_x(hs) -> list[dict]:
    """The spatial Jean-Pratt scene launched along x against the planar scene, both methods."""
    rows = []
    for R, v0 in ((0.5, 1.0), (1.3, 0.8), (0.35, -1.7)):
        sp = jean_pratt_spatial(m=1.3, M=0.7, alpha=0.9, R=R, v0=(v0, 0.0))
        pl = lcp.scenes.jean_pratt(m=1.3, M=0.7, alpha=0.9, R=R, v0=v0)
        t = np.linspace(0.0, 0.3, 61)
        a = lcp.simulate(sp, 0.3, method="event", t_eval=t)
        b = lcp.simulate(pl, 0.3, method="event", t_eval=t)
        diff = (float(np.max(np.abs(a.q[:, 0] - b.q[:, 0]) + np.abs(a.q[:, 2] - b.q[:, 1])))
                if a.success and b.success else math.nan)
        rows.append(dict(R=R, v0=v0, method="event", h=0.0, max_difference=diff, success=a.success))
        for h in hs:
            a = lcp.simulate(sp, 0.3, h=h)
            b = lcp.simulate(pl, 0.3, h=h)
            diff = (float(np.max(np.abs(a.q[:, 0] - b.q[:, 0]) + np.abs(a.q[:, 2] - b.q[:, 1])))
                    if a.success and b.success else math.nan)
            rows.append(dict(R=R, v0=v0, method="moreau-jean", h=h, max_difference=diff, success=a.success))
    return rows


def jean_pratt_oblique(hs, outdir) -> list[dict]:
    """The spatial Jean-Pratt block launched obliquely: Moreau-Jean against the event method."""
    sc = jean_pratt_spatial(R=0.5, v0=(1.0, 0.6))
    t = np.linspace(0.0, 0.3, 301)
    ev = lcp.simulate(sc, 0.3, method="event", t_eval=t)
    rows, runs = [], {}
    for h in hs:
        every = max(1, int(round(1e-3 / h)))
        mj = lcp.simulate(sc, 0.3, h=h, save_every=every)
        runs[h] = mj
        ref = ev.q[:: max(1, int(round(h / 1e-3)))] if ev.success else None
        n = min(len(mj.t), len(ref)) if ref is not None else 0
        err = float(np.max(np.abs(mj.q[:n, :2] - ref[:n, :2]))) if n else math.nan
        rows.append(dict(h=h, error_vs_event=err, max_gap=float(np.max(np.abs(mj.q[:, 2]))), success=mj.success))
    write_csv(outdir / "jean_pratt_oblique_paths.csv", ["method", "h", "t", "x", "z", "y"],
              [("event", 0.0, *r) for r in np.column_stack([ev.t, ev.q])] +
              [("moreau-jean", h, *r) for h, mj in runs.items() for r in np.column_stack([mj.t, mj.q])])
    return rows


def plot_paths(scs, outdir, h_show: float):
    """The paths in the plane: exact, event, Moreau-Jean (h_show), LEM; CSV with every series."""
    fig, axes = plt.subplots(1, len(scs), figsize=(4.2 * len(scs), 3.8))
    csv_rows = []
    for ax, (label, sc) in zip(axes, scs.items()):
        t = np.linspace(0.0, sc.t_end, 401)
        ex = sc.exact(t)
        ev = lcp.simulate(sc, sc.t_end, method="event", t_eval=t[::20])
        mj = lcp.simulate(sc, sc.t_end, h=h_show)
        lem_res = _lem(sc, t[::20])
        ax.plot(ex["x"], ex["z"], "-", color="0.3", lw=1.2, label="exact")
        if ev.success:
            ax.plot(ev.q[:, 0], ev.q[:, 1], "o", mfc="none", ms=6, label="event")
        ax.plot(mj.q[:, 0], mj.q[:, 1], "--", lw=1.0, label=f"Moreau-Jean h = {h_show:g}")
        ax.plot(lem_res.x, lem_res.y, "+", ms=7, label="LEM")
        ax.set_title(label)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("z [m]")
        ax.set_aspect("equal", adjustable="datalim")
        csv_rows += [(label, "exact", *r) for r in zip(t, ex["x"], ex["z"])]
        csv_rows += [(label, "event", *r) for r in zip(ev.t, ev.q[:, 0], ev.q[:, 1])]
        csv_rows += [(label, f"moreau-jean h={h_show:g}", *r) for r in zip(mj.t, mj.q[:, 0], mj.q[:, 1])]
        csv_rows += [(label, "lem", *r) for r in zip(lem_res.t, lem_res.x, lem_res.y)]
    legend(axes[-1])
    save(fig, outdir / "paths.png")
    write_csv(outdir / "paths.csv", ["scene", "method", "t", "x", "z"], csv_rows)


def plot_incline_speed(sc, outdir):
    """Speed against time on the incline, with the invariant v (1 + cos phi) = v0 (1 + cos phi0)."""
    t = np.linspace(0.0, sc.t_end, 401)
    ex = sc.exact(t)
    ev = lcp.simulate(sc, sc.t_end, method="event", t_eval=t)
    v0, phi0 = sc.params["v0"], sc.params["phi0"]
    fig, ax = plt.subplots(figsize=(6.0, 3.8))
    ax.plot(t, ex["speed"], "-", color="0.3", label="exact")
    speed = np.hypot(ev.v[:, 0], ev.v[:, 1]) if ev.success else np.full_like(t, np.nan)
    ax.plot(t[::10], speed[::10], "o", mfc="none", label="event")
    invariant = v0 * (1 + math.cos(phi0)) / (1 + np.cos(ex["phi"]))
    ax.plot(t, invariant, ":", lw=2, label="v0 (1 + cos phi0) / (1 + cos phi)")
    ax.axhline(v0 / 2, color="0.6", lw=0.8, ls="--", label="v0 / 2 (limit)")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("speed [m/s]")
    legend(ax)
    save(fig, outdir / "speed_incline.png")
    write_csv(outdir / "speed_incline.csv", ["t", "exact", "event", "invariant"],
              zip(t, ex["speed"], speed, invariant))
    return float(np.max(np.abs(ex["speed"] * (1 + np.cos(ex["phi"])) - v0 * (1 + math.cos(phi0)))))


def plot_work_precision(rows, outdir):
    """Error against run time, one panel per scene."""
    labels = sorted({r["scene"] for r in rows})
    fig, axes = plt.subplots(1, len(labels), figsize=(4.2 * len(labels), 3.8))
    for ax, label in zip(np.atleast_1d(axes), labels):
        sub = [r for r in rows if r["scene"] == label]
        for method, fmt in (("event", "o"), ("moreau-jean", "s-"), ("lem", "^")):
            pts = sorted((r["seconds"], r["error"]) for r in sub if r["method"] == method)
            if pts:
                x, y = zip(*pts)
                floored(ax, x, y, FLOOR, fmt=fmt, label=method)
        ax.set_xscale("log")
        ax.set_yscale("log")
        # run times span less than a decade: matplotlib would label every minor tick, overprinted
        ax.xaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 3.0), numticks=6))
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("run time [s]")
        ax.set_ylabel("max |position - exact| [m]")
        ax.set_title(label)
    legend(np.atleast_1d(axes)[-1])
    save(fig, outdir / "work_precision.png")


def run(out=None, quick: bool = False) -> dict:
    """Write all figures and CSV files; return the numbers behind them."""
    outdir = out_dir(out, NAME)
    scs = scenes()
    hs = [1e-2, 1e-3] if quick else [1e-2, 1e-3, 1e-4]
    repeats = 1 if quick else 3
    rows = []
    for label, sc in scs.items():
        for r in compare(sc, hs, repeats):
            rows.append(dict(scene=label, **r))
    write_csv(outdir / "work_precision.csv", ["scene", "method", "h", "error", "seconds", "success", "message"],
              [(r["scene"], r["method"], r["h"], r["error"], r["seconds"], r["success"], r["message"]) for r in rows])
    plot_work_precision(rows, outdir)
    plot_paths(scs, outdir, hs[0])
    invariant = plot_incline_speed(scs["incline"], outdir)
    incline = incline_reference_check(scs["incline"])
    creep = no_creep(scs["plane"], 1e2 if quick else 1e4)
    write_csv(outdir / "no_creep.csv", ["method", "h", "max_speed_after_stop", "success"],
              [(r["method"], r["h"], r["max_speed"], r["success"]) for r in creep])
    along_x = jean_pratt_along_x(hs[:2])
    write_csv(outdir / "jean_pratt_along_x.csv", ["R", "v0", "method", "h", "max_difference", "success"],
              [(r["R"], r["v0"], r["method"], r["h"], r["max_difference"], r["success"]) for r in along_x])
    oblique = jean_pratt_oblique(hs[:2], outdir)
    write_csv(outdir / "jean_pratt_oblique.csv", ["h", "error_vs_event", "max_gap", "success"],
              [(r["h"], r["error_vs_event"], r["max_gap"], r["success"]) for r in oblique])
    write_csv(outdir / "incline_reference.csv", ["what", "max_distance_from_reduced_reference"],
              [(k, v) for k, v in incline.items()] + [("invariant v(1+cos phi) of the closed form", invariant)])
    plane = scs["plane"]
    ev = lcp.simulate(plane, plane.t_end, method="event")
    stop_error = (abs(ev.t_events[0] - plane.solution.t_stop) / plane.solution.t_stop
                  if ev.success and len(ev.t_events) else math.nan)
    files = sorted(p.name for p in outdir.iterdir())
    return dict(work_precision=rows, incline=incline, invariant=invariant, no_creep=creep, along_x=along_x,
                oblique=oblique, stop_time_error=stop_error, files=files, out=str(outdir))


def main(argv=None):
    args = parse_args(NAME, "Spatial sliding under the Coulomb disk law: exact, event, Moreau-Jean and LEM.", argv)
    res = run(args.out, args.quick)
    print(f"Figures and CSV data written to {res['out']}/")
    for r in res["work_precision"]:
        h = f"h = {r['h']:g}" if r["h"] else ""
        print(f"  {r['scene']:8s} {r['method']:12s} {h:10s} error {r['error']:.3e}  {1e3 * r['seconds']:9.2f} ms"
              + ("" if r["success"] else f"  FAILED: {r['message']}"))
    print("  incline against the high-accuracy reduced integration: "
          + ", ".join(f"{k} {v:.2e}" for k, v in res["incline"].items()))
    print(f"  plane: event stop time relative error {res['stop_time_error']:.2e}")
    for r in res["no_creep"]:
        print(f"  no creep ({r['method']}): max speed after the stop {r['max_speed']:.3g}")
    worst = max((r["max_difference"] for r in res["along_x"]), default=math.nan)
    print(f"  spatial Jean-Pratt along x vs planar: worst difference {worst:.3g}")


if __name__ == "__main__":
    main()
