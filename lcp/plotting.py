"""Plots and animations of simulation results, drawn with matplotlib (imported on first use).

Holds :func:`plot_result` (what ``SimulationResult.plot()`` draws: coordinates, velocities,
contact forces with the impacts, and contact modes against time) and :func:`animate` (a planar
system moving, saved as a GIF with Pillow or as an MP4 where ffmpeg exists).

Reads results and systems by their attributes only, so it imports nothing of ``lcp``: it sits low
enough in the layers for :mod:`lcp.result` to offer ``result.plot()``. matplotlib (and, for
:func:`animate` of a ``System``, CasADi) are imported inside the functions.
"""
from __future__ import annotations

import pathlib
from typing import Callable, Sequence

import numpy as np

__all__ = ["MODE_NAMES", "plot_result", "animate", "contact_points"]

#: contact mode code -> name, as in ``SimulationResult.modes`` (-1: the contact was not active)
MODE_NAMES = {-1: "inactive", 0: "open", 1: "stick", 2: "slide+", 3: "slide-", 4: "slide"}


def _names(result, system, names, n: int) -> list[str]:
    if names is not None:
        names = list(names)
        if len(names) != n:
            raise ValueError(f"names must have {n} entries (one per coordinate), got {len(names)}")
        return names
    sys_names = getattr(system, "names", None)
    if sys_names is not None and len(sys_names) == n:
        return list(sys_names)
    return [f"q{i}" for i in range(n)]


def _contact_names(system, m: int) -> list[str]:
    contacts = getattr(system, "contacts", None)
    if contacts is not None and len(contacts) == m:
        return [getattr(c, "name", f"contact {j}") for j, c in enumerate(contacts)]
    return [f"contact {j}" for j in range(m)]


def plot_result(result, system=None, *, names: Sequence[str] | None = None, exact: dict | None = None,
                fig=None):
    """Draw a simulation result against time: coordinates, velocities, contact forces, modes.

    Parameters
    ----------
    result : SimulationResult or EventResult
        What :func:`lcp.simulate` returned (any object with ``t``, ``q``, ``v``, ``p_N``, ``p_T``,
        ``modes``, ``h`` and ``impacts`` will do).
    system : System, optional
        Supplies the coordinates' and contacts' names for the legends.
    names : sequence of str, optional
        The coordinates' names (instead of the system's).
    exact : dict, optional
        Reference curves drawn dashed over the coordinates: ``{"t": times, name: values, ...}``
        where each name is one of the coordinates' names.
    fig : matplotlib.figure.Figure, optional
        Draw into this (empty) figure; a new one by default.

    Returns
    -------
    matplotlib.figure.Figure
        Four axes sharing the time axis, top to bottom: the coordinates q (one line per
        coordinate, plus the ``exact`` curves), the velocities v, the contact forces (normal
        solid, tangential dashed; the impacts as vertical dotted lines) and the contact modes
        (one step line per contact, y ticks named by :data:`MODE_NAMES`). Empty and failed runs
        are drawn as far as they went; the title carries the status message of a failed run.

    Notes
    -----
    The forces are the mean forces over each step, ``p / h`` (Moreau-Jean), or the forces at
    the output times (``force_N``, ``force_T`` of an event-driven result). An impact's impulse is
    not a force: a step that holds one shows its mean, p / h, which grows as h shrinks.
    """
    import matplotlib.pyplot as plt

    t = np.asarray(result.t, dtype=float)
    q = np.asarray(result.q, dtype=float).reshape(len(t), -1)
    v = np.asarray(result.v, dtype=float).reshape(len(t), -1)
    n = q.shape[1]
    labels = _names(result, system, names, n)
    if fig is None:
        fig = plt.figure(figsize=(7.5, 8.0), layout="constrained")
    ax_q, ax_v, ax_f, ax_m = fig.subplots(4, 1, sharex=True)

    # a system with Newton-Euler kinematics has fewer velocities than coordinates (their own names)
    vlabels = labels if v.shape[1] == n else list(getattr(system, "velocity_names", None)
                                                   or [f"v{i}" for i in range(v.shape[1])])
    for i in range(n):
        ax_q.plot(t, q[:, i], label=labels[i])
    for i in range(v.shape[1]):
        ax_v.plot(t, v[:, i], label=vlabels[i])
    if exact is not None:
        te = np.asarray(exact["t"], dtype=float)
        for i, name in enumerate(labels):
            if name in exact:
                ax_q.plot(te, np.asarray(exact[name], dtype=float), "k--", lw=1.0, label=f"{name} exact")
    ax_q.set_ylabel("q")
    ax_v.set_ylabel("v")

    p_N = np.asarray(result.p_N, dtype=float).reshape(max(len(t) - 1, 0), -1)
    m = p_N.shape[1]
    contact_labels = _contact_names(system, m)
    force_N = getattr(result, "force_N", None)
    force_T = getattr(result, "force_T", None)
    if force_N is not None:  # event-driven: the forces at the output times
        fN = np.asarray(force_N, dtype=float).reshape(len(t), -1)
        fT = None if force_T is None else np.asarray(force_T, dtype=float).reshape(len(t), -1)
        for j in range(m):
            line, = ax_f.plot(t, fN[:, j], label=f"N {contact_labels[j]}")
            if fT is not None and fT.shape[1] == m:
                ax_f.plot(t, fT[:, j], "--", color=line.get_color(), label=f"T {contact_labels[j]}")
    elif len(t) > 1:
        dt = np.diff(t)
        N = p_N / dt[:, None]
        T = np.asarray(result.p_T, dtype=float).reshape(len(t) - 1, -1) / dt[:, None]
        for j in range(m):
            line, = ax_f.step(t[:-1], N[:, j], where="post", label=f"N {contact_labels[j]}")
            if T.shape[1] == m:
                ax_f.step(t[:-1], T[:, j], "--", where="post", color=line.get_color(),
                          label=f"T {contact_labels[j]}")
        if T.shape[1] != m:  # spatial contacts: one column per tangent row
            for k in range(T.shape[1]):
                ax_f.step(t[:-1], T[:, k], "--", where="post", lw=0.8, label=f"T row {k}")
    impacts = getattr(result, "impacts", None) or []
    for k, imp in enumerate(impacts):
        ax_f.axvline(imp.t, color="0.5", ls=":", lw=1.0, label="impact" if k == 0 else None)
    ax_f.set_ylabel("force")

    modes = np.asarray(result.modes).reshape(max(len(t) - 1, 0), -1)
    for j in range(modes.shape[1]):
        if len(t) > 1:
            ax_m.step(t[:-1], modes[:, j] + 0.06 * (j - (modes.shape[1] - 1) / 2), where="post",
                      label=contact_labels[j])
    shown = sorted(set(np.unique(modes).tolist()) | {0, 1}) if modes.size else [0, 1]
    ax_m.set_yticks(shown, [MODE_NAMES.get(c, str(c)) for c in shown])
    ax_m.set_ylabel("mode")
    ax_m.set_xlabel("t")

    for ax in (ax_q, ax_v, ax_f, ax_m):
        handles, _ = ax.get_legend_handles_labels()
        if handles:
            ax.legend(fontsize=7, loc="best", ncol=min(3, len(handles)))
    title = f"{getattr(result, 'method', '')}"
    if getattr(result, "status", 0) < 0:
        title += f" (failed: {result.message})"
    fig.suptitle(title.strip(), fontsize=9)
    return fig


def contact_points(system) -> Callable[[np.ndarray], list[np.ndarray]]:
    """The contact points of a planar system as a function of q, for :func:`animate`.

    Each planar contact given by a tangent coordinate s(q) and a gap g(q) is drawn at (s, g): in
    its own frame (tangent along x, normal along y). For contacts on one flat floor that is where
    the contact point is.

    Parameters
    ----------
    system : System or Scene

    Returns
    -------
    callable
        ``points(q)``: a list with one array of shape (m', 2), the contacts' (s, g).

    Raises
    ------
    ValueError
        If no contact has a tangent coordinate (a planar contact given by ``tangent``).
    """
    import casadi as ca

    system = getattr(system, "system", system)  # a Scene: its System
    rows = [ca.vertcat(c.tangent, c.gap) for c in system.contacts
            if c.tangent is not None and ca.SX(c.tangent).numel() == 1]
    if not rows:
        raise ValueError("the system has no planar contact with a tangent coordinate to draw; "
                         "pass shapes=callable(q) -> list of (k, 2) arrays")
    fn = ca.Function("contact_points", [system.q_sym], [ca.horzcat(*rows).T])
    return lambda q: [np.array(fn(np.asarray(q, dtype=float)), dtype=float).reshape(-1, 2)]


def animate(result, shapes, *, path: str | pathlib.Path | None = None, fps: int = 25, every: int = 1,
            xlim: tuple[float, float] | None = None, ylim: tuple[float, float] | None = None,
            floor: float | None = 0.0, closed: bool = False, title: str = ""):
    """Animate a planar system's motion with matplotlib.

    Parameters
    ----------
    result : SimulationResult or EventResult
    shapes : callable, System or Scene
        ``shapes(q)`` returns a list of arrays of shape (k, 2): the points of each body, drawn as
        one polyline per array (closed with ``closed=True``). A ``System`` draws its contact
        points (:func:`contact_points`), as does a ``Scene``.
    path : str or Path, optional
        Save the animation there: ``.gif`` (Pillow) or ``.mp4`` (ffmpeg, which must be on the
        PATH). Nothing is saved by default.
    fps : int
        Frames per second of the saved file.
    every : int
        Draw every ``every``-th saved state.
    xlim, ylim : (float, float), optional
        Axis limits; by default the range of all points over the run, with a margin.
    floor : float or None
        Height of a floor line (None: no floor).
    closed : bool
        Close each polyline (a box, a polygon).
    title : str
        Axis title; the time is appended frame by frame.

    Returns
    -------
    matplotlib.animation.FuncAnimation
        Its figure is ``anim._fig``; the first frame is drawn, so a headless script (Agg) can save
        the figure as a still as well.

    Raises
    ------
    ValueError
        For ``every < 1``, ``fps < 1``, an unknown file suffix, or ``.mp4`` without ffmpeg.
    """
    import matplotlib.pyplot as plt
    from matplotlib import animation

    if int(every) != every or every < 1:
        raise ValueError(f"every must be an integer >= 1, got {every!r}")
    if int(fps) != fps or fps < 1:
        raise ValueError(f"fps must be an integer >= 1, got {fps!r}")
    suffix = None if path is None else pathlib.Path(path).suffix.lower()
    if suffix not in (None, ".gif", ".mp4"):
        raise ValueError(f"path must end in .gif or .mp4, got {str(path)!r}")
    if suffix == ".mp4" and not animation.FFMpegWriter.isAvailable():
        raise ValueError("saving .mp4 needs ffmpeg on the PATH; save a .gif instead")
    is_model = hasattr(shapes, "contacts") or hasattr(shapes, "system")
    draw = contact_points(shapes) if is_model else shapes
    if not callable(draw):
        raise ValueError("shapes must be a callable q -> list of (k, 2) arrays, a System or a Scene")

    t = np.asarray(result.t, dtype=float)
    q = np.asarray(result.q, dtype=float).reshape(len(t), -1)
    frames = list(range(0, len(t), int(every)))
    if frames and frames[-1] != len(t) - 1:
        frames.append(len(t) - 1)
    polys = [[np.asarray(p, dtype=float).reshape(-1, 2) for p in draw(q[k])] for k in frames]
    allpts = np.concatenate([p for ps in polys for p in ps]) if polys else np.zeros((1, 2))
    lo, hi = allpts.min(axis=0), allpts.max(axis=0)
    pad = 0.1 * max(float(np.max(hi - lo)), 1e-3)
    fig, ax = plt.subplots(figsize=(5.5, 4.0), layout="constrained")
    ax.set_xlim(xlim if xlim is not None else (lo[0] - pad, hi[0] + pad))
    ax.set_ylim(ylim if ylim is not None else (min(lo[1], floor if floor is not None else lo[1]) - pad, hi[1] + pad))
    ax.set_aspect("equal")
    if floor is not None:
        ax.axhline(floor, color="0.3", lw=1.5)
    lines = [ax.plot([], [], "o-", lw=2, ms=4)[0] for _ in polys[0]] if polys else []
    label = ax.set_title(title)

    def frame(i):
        for line, pts in zip(lines, polys[i]):
            if closed and len(pts) > 2:
                pts = np.vstack([pts, pts[:1]])
            line.set_data(pts[:, 0], pts[:, 1])
        label.set_text(f"{title}  t = {t[frames[i]]:.3f}".strip())
        return [*lines, label]

    anim = animation.FuncAnimation(fig, frame, frames=len(frames), interval=1000.0 / fps, blit=False)
    if polys:
        frame(0)
    if path is not None:
        writer = animation.PillowWriter(fps=fps) if suffix == ".gif" else animation.FFMpegWriter(fps=fps)
        anim.save(str(path), writer=writer)
    return anim
