"""numba kernels of the compiled general loop for steps with several active spatial contacts.

Holds :func:`cone_multi_step` (the contact solve of one step with two or more active contacts of
the disk law under ``"auto"``, as :class:`lcp.timestepping.contact_step.ContactStep` with
:class:`lcp.contact.spatial_solvers.ConeAutoSolver` solves it: NSGS from zero, its branch
refinement, the solver's acceptance test, the all-stick correction) and :func:`record_multi` (the
step's bookkeeping: impacts, loaded contacts, saved impulses and modes). Imports NumPy, numba
(:mod:`lcp.numerics.jit`) and the compiled kernels of :mod:`lcp.contact.spatial_nsgs`; never the
loops, the Python solvers or anything above :mod:`lcp.timestepping`.

The sweeps are those of :class:`lcp.contact.spatial_solvers.ConeNsgsSolver` (the same kernel,
:func:`~lcp.contact.spatial_nsgs.cone_nsgs_sweeps`, on W in contact-by-contact order without its
zero entries, from p = 0, stopping at a tenth of ``residual_tol`` times the problem's impulse
scale); products are summed in order (not NumPy's BLAS), so a step's impulses equal the Python
loop's to rounding, not bit for bit. A step is kept only where it passes the test the Python route
applies (:meth:`lcp.contact.solver_base.OneStepSolver.solve`: the Coulomb residual within
``residual_tol`` of max(scale, max|p|), then the natural-map error within ``residual_tol``);
anything else (sweeps that stop short, a test failed, non-finite numbers) returns False and the
Python side solves the step with its fallbacks and messages.
"""
from __future__ import annotations

import math

import numpy as np

from lcp.contact.spatial_nsgs import (
    cone_nsgs_sweeps,
    refine_dense,
    residual_blocked_dense,
    solve_dense,
)
from lcp.numerics.jit import njit
from lcp.timestepping.contact_step import CONE_RTOL

__all__ = ["cone_multi_step", "cone_natural_map_error", "record_multi", "store_solve"]

_EPS = 2.220446049250313e-16


@njit(cache=True)
def cone_natural_map_error(W, q, mu, dims, toff, p):
    """:func:`lcp.contact.law.natural_map_error` of a blocked disk-law problem (dims 1 or 2),
    sums in order: ||p - proj_K(p - u~)|| / max(||p||, ||u||, ||q||)."""
    k = mu.size
    n = q.size
    u = np.empty(n)
    for i in range(n):
        s = 0.0
        for c in range(n):
            s += W[i, c] * p[c]
        u[i] = s + q[i]
    err2 = 0.0
    for j in range(k):
        t0 = k + toff[j]
        two = dims[j] == 2
        uT0 = u[t0]
        uT1 = u[t0 + 1] if two else 0.0
        rT0 = p[t0]
        rT1 = p[t0 + 1] if two else 0.0
        zN = p[j] - u[j] - mu[j] * math.hypot(uT0, uT1)
        z0 = rT0 - uT0
        z1 = rT1 - uT1
        aT = math.hypot(z0, z1)
        inside = aT <= mu[j] * zN and zN >= 0
        polar = mu[j] * aT <= -zN
        rN = (zN + mu[j] * aT) / (1.0 + mu[j] * mu[j])
        f = 0.0 if (inside or polar) else mu[j] * rN / (aT if aT > 0 else 1.0)
        pN = zN if inside else (0.0 if polar else rN)
        pT0 = z0 if inside else z0 * f
        pT1 = z1 if inside else z1 * f
        err2 += (p[j] - pN) ** 2 + (rT0 - pT0) ** 2 + (rT1 - pT1) ** 2
    sp = 0.0
    su = 0.0
    sq = 0.0
    for i in range(n):
        sp += p[i] * p[i]
        su += u[i] * u[i]
        sq += q[i] * q[i]
    scale = max(math.sqrt(sp), math.sqrt(su), math.sqrt(sq))
    err = math.sqrt(err2)
    return err / scale if scale > _EPS else err


@njit(cache=True)
def cone_multi_step(act, na, m, n, r, o_W, o_H, o_SHt, o_b1, moving, v, vfree, dvf, uNm, mu, e, dims, toff,
                    res_tol, max_sweeps, istate, fstate, dv, P, MDo):
    """The contact solve of a step whose active contacts ``act[:na]`` (two or more) are all of the
    disk law's problem (module docstring). Fills dv (the step's velocity increment), P (the
    impulses in the blocked order: normals, then tangents contact by contact) and MDo (the modes);
    False where the Python side must solve the step."""
    k = na
    dl = np.empty(k, dtype=np.int64)
    tl = np.empty(k, dtype=np.int64)
    nl = k
    for i in range(k):
        j = act[i]
        dl[i] = dims[j]
        tl[i] = nl - k
        nl += dims[j]
    idx = np.empty(nl, dtype=np.int64)  # rows of H and W (system.contact_rows of the active set)
    for i in range(k):
        j = act[i]
        idx[i] = j
        for a in range(dl[i]):
            idx[k + tl[i] + a] = m + toff[j] + a
    Wl = np.empty((nl, nl))
    for a in range(nl):
        for b in range(nl):
            Wl[a, b] = o_W[idx[a] + idx[b] * r]
    qa = np.empty(nl)
    for a in range(nl):
        s = 0.0
        ra = idx[a]
        for c in range(n):
            s += o_H[ra + c * r] * vfree[c]
        if moving:
            s = s + o_b1[ra]
        qa[a] = s
    shift = np.zeros(k)
    for i in range(k):
        j = act[i]
        if e[j] != 0.0:
            shift[i] = e[j] * min(uNm[j], 0.0)
            qa[i] += shift[i]
    mus = np.empty(k)
    rhoN = np.empty(k)
    rhoT = np.empty(k)
    for i in range(k):
        mus[i] = mu[act[i]]
        dN = Wl[i, i]
        dT = 0.0
        for a in range(dl[i]):
            dT = max(dT, Wl[k + tl[i] + a, k + tl[i] + a])
        rhoN[i] = 1.0 / dN if dN > 0 else 1.0
        rhoT[i] = 1.0 / dT if dT > 0 else 1.0
    scale = 0.0
    for i in range(k):
        scale = max(scale, abs(qa[i]) * rhoN[i])
        for a in range(dl[i]):
            scale = max(scale, abs(qa[k + tl[i] + a]) * rhoT[i])
    scale = max(scale, 1e-300)
    if not math.isfinite(scale):
        return False
    # contact-by-contact order (ConeOperator): perm[i] is the blocked row at interleaved place i
    perm = np.empty(nl, dtype=np.int64)
    start = np.empty(k, dtype=np.int64)
    c = 0
    for i in range(k):
        start[i] = c
        perm[c] = i
        for a in range(dl[i]):
            perm[c + 1 + a] = k + tl[i] + a
        c += 1 + dl[i]
    indptr = np.zeros(nl + 1, dtype=np.int64)
    indices = np.empty(nl * nl, dtype=np.int64)
    data = np.empty(nl * nl)
    t = 0
    for a in range(nl):
        for b in range(nl):
            x = Wl[perm[a], perm[b]]
            if x != 0.0:  # the stored entries of scipy's CSR
                indices[t] = b
                data[t] = x
                t += 1
        indptr[a + 1] = t
    blocks = np.zeros((k, 3, 3))
    for i in range(k):
        for a in range(dl[i] + 1):
            for b in range(dl[i] + 1):
                blocks[i, a, b] = Wl[perm[start[i] + a], perm[start[i] + b]]
    qi = np.empty(nl)
    for a in range(nl):
        qi[a] = qa[perm[a]]
    ri = np.zeros(nl)
    tol = 0.1 * res_tol * scale
    sweeps, res_s, _ = cone_nsgs_sweeps(indptr, indices[:t], data[:t], blocks, qi, mus, dl, start, rhoN, rhoT,
                                        ri, tol, max_sweeps)
    if not res_s <= tol:
        return False
    p0 = np.empty(nl)
    for a in range(nl):
        p0[perm[a]] = ri[a]
    p, md = refine_dense(Wl, qa, mus, dl, tl, rhoN, rhoT, scale, p0, 3, 1e-9)
    pmax = 0.0
    for a in range(nl):
        if not math.isfinite(p[a]):
            return False
        pmax = max(pmax, abs(p[a]))
    res = residual_blocked_dense(Wl, qa, mus, dl, tl, rhoN, rhoT, p)
    if not math.isfinite(res) or res > res_tol * max(scale, pmax, 1e-300):
        return False
    if not cone_natural_map_error(Wl, qa, mus, dl, tl, p) <= res_tol:
        return False
    pv = p.copy()
    for a in range(n):
        s = 0.0
        for b in range(nl):
            s += o_SHt[a + idx[b] * n] * pv[b]
        dv[a] = dvf[a] + s
    stuck = True
    for i in range(k):
        stuck = stuck and md[i] == 1
    if stuck:  # every contact stuck: one correction on the velocities themselves (ContactStep.solve)
        w = np.empty(n)
        for a in range(n):
            w[a] = v[a] + dv[a]
        rl = np.empty(nl)
        for a in range(nl):
            s = 0.0
            ra = idx[a]
            for c2 in range(n):
                s += o_H[ra + c2 * r] * w[c2]
            if moving:
                s = s + o_b1[ra]
            rl[a] = -(s + shift[a]) if a < k else -s
        dp, ok = solve_dense(Wl, rl)
        if ok:  # the corrected impulse in every cone (contact_step.in_cones: the same test)
            big = 0.0
            for b in range(nl):
                big = max(big, abs(pv[b] + dp[b]))
            tol = CONE_RTOL * big
            off = k
            for i in range(k):
                pn = pv[i] + dp[i]
                if dl[i] == 1:
                    pt = abs(pv[off] + dp[off])
                else:
                    ta = pv[off] + dp[off]
                    tb = pv[off + 1] + dp[off + 1]
                    pt = math.sqrt(ta * ta + tb * tb)
                off += dl[i]
                if pn < -tol or pt > mus[i] * pn + tol:
                    ok = False
        if ok:
            for b in range(nl):
                pv[b] = pv[b] + dp[b]
            for a in range(n):
                s = 0.0
                for b in range(nl):
                    s += o_SHt[a + idx[b] * n] * dp[b]
                dv[a] = dv[a] + s
    store_solve(istate, fstate, sweeps, res, pv, nl, md, k, P, MDo)
    return True


@njit(cache=True)
def store_solve(istate, fstate, iterations, res, p, nl, md, k, P, MDo):
    """A kernel's solved step in the loop's counters (solver calls, iterations, their maximum,
    kernel-solved steps, largest residual) and its impulses and modes into P and MDo."""
    istate[2] += 1
    istate[3] += iterations
    istate[4] = max(istate[4], iterations)
    istate[18] += 1
    fstate[0] = max(fstate[0], res)
    for a in range(nl):
        P[a] = p[a]
    for i in range(k):
        MDo[i] = md[i]


@njit(cache=True)
def record_multi(act, na, m, tk, h, row, P, MDo, dims, toff, e, o_gap, uNm, uNf, loaded, ploaded, project, istate,
                 imp_t, imp_j, imp_p, PN, PT, MD):
    """The bookkeeping of a step solved by :func:`cone_multi_step`, as the Python side does it for
    a handed-over step: impacts (:func:`lcp.timestepping.outcome.record_impacts`, while some contact
    was unloaded), the loaded contacts, every contact's mode count, the saved row."""
    k = na
    if istate[0] == 0:
        tcol = k
        for i in range(k):
            j = act[i]
            pN = P[i]
            um = uNm[j]
            if pN > 0 and not loaded[j] and um < 0 and -um > abs(uNf[j] - um):
                c = istate[12]
                imp_t[c] = tk + min(h, max(0.0, o_gap[j] / -um))
                imp_j[c] = j
                imp_p[c, 0] = pN
                imp_p[c, 1] = P[tcol]
                imp_p[c, 2] = P[tcol + 1] if dims[j] == 2 else 0.0
                istate[12] = c + 1
            tcol += dims[j]
    if k < m:
        for i in range(m):
            loaded[i] = False
    allp = True
    for i in range(k):
        loaded[act[i]] = P[i] > 0
        allp = allp and P[i] > 0
    istate[0] = 1 if (k == m and allp) else 0
    if project:
        for i in range(m):
            ploaded[i] = False
        for i in range(k):
            j = act[i]
            ploaded[j] = P[i] > 0 and (e[j] == 0 or uNm[j] >= 0)
    tcol = k
    for i in range(k):
        j = act[i]
        if row >= 0:
            PN[row, j] = P[i]
            for a in range(dims[j]):
                PT[row, toff[j] + a] = P[tcol + a]
            MD[row, j] = MDo[i]
        tcol += dims[j]
        istate[5 + MDo[i]] += 1
