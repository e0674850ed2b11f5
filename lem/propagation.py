"""The LEM engine's entry point :func:`solve`: plain expansion, restarts and error propagation."""
from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from .fields import as_field
from .result import STATUS_MESSAGES, LEMOptions, LEMResult, LEMStats, LEMWarning
from .segment import EPS, Blowup, IVPFailure, Segment, propagate_segment
from .validation import check_outputs, finite_vector

if TYPE_CHECKING:
    from .fields import AnalyticField, PolynomialField

__all__ = ["solve"]


def _degrees(opts: LEMOptions) -> tuple:
    N, k = opts.degree, opts.check_step
    if not opts.check:
        return (N,)
    return tuple(d for d in (N - 2 * k, N - k, N, N + k) if d >= 1)


def solve(fun: Callable | Sequence[Mapping] | PolynomialField | AnalyticField, x_span: tuple[float, float],
          y0: ArrayLike, *, t_eval: ArrayLike | None = None, outputs: Sequence[int] | None = None,
          **options) -> LEMResult:
    """Solve ``y' = f(t, y)``, ``y(x0) = y0`` by the truncated Linear Equivalence Method.

    Parameters
    ----------
    fun : callable ``fun(t, y)``, list of ``{exponent tuple: coefficient}`` dicts, or a field
        The vector field: an analytic function written with NumPy ufuncs (see
        :class:`AnalyticField`) or a polynomial (:class:`PolynomialField`; coefficients may be
        callables of ``t``).
    x_span : (x0, x1)
        Interval of integration (x1 may be smaller than x0).
    y0 : array_like, shape (n,)
        Initial state.
    t_eval : array_like, optional
        Output points inside the interval, ordered from x0 to x1. Default: x0, x1 and every
        restart point.
    outputs : sequence of int, optional
        Components to return (default all); without restarts only the moments they need are built.
    **options
        Any field of :class:`LEMOptions` (``degree``, ``restart``, ``rtol``, ...). Unknown names
        raise ``ValueError``.

    Returns
    -------
    LEMResult
        ``t`` (m,), ``y`` (n_out, m), ``error_estimate`` (n_out, m), ``status``/``message``/
        ``success``, ``diverging``, ``sensitivity`` (n_out, n, m), ``moment_dimension``,
        ``n_restarts`` and ``stats``.

    Notes
    -----
    The plain engine (``restart=None``) expands once about ``centre`` (the origin by default,
    as in the paper): with f(0) = 0 its degree-N answer is the degree-N Taylor polynomial of the
    flow in the initial data, which converges only inside that series' radius, a radius that
    shrinks with x. The trust test compares degrees N - 2k, N - k, N, N + k: differences that
    keep growing flag divergence (status -1, :class:`LEMWarning`); otherwise the last difference
    (or its geometric extrapolation, if larger) is the error estimate. With restarts the local
    estimates are carried forward through the LEM sensitivity d y / d y0.

    Examples
    --------
    The sliding block q'' = -1 is reproduced exactly at every degree:

    >>> res = solve([{(0, 1): 1}, {(0, 0): -1}], (0.0, 2.0), [0.0, 1.5], degree=1, check=False)
    >>> res.y[:, -1].tolist()
    [1.0, -0.5]

    Restarts carry y'' = tanh y beyond the radius of the first expansion:

    >>> import numpy as np
    >>> f = lambda t, y: [y[1], np.tanh(y[0])]
    >>> res = solve(f, (0.0, 2.0), [0.0, 1.0], degree=16, restart="auto")
    >>> res.success, res.n_restarts > 0, bool(np.all(res.error_estimate < 1e-9))
    (True, True, True)
    """
    opts = LEMOptions.from_kwargs(**options)
    y0 = finite_vector("y0", y0)
    n = y0.size
    fld = as_field(fun, n)
    try:
        x0, x1 = (float(v) for v in x_span)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"x_span must be a pair (x0, x1), got {x_span!r}") from exc
    if not (np.isfinite(x0) and np.isfinite(x1)) or x0 == x1:
        raise ValueError(f"x_span must be two distinct finite numbers, got {x_span!r}")
    direction = 1.0 if x1 > x0 else -1.0
    outs = check_outputs(outputs, n)
    if t_eval is not None:
        te = finite_vector("t_eval", t_eval)
        if te.size == 0:
            raise ValueError("t_eval must not be empty")
        if np.any(direction * (te - x0) < 0) or np.any(direction * (te - x1) > 0):
            raise ValueError("t_eval must lie inside x_span")
        if np.any(direction * np.diff(te) <= 0):
            raise ValueError("t_eval must be strictly ordered from x0 to x1")
    else:
        te = None
    if opts.restart is not None and not isinstance(opts.centre, str):
        raise ValueError("centre applies only to the plain engine (restart=None); restarts "
                         "re-centre on the current state")

    stats = LEMStats()
    degrees = _degrees(opts)
    if opts.restart is None:
        if isinstance(opts.centre, str):
            centre = np.zeros(n) if opts.centre == "origin" else y0.copy()
        else:
            centre = finite_vector("centre", opts.centre, n, allow_exact=True)
        t_out = te if te is not None else np.array([x0, x1])
        return _solve_plain(fld, x0, y0, centre, t_out, outs, opts, degrees, stats)
    return _solve_restarted(fld, x0, x1, direction, y0, te, outs, opts, degrees, stats)


def _status_from(y, err, div, opts, t, nonfinite_at=None):
    if nonfinite_at is not None:
        return -2, f"{STATUS_MESSAGES[-2]} (at t = {nonfinite_at:.6g})"
    if np.any(div):
        i = int(np.argmax(div))
        return -1, f"{STATUS_MESSAGES[-1]} (first at t = {t[i]:.6g})"
    if not opts.check:
        return 2, STATUS_MESSAGES[2]
    tol = opts.atol + opts.rtol * np.abs(y)
    bad = ~(err <= tol)
    if np.any(bad):
        i = int(np.argmax(np.any(bad, axis=0)))
        return 1, (f"{STATUS_MESSAGES[1]} (first at t = {t[i]:.6g}: estimate "
                   f"{np.nanmax(err[:, i]):.3g})")
    return 0, STATUS_MESSAGES[0]


def _finish(res: LEMResult, opts: LEMOptions) -> LEMResult:
    if res.status < 0 and opts.warn:
        warnings.warn(res.message, LEMWarning, stacklevel=3)
    return res


def _solve_plain(fld, x0, y0, centre, t_out, outs, opts, degrees, stats) -> LEMResult:
    n = fld.n
    taus = t_out - x0
    nz = taus != 0.0
    m = t_out.size
    y = np.empty((len(outs), m))
    err = np.zeros((len(outs), m))
    jac = np.zeros((len(outs), n, m))
    ratio = np.full(m, np.nan)
    rad = np.zeros(m)
    div = np.zeros(m, dtype=bool)
    y[:, ~nz] = y0[list(outs)][:, None]
    jac[:, :, ~nz] = np.eye(n)[list(outs)][:, :, None]
    status_nf = None
    dim = nnz = 0
    if np.any(nz):
        try:
            seg = propagate_segment(fld, x0, y0, centre, taus[nz], outs, opts, degrees, stats,
                                    lean=False)
            y[:, nz], err[:, nz], jac[:, :, nz] = seg.y, seg.local, seg.jac
            ratio[nz], div[nz], rad[nz] = seg.ratio, seg.diverging, seg.radius
            dim, nnz = seg.dim, seg.nnz
        except Blowup as exc:
            status_nf = exc.args[0]
            y[:, nz] = np.nan
            err[:, nz] = np.inf
        except IVPFailure as exc:
            y[:, nz] = np.nan
            res = LEMResult(t_out, y, -5, f"{STATUS_MESSAGES[-5]} ({exc.args[0]})", err, div, ratio,
                            jac, opts.degree, degrees, dim, 0, np.array([x0, t_out[-1]]), stats, rad)
            return _finish(res, opts)
    if not opts.check:
        err[:, nz] = np.nan
    stats.n_segments = 1
    stats.max_nnz = nnz
    status, msg = _status_from(y, err, div, opts, t_out, status_nf)
    res = LEMResult(t_out, y, status, msg, err, div, ratio, jac, opts.degree, degrees, dim, 0,
                    np.array([x0, t_out[-1]]), stats, rad)
    return _finish(res, opts)


def _auto_ratio(seg: Segment, h: float, span: float, opts: LEMOptions) -> float:
    """Local estimate over its share of the tolerance (error per unit step: the local estimates
    of all segments then add up to at most atol + rtol*|y| before amplification by the flow)."""
    # ... but never below the rounding level of the state, which no degree can beat.
    tol = np.maximum((opts.atol + opts.rtol * np.abs(seg.y)) * (h / span), 16 * EPS * np.abs(seg.y))
    with np.errstate(invalid="ignore", divide="ignore"):
        q = np.nanmax(seg.local / tol) if seg.local.size else 0.0
    return float(q) if np.isfinite(q) or np.isinf(q) else np.inf


def _solve_restarted(fld, x0, x1, direction, y0, te, outs, opts, degrees, stats) -> LEMResult:
    n = fld.n
    allc = tuple(range(n))
    span = abs(x1 - x0)
    auto = opts.restart == "auto"
    min_step = opts.min_step if opts.min_step is not None else 1e-12 * max(span, abs(x0), 1.0)
    max_step = opts.max_step if opts.max_step is not None else span
    if auto:
        if opts.first_step is not None:
            h = opts.first_step
        else:
            e1 = fld.expansion(x0, list(y0), 1)
            lin = e1.exps.sum(axis=1) == 1
            J = np.zeros((e1.n, e1.n))
            np.add.at(J, (e1.comp[lin], np.argmax(e1.exps[lin], axis=1)), np.asarray(e1.vals[lin], float))
            h = 1.0 / (1.0 + np.abs(J).sum(axis=1).max(initial=0.0))
        h = min(h, max_step, span)
    else:
        h = min(float(opts.restart), span)
    # With w(t_c) = 0 the degree-N truncation is exact in x to order about 2N (the k-th
    # derivative only visits moments of degree <= (k + 1)/2): the local error behaves like h**(2N).
    order = 2 * opts.degree
    just_rejected = False
    t_c, state = x0, y0.copy()
    # Error propagation: the local error delta_k made in segment k reaches time t as
    # Phi(t, t_k) delta_k (signs unknown). Phi(t, t_k) = J(t) M_k is kept exactly for every earlier
    # segment (M_k = product of later segments' Jacobians): bounding with |J_m|...|J_1| instead
    # would grow like sqrt(2)**m for a mere rotation (an oscillator) and drown the estimate.
    Ms = np.zeros((0, n, n))
    deltas = np.zeros((0, n))
    S_tot = np.eye(n)                     # d state / d y0
    T_list, Y_list, E_list, J_list = [x0], [y0.copy()], [np.zeros(n)], [np.eye(n)]
    R_list, D_list, Q_list = [np.nan], [False], [0.0]
    restart_points = [x0]
    status_override = None
    dim_max = nnz_max = 0
    pending = list(te[direction * (te - x0) > 0]) if te is not None else None
    while direction * (x1 - t_c) > 0:
        if stats.n_segments >= opts.max_segments:
            status_override = (-4, f"{STATUS_MESSAGES[-4]} ({opts.max_segments}, at t = {t_c:.6g})")
            break
        if auto and opts.step_hint is not None and not just_rejected \
                and stats.n_segments < len(opts.step_hint):
            h = min(opts.step_hint[stats.n_segments], max_step)
        h = min(h, abs(x1 - t_c))
        if abs(x1 - t_c) - h < 1e-14 * max(span, 1.0):
            h = abs(x1 - t_c)
        t_end = t_c + direction * h
        if pending is not None:
            inside = [p for p in pending if direction * (p - t_end) < 0]
            pts = inside + [t_end]
        else:
            pts = [t_end]
        taus = np.array(pts) - t_c
        try:
            seg = propagate_segment(fld, t_c, state, state, taus, allc, opts, degrees, stats)
            failed = None
        except Blowup as exc:
            seg, failed = None, ("blowup", exc.args[0])
        except IVPFailure as exc:
            seg, failed = None, ("ivp", exc.args[0])
        if auto:
            if seg is not None:
                q = _auto_ratio(seg, h, span, opts)
                reach = float(seg.radius.max(initial=0.0))
                ok = (not np.any(seg.diverging)) and np.isfinite(q) and q <= 1.0 \
                    and reach <= opts.radius_fraction
            else:
                ok, q, reach = False, np.inf, 0.0
            if not ok:
                stats.n_rejected += 1
                if failed is not None and failed[0] == "ivp":
                    status_override = (-5, f"{STATUS_MESSAGES[-5]} ({failed[1]})")
                    break
                if not np.isfinite(q) or seg is None or np.any(seg.diverging):
                    fac = 0.3
                elif q > 1.0:
                    fac = max(0.2, min(0.7, 0.9 * q ** (-1.0 / order)))
                else:
                    fac = 0.7
                if reach > opts.radius_fraction:
                    # the displacement grows about linearly with the segment
                    fac = min(fac, max(0.1, 0.9 * opts.radius_fraction / reach))
                h *= fac
                just_rejected = True
                if h < min_step:
                    status_override = (-3, f"{STATUS_MESSAGES[-3]} (at t = {t_c:.6g}, step {h:.3g})")
                    break
                continue
        else:
            if seg is None:
                if failed[0] == "ivp":
                    status_override = (-5, f"{STATUS_MESSAGES[-5]} ({failed[1]})")
                else:
                    status_override = (-2, f"{STATUS_MESSAGES[-2]} (at t = {failed[1]:.6g})")
                break
        # accept the segment
        stats.n_segments += 1
        dim_max, nnz_max = max(dim_max, seg.dim), max(nnz_max, seg.nnz)
        loc = seg.local if opts.check else np.zeros_like(seg.y)
        for i, p in enumerate(pts):
            Ji = seg.jac[:, :, i]
            T_list.append(p)
            Y_list.append(seg.y[:, i].copy())
            carried = np.einsum("kij,kj->i", np.abs(np.matmul(Ji, Ms)), deltas) if deltas.size else 0.0
            E_list.append(carried + np.nan_to_num(loc[:, i], nan=0.0))
            J_list.append(Ji @ S_tot)
            R_list.append(seg.ratio[i])
            D_list.append(bool(seg.diverging[i]))
            Q_list.append(float(seg.radius[i]))
        state = seg.y[:, -1].copy()
        Ms = np.concatenate([np.matmul(seg.jac[:, :, -1], Ms), np.eye(n)[None]], axis=0)
        deltas = np.vstack([deltas, np.nan_to_num(loc[:, -1], nan=0.0)[None]])
        S_tot = J_list[-1].copy()
        t_c = t_end
        restart_points.append(t_c)
        if pending is not None:
            pending = [p for p in pending if direction * (p - t_end) > 0]
        if not auto and np.any(seg.diverging):
            break  # the state is garbage beyond this point: stop honestly
        if auto:
            # No growth right after a rejection: near the radius of convergence the error jumps
            # from rounding level to divergence within a factor 2 of h, and growing at once
            # would only be rejected again.
            q = _auto_ratio(seg, h, span, opts)
            cap = 1.0 if just_rejected else 2.0
            grow = cap if q <= 0 else min(cap, max(1.0, 0.9 * q ** (-1.0 / order)))
            reach = float(seg.radius.max(initial=0.0))
            if reach > 0:
                grow = min(grow, max(1.0, 0.9 * opts.radius_fraction / reach))
            h = min(h * grow, max_step)
            just_rejected = False
    T = np.array(T_list)
    Y = np.array(Y_list).T
    Ev = np.array(E_list).T
    Jv = np.transpose(np.array(J_list), (1, 2, 0))
    Rv = np.array(R_list)
    Dv = np.array(D_list)
    Qv = np.array(Q_list)
    if te is not None:
        wanted = set(te.tolist())
        keep = [i for i, tt in enumerate(T.tolist()) if tt in wanted]
        T, Y, Ev, Jv, Rv, Dv, Qv = (T[keep], Y[:, keep], Ev[:, keep], Jv[:, :, keep], Rv[keep],
                                    Dv[keep], Qv[keep])
    sel = list(outs)
    Y, Ev, Jv = Y[sel], Ev[sel], Jv[sel]
    if not opts.check:
        Ev = np.where(T[None, :] == x0, 0.0, np.nan)
    stats.max_nnz = nnz_max
    if np.any(Dv) or status_override is None:
        status, msg = _status_from(Y, Ev, Dv, opts, T)
    else:
        status, msg = status_override
    res = LEMResult(T, Y, status, msg, Ev, Dv, Rv, Jv, opts.degree, degrees, dim_max,
                    max(0, stats.n_segments - 1), np.array(restart_points), stats, Qv)
    return _finish(res, opts)
