"""One expansion segment of the LEM engine: scaling, propagation, truncation differences.

:func:`propagate_segment` expands the field about a centre, builds the moment systems of the
degrees compared by the a-posteriori check, scales the moments, propagates them (and the
sensitivity d y / d state) to the requested times, and turns the differences between degrees
into a local error estimate and a divergence flag.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.integrate import solve_ivp
from scipy.linalg import expm
from scipy.optimize import minimize
from scipy.sparse.linalg import expm_multiply

from .expmv import expmv, nonnegative_expm, onenorm
from .fields import Expansion
from .jets import RADIUS_TRUST
from .moments import MomentSystem, build_system
from .result import LEMOptions, LEMStats

__all__ = ["EPS", "Blowup", "IVPFailure", "Segment", "propagate_segment"]

EPS = np.finfo(float).eps
# Differences between truncations below this (relative to max(1, |y|)) are rounding noise, not a
# trend: they never count as divergence. Measured noise of the degree-61 tanh system is ~1e-15.
_NOISE = 1e3 * EPS
#: Small systems whose ||A|| dt exceeds this use a dense matrix exponential instead of expmv.
_DENSE_NORM, _DENSE_DIM = 500.0, 600


class Blowup(Exception):
    pass


class IVPFailure(Exception):
    pass


def _propagate(S: MomentSystem, B: np.ndarray, taus: np.ndarray, t_c: float, opts: LEMOptions,
               stats: LEMStats, lean: bool = True) -> tuple:
    """Moments' output rows at each tau (relative to t_c), shape (len(taus), n_out, ncols), and the
    rounding level of the first column there, shape (len(taus),), in units of the scaled moments.

    The rounding level is what the propagation itself cannot resolve: about eps times the number
    of matrix-vector products (~ ||A||_1 tau) times what feeds the output rows, |v_i| + tau
    (|A| |V|)_i (for solve_ivp: its rtol instead of eps). Differences between truncations below
    it are noise, not a trend.
    """
    out = np.empty((taus.size, S.outputs.size, B.shape[1]))
    noise = np.empty(taus.size)
    t0 = time.perf_counter()
    if not S.varying:
        anorm = onenorm(S.A)
        V, prev = B, 0.0
        for i, tau in enumerate(taus):
            dt = tau - prev
            if dt != 0.0:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RuntimeWarning)
                    if anorm * abs(dt) > _DENSE_NORM and S.dimension <= _DENSE_DIM:
                        # stiff segment (a smoothed friction law after the stop: rates ~ 1/eps):
                        # expmv needs ~||A|| dt products, scaling and squaring log2 of it
                        V = expm(S.A.toarray() * dt) @ V
                    elif lean:
                        # scaled Taylor series without a shift by trace(A)/n: for moment matrices
                        # (diagonal ~ degree x growth rate) the shift costs digits, 3e-13 instead
                        # of 1e-16 on the logistic equation at degree 60
                        V = expmv(S.A, V, dt, anorm)
                    else:
                        V = expm_multiply(S.A * dt, V, traceA=0.0)
                stats.n_propagations += 1
                if not np.all(np.isfinite(V)):
                    stats.solve_time += time.perf_counter() - t0
                    raise Blowup(t_c + tau)
            out[i] = V[S.outputs]
            feed = np.abs(V[S.outputs, 0]) + abs(tau) * _abs_rows_dot(S.A, S.outputs, V[:, 0])
            noise[i] = EPS * (16.0 + 4.0 * anorm * abs(tau)) * feed.max(initial=0.0)
            prev = tau
    else:
        ncols = B.shape[1]

        def rhs(tau, v):
            V = v.reshape(-1, ncols)
            dV = S.A @ V
            for a, Ai in S.varying:
                dV = dV + a(t_c + tau) * (Ai @ V)
            return dV.ravel()

        res = solve_ivp(rhs, (0.0, taus[-1]), B.ravel(), method=opts.ivp_method, t_eval=taus,
                        rtol=opts.ivp_rtol, atol=opts.ivp_atol)
        stats.n_propagations += 1
        if res.status < 0 or res.y.shape[1] != taus.size:
            stats.solve_time += time.perf_counter() - t0
            raise IVPFailure(res.message)
        Y = res.y.T.reshape(taus.size, -1, ncols)
        if not np.all(np.isfinite(Y)):
            stats.solve_time += time.perf_counter() - t0
            raise Blowup(t_c + taus[-1])
        out[:] = Y[:, S.outputs, :]
        noise[:] = 10.0 * opts.ivp_rtol * np.abs(Y[:, S.outputs, 0]).max(axis=1)
    stats.solve_time += time.perf_counter() - t0
    return out, noise


@dataclass
class Segment:
    y: np.ndarray        # (n_out, m) degree-N values
    local: np.ndarray    # (n_out, m) local error estimate
    jac: np.ndarray      # (n_out, n, m) d y / d state at start
    ratio: np.ndarray    # (m,)
    diverging: np.ndarray  # (m,) bool
    dim: int
    nnz: int
    radius: np.ndarray   # (m,) displacement of f's singular arguments / distance to singularity


def _scales(exp: Expansion, w0: np.ndarray, h: float, t_c: float, N: int) -> np.ndarray:
    """Powers of two rho_i by which the moments are scaled: they are propagated as (w/rho)**gamma.

    The scaling is the similarity A -> D^-1 A D, D = diag(rho**gamma), which changes nothing in
    exact arithmetic (nor, with powers of two, in rounding), but matters twice in practice:

    * the Taylor propagator controls its error relative to the whole moment vector, so rho must be close
      to the displacement |w| actually reached: if rho >> |w| the degree-1 moments drown under
      v_0 = 1 (the slide q'' = -1 lost its -t**2/2 that way); if rho << |w| the high moments
      (w/rho)**N swamp them. Hence rho_i lies between |w0_i| and a two-term estimate
      r = |w0| + h a0 + h J (|w0| + h a0) of the displacement over the segment (a0 = f(centre),
      J = |Jacobian|), and as close to r as the next point allows;
    * its cost grows with the norm of A: unscaled, large Taylor coefficients of f (sinh(lambda y)
      with z ~ 1e5 near a pole of Troesch's solution) need 1e4-1e5 matrix-vector products per
      segment. Within [max(|w0|, r / 2**20), r], rho is the largest scale whose row-sum bound
      max_j sum_mu |a_jmu| rho**mu / rho_j (of A / |gamma|, convex in log rho) is within a factor
      4 of the smallest: it drops below r only when that tames large coefficients (tanh beyond
      its radius pi/2, where r overestimates the displacement).
    """
    n = exp.n
    comp = [exp.comp] + [c for _, c, _, _ in exp.varying]
    exps = [exp.exps] + [e for _, _, e, _ in exp.varying]
    vals = [np.asarray(exp.vals, dtype=float)] + [float(a(t_c)) * np.asarray(v, dtype=float)
                                                  for a, _, _, v in exp.varying]
    comp, exps, vals = np.concatenate(comp), np.vstack(exps), np.abs(np.concatenate(vals))
    keep = vals > 0
    comp, exps, vals = comp[keep], exps[keep], vals[keep]
    if comp.size == 0 or not np.all(np.isfinite(vals)):
        return np.ones(n)
    deg = exps.sum(axis=1)
    a0, J = np.zeros(n), np.zeros((n, n))
    np.add.at(a0, comp[deg == 0], vals[deg == 0])
    one = deg == 1
    np.add.at(J, (comp[one], np.argmax(exps[one], axis=1)), vals[one])
    # |w(t)| <= expm(t |J|) (|w0| + t a0) to first order: the growth of the linearization matters,
    # since the top moments of a truncation grow like exp(N lambda t) (w0/rho)**N when rho is small
    with np.errstate(over="ignore", invalid="ignore"):
        r = nonnegative_expm(np.minimum(abs(h) * J, 700.0 / n)) @ (np.abs(w0) + abs(h) * a0)
    r = np.where(np.isfinite(r), r, np.finfo(float).max)
    B = max(1, int(600 // max(N, 1)))
    with np.errstate(divide="ignore"):
        up = np.where(r > 0, np.ceil(np.log2(np.where(r > 0, r, 1.0))), 0.0)
        lo = np.where(w0 != 0, np.ceil(np.log2(np.where(w0 != 0, np.abs(w0), 1.0))), up - 20)
    up, lo = np.clip(up, -B, B), np.clip(lo, -B, B)
    lo = np.minimum(lo, up)
    if np.all(lo == up):
        return np.exp2(up)
    exps = exps.astype(float)
    L = np.log2(vals)
    comps = np.unique(comp)
    members = [np.flatnonzero(comp == j) for j in comps]
    sizes = up - lo + 1
    if np.prod(sizes) <= 20000:
        # few candidates (the usual case): evaluate the exact bound on the whole grid
        axes = [np.arange(l, u + 1) for l, u in zip(lo, up)]
        U = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, n)
        X = L[None, :] + U @ exps.T
        F = np.full(U.shape[0], -np.inf)
        for j, mem in zip(comps, members):
            Xj = X[:, mem]
            m = Xj.max(axis=1)
            F = np.maximum(F, m + np.log2(np.exp2(Xj - m[:, None]).sum(axis=1)) - U[:, j])
        # the largest scales (closest to the displacement estimate) whose bound is within a
        # factor 4 of the best: a smaller rho is only worth it when it tames big coefficients
        best = np.flatnonzero(F <= F.min() + 2.0)
        return np.exp2(U[best[np.argmax(U[best].sum(axis=1))]])
    beta = 8.0  # smooth max over components; convex in u = log2(rho), so a local solver suffices

    def objective(u):
        X = L + exps @ u
        g = np.empty(comps.size)
        grads = np.zeros((comps.size, n))
        for k, (j, mem) in enumerate(zip(comps, members)):
            Xj = X[mem]
            m = Xj.max()
            w = np.exp2(Xj - m)
            sw = w.sum()
            g[k] = m + np.log2(sw) - u[j]
            grads[k] = (w / sw) @ exps[mem]
            grads[k, j] -= 1.0
        gm = g.max()
        p = np.exp2(beta * (g - gm))
        ps = p.sum()
        return gm + np.log2(ps) / beta, (p / ps) @ grads

    res = minimize(objective, up.copy(), jac=True, method="L-BFGS-B",
                   bounds=list(zip(lo.tolist(), up.tolist())), options={"maxiter": 100})
    u = np.clip(np.round(res.x if np.all(np.isfinite(res.x)) else up), lo, up)
    # as on the grid: move up towards the displacement estimate while the bound stays within 4x
    fmin = objective(u)[0]
    for i in range(n):
        while u[i] < up[i]:
            trial = u.copy()
            trial[i] += 1
            if objective(trial)[0] > fmin + 2.0:
                break
            u = trial
    return np.exp2(u)


def _scaled(S: MomentSystem, scale: np.ndarray) -> MomentSystem:
    """The same system for the moments V / scale (a diagonal similarity transform)."""
    if np.all(scale == 1.0):
        return S
    A = scaled_csr(S.A, scale)
    varying = [(a, scaled_csr(B, scale)) for a, B in S.varying]
    return MomentSystem(A, varying, S.exponents, S.degree, S.outputs, S.constant_index, None,
                        S.n_vars, S.codes, S.pw)


def scaled_csr(A: sp.csr_matrix, scale: np.ndarray) -> sp.csr_matrix:
    """diag(1/scale) A diag(scale), computed on the stored entries (same pattern as A).

    >>> import numpy as np, scipy.sparse as sp
    >>> A = sp.csr_matrix(np.array([[1.0, 2.0], [3.0, 4.0]]))
    >>> scaled_csr(A, np.array([1.0, 2.0])).toarray().tolist()
    [[1.0, 4.0], [1.5, 4.0]]
    """
    rows = np.repeat(np.arange(A.shape[0]), np.diff(A.indptr))
    data = A.data * (scale[A.indices] / scale[rows])
    return sp.csr_matrix((data, A.indices, A.indptr), shape=A.shape)


def _abs_rows_dot(A: sp.csr_matrix, rows: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(|A| |v|) at the given rows only."""
    out = np.empty(rows.size)
    for k, r in enumerate(rows):
        sl = slice(A.indptr[r], A.indptr[r + 1])
        out[k] = np.abs(A.data[sl]) @ np.abs(v[A.indices[sl]])
    return out


def propagate_segment(fld, t_c: float, state: np.ndarray, centre, taus: np.ndarray, outs,
                      opts: LEMOptions, degrees: tuple, stats: LEMStats, lean: bool = True) -> Segment:
    """Propagate one expansion about ``centre`` from ``state`` at t_c to t_c + taus.

    ``lean`` propagates with :func:`lem.expmv.expmv` (restart segments: many short, well-scaled
    propagations, where its fixed cost matters); otherwise with SciPy's ``expm_multiply``, as the
    plain engine always did: its one long expansion (||A|| tau in the hundreds, moments over many
    orders of magnitude) loses digits to rounding in either propagator, and keeping SciPy's keeps
    its results and error estimates bit-identical.
    """
    N = opts.degree
    n = fld.n
    Dmax = max(degrees)
    tdeg = Dmax if opts.taylor_degree is None else min(opts.taylor_degree, Dmax)
    t0 = time.perf_counter()
    full = fld.expansion(t_c, list(centre), tdeg)
    stats.build_time += time.perf_counter() - t0
    stats.time_varying |= bool(full.varying)
    stats.time_augmented |= full.time_augmented
    w0 = np.zeros(full.n)
    w0[:n] = np.asarray(state, dtype=float) - np.asarray([float(c) for c in centre])
    rho = _scales(full, w0, float(taus[-1]), t_c, max(degrees))
    values, jac, dim, nnz = {}, None, 0, 0
    noise = np.zeros((len(outs), taus.size))
    for D in degrees:
        t0 = time.perf_counter()
        exp = full.truncated(D if opts.taylor_degree is None else min(opts.taylor_degree, D))
        S = build_system(exp, D, outs, opts.prune, opts.max_dimension)
        stats.build_time += time.perf_counter() - t0
        stats.n_systems += 1
        V0 = S.initial_moments(w0)
        scale = np.prod(rho[None, :] ** S.exponents, axis=1)
        S_run = _scaled(S, scale)
        if D == N:
            # d V0 / d w0_j = gamma_j w0**(gamma - e_j): propagating it gives the sensitivity.
            cols = [V0]
            for j in range(n):
                g = S.exponents
                e = g.copy()
                e[:, j] -= 1
                with np.errstate(invalid="ignore"):
                    dv = np.where(g[:, j] > 0, g[:, j] * np.prod(w0[None, :] ** np.maximum(e, 0), axis=1), 0.0)
                cols.append(dv)
            B = np.column_stack(cols) / scale[:, None]
            dim, nnz = S.dimension, S.nnz
            stats.taylor_degree = exp.exps.sum(axis=1).max(initial=0)
        else:
            B = (V0 / scale)[:, None]
        P, nz = _propagate(S_run, B, taus, t_c, opts, stats, lean)
        P = P * rho[list(outs)][None, :, None]
        noise = np.maximum(noise, rho[list(outs)][:, None] * nz[None, :])
        c_out = np.array([float(centre[i]) for i in outs])
        values[D] = P[:, :, 0].T + c_out[:, None]
        if D == N:
            jac = np.transpose(P[:, :, 1:], (1, 2, 0))
    yN = values[N]
    m = taus.size
    local = np.full(yN.shape, np.nan)
    ratio = np.full(m, np.nan)
    diverging = np.zeros(m, dtype=bool)
    if opts.check and len(degrees) > 1:
        k = opts.check_step
        d3 = np.abs(values[N + k] - yN)
        d2 = np.abs(yN - values[N - k]) if (N - k) in values else None
        d1 = np.abs(values[N - k] - values[N - 2 * k]) if (N - 2 * k) in values else None
        floor = np.maximum(_NOISE * np.maximum(1.0, np.abs(yN)), noise)
        local = d3.copy()
        if d2 is not None:
            with np.errstate(divide="ignore", invalid="ignore"):
                r32 = np.where(d3 > floor, d3 / np.maximum(d2, 1e-300), 0.0)
            grow = (d3 > floor) & (r32 >= 1.0)
            if d1 is not None:
                # one freak small difference (a coefficient that happens to vanish) must not decide:
                # divergence needs growth over the last step and over two steps.
                grow &= d3 >= d1
                with np.errstate(divide="ignore", invalid="ignore"):
                    expected = np.where(d1 > 0, d2 * d2 / np.where(d1 > 0, d1, 1.0), 0.0)
                local = np.maximum(local, np.where(d2 > floor, expected, 0.0))
            # moments so large that rounding alone exceeds the solution: the series has blown up
            # even if the differences cannot show a trend any more
            grow |= noise > np.maximum(np.abs(yN), opts.atol)
            diverging = np.any(grow, axis=0)
            ratio = np.max(r32, axis=0)
            # geometric tail of the remaining degrees: slow convergence (ratio near 1) must not
            # pass for accuracy (the ratio is capped so a freak value cannot make it infinite)
            q_tail = np.clip(np.where(d2 > floor, r32, 0.0), 0.0, 0.95)
            local = local / (1.0 - q_tail)
    # Truncation differences cannot see a singularity of f whose Taylor coefficients are tiny at
    # the centre (tanh(v/eps) saturated: sech**2 underflows, every truncation agrees, and the state
    # slides across v = 0 where tanh turns). The jets know where each singularity is: beyond
    # RADIUS_TRUST of the distance, f's own series no longer represents f.
    W = np.zeros((n, m))
    W[list(outs)] = yN - c_out[:, None]
    radius = full.radius_ratio(W, taus)
    diverging = diverging | (radius >= RADIUS_TRUST)
    return Segment(yN, local, jac, ratio, diverging, dim, nnz, radius)
