"""numba kernels of the compiled general loop for steps with several active planar contacts.

Holds :func:`planar_multi_step`: the contact solve of one step with two or more active planar
contacts under ``"auto"`` (or ``"nsgs"``), as :class:`lcp.timestepping.contact_step.ContactStep`
with :class:`lcp.contact.solvers.AutoSolver` solves it on a system whose W changes from step to step
(no warm start): :class:`lcp.contact.solvers.NewtonSolver`'s rounds (NSGS sweeps from zero by the
compiled sweeps of :func:`lcp.contact.nsgs.nsgs_sweeps`, then semismooth Newton,
:func:`lcp.contact.newton.newton_solve`'s iteration), the outer loop of
:class:`lcp.contact.solvers.PlanarIterativeSolver` (the contact-by-contact test, the error target),
the acceptance test of :meth:`lcp.contact.solver_base.OneStepSolver.solve`, the modes
(:meth:`lcp.contact.problem.ContactProblem.modes`) and the branch refinement (the dense
:meth:`~lcp.contact.planar_branches.PlanarBranches.solve_branch`). The step's bookkeeping is
:func:`lcp.timestepping.multi_kernels.record_multi`'s (its counters and stores:
:func:`~lcp.timestepping.multi_kernels.store_solve`). Imports NumPy, numba
(:mod:`lcp.numerics.jit`), the compiled kernels of :mod:`lcp.contact.nsgs`, the products of
:mod:`lcp.timestepping.step_products`, ``store_solve`` and the cone tolerance of
:mod:`lcp.timestepping.contact_step`; never the loops, the Python solvers or anything above
:mod:`lcp.timestepping`.

The arithmetic is the Python route's, operation for operation (the same sweeps kernel on the same
contact-by-contact CSR arrays, the same natural-map kernels, NumPy's products by
:mod:`~lcp.timestepping.step_products`, LAPACK's solve of the branch system), with one exception:
Newton's linear systems, which the Python solver factorizes with SuperLU, are solved here by
LAPACK's dense LU (the same equations, another rounding). A step whose sweeps converge before any
Newton iteration therefore gives the Python loop's bits; a step that took Newton iterations agrees
to rounding, and is handed back to Python (False) where a mode decision lies within 1 % of its
threshold, so that the rounding cannot choose another branch than the Python loop. Where Newton's
matrix is singular (redundant contacts, e.g. a block flat on two sticking corners: its tangential
impulses are not unique, only their sum), both solve it with the Levenberg shift of
:func:`~lcp.contact.newton.newton_solve`, which amplifies the rounding: the split of the tangential
impulse between such contacts then agrees to 4e-8 (the rocking block at rest) to 1.3e-4 (a block
carried by a belt) of the largest tangential impulse, within the Python loop's own sensitivity (its
split moves by up to 2e-4 when its problem's q changes by one ulp); their sum, the normal impulses,
velocities and positions agree to rounding. Any failure
(a round that does not converge, a test failed, non-finite numbers) returns False before anything
is counted: the Python side solves the step with its fallbacks (core pivot, Lemke) and notes.
"""
from __future__ import annotations

import math

import numpy as np

from lcp.contact.law import COUPLING_FLOOR, SCALE_FLOOR
from lcp.contact.nsgs import checks_blocked_dense, nsgs_sweeps, residual_blocked_dense
from lcp.numerics.jit import njit
from lcp.timestepping.contact_step import CONE_RTOL
from lcp.timestepping.multi_kernels import store_solve
from lcp.timestepping.step_products import cols_f, matvec, rows

__all__ = ["MODE_MARGIN", "planar_multi_step", "solve_planar"]

#: a step that took Newton iterations goes back to Python where a mode's test quantity lies within
#: this fraction of its threshold (the rounding of another LU could then flip the mode)
MODE_MARGIN = 0.01


@njit(cache=True)
def _finite(x):
    for a in range(x.size):
        if not math.isfinite(x[a]):
            return False
    return True


@njit(cache=True)
def _measure(W, q, mu, rho, p, rel_scale):
    """ContactProblem.residual (rel_scale 0) or ContactProblem.stop_measure (rel_scale = the
    problem's scale) of p; NaN where p is not finite (the step then goes back to Python)."""
    if not _finite(p):
        return np.nan
    if rel_scale == 0.0:
        return residual_blocked_dense(W, q, mu, rho, p)
    res, rel, _ = checks_blocked_dense(W, q, mu, rho, p, SCALE_FLOOR * rel_scale)
    return max(res, rel_scale * rel)


@njit(cache=True)
def _dot(x):
    """x @ x as NumPy's BLAS dot sums it (in order for short vectors, step_products.matvec)."""
    return matvec(x.reshape((1, x.size)), x)[0]


@njit(cache=True)
def _alart_curnier(W, q, mu, rho, p, phi, closed, stick, sgn):
    """lcp.contact.newton.alart_curnier: Phi(p) into phi and the piece (closed, stick, sign of z_T);
    W p summed in order over W's nonzero entries (SciPy's CSR product)."""
    k = mu.size
    n2 = 2 * k
    u = np.empty(n2)
    for i in range(n2):
        s = 0.0
        for c in range(n2):
            w = W[i, c]
            if w != 0.0:
                s += w * p[c]
        u[i] = s + q[i]
    for j in range(k):
        zN = p[j] - rho[j] * u[j]
        zT = p[k + j] - rho[k + j] * u[k + j]
        closed[j] = zN > 0
        zp = max(zN, 0.0)
        s = mu[j] * zp
        stick[j] = closed[j] and abs(zT) < s
        phi[j] = p[j] - zp
        phi[k + j] = p[k + j] - min(max(zT, -s), s)
        sgn[j] = 1.0 if zT > 0 else (-1.0 if zT < 0 else 0.0)


@njit(cache=True)
def _jacobian(W, mu, rho, closed, stick, sgn):
    """lcp.contact.newton._jacobian's J = A + B W, dense, entry by entry as SciPy computes it
    (each entry one product and at most one sum)."""
    k = mu.size
    n2 = 2 * k
    J = np.zeros((n2, n2))
    for j in range(k):
        if closed[j]:
            for c in range(n2):
                J[j, c] = rho[j] * W[j, c]
        else:
            J[j, j] = 1.0
        i = k + j
        if stick[j]:
            for c in range(n2):
                J[i, c] = rho[i] * W[i, c]
        elif closed[j]:  # sliding: p_T - sgn mu (p_N - rho_N u_N)
            cc = sgn[j] * mu[j]
            b = cc * rho[j]
            for c in range(n2):
                J[i, c] = b * W[j, c]
            J[i, i] = 1.0 + J[i, i]
            J[i, j] = -cc + J[i, j]
        else:
            J[i, i] = 1.0
    return J


@njit(cache=True)
def _newton(W, q, mu, rho, p0, tol, max_iter, rel_scale, max_damped=8):
    """lcp.contact.newton.newton_solve from p0 (the stopping measure :func:`_measure`), Newton's
    systems by LAPACK's LU: (p, iterations)."""
    k = mu.size
    n2 = 2 * k
    p = p0.copy()
    res = _measure(W, q, mu, rho, p, rel_scale)
    if res <= tol:
        return p, 0
    phi = np.empty(n2)
    closed = np.zeros(k, dtype=np.bool_)
    stick = np.zeros(k, dtype=np.bool_)
    sgn = np.empty(k)
    _alart_curnier(W, q, mu, rho, p, phi, closed, stick, sgn)
    merit = _dot(phi)
    damped = 0
    phin = np.empty(n2)
    for it in range(1, max_iter + 1):
        J = _jacobian(W, mu, rho, closed, stick, sgn)
        rhs = -phi
        ok = True
        try:
            d = np.linalg.solve(J, rhs)
        except Exception:
            ok = False
            d = rhs
        if not ok:  # a singular piece: the tiny Levenberg shift of newton_solve (numba: no try in except)
            big = 0.0
            for a in range(n2):
                for c in range(n2):
                    big = max(big, abs(J[a, c]))
            shift = 1e-12 * max(1.0, big)
            for a in range(n2):
                J[a, a] = J[a, a] + shift
            ok = True
            try:
                d = np.linalg.solve(J, rhs)
            except Exception:
                ok = False
        if not ok or not _finite(d):
            return p, it
        t = 1.0
        found = False
        for _ in range(40):  # lcp.contact.newton.armijo
            pn = p + t * d
            _alart_curnier(W, q, mu, rho, pn, phin, closed, stick, sgn)
            m_new = _dot(phin)
            if m_new <= (1 - 1e-4 * t) * merit or m_new == 0.0:
                found = True
                break
            t *= 0.5
        if not found:
            return p, it
        p = pn
        merit = m_new
        for a in range(n2):
            phi[a] = phin[a]
        res = _measure(W, q, mu, rho, p, rel_scale)
        if res <= tol:
            return p, it
        damped = damped + 1 if t < 1.0 else 0
        if damped >= max_damped:
            return p, it
    return p, max_iter


@njit(cache=True)
def _sweep_blocked(op_p, op_i, op_x, blocks, orho, perm, qi, mu, p, tol, n_sw, rel_scale):
    """lcp.contact.solver_base.sweep_blocked: NSGS sweeps from p (blocked order), a new array."""
    n2 = p.size
    r = np.empty(n2)
    for a in range(n2):
        r[a] = p[perm[a]]
    sw, res, _ = nsgs_sweeps(op_p, op_i, op_x, blocks, qi, mu, orho, r, tol, n_sw, rel_scale)
    out = np.empty(n2)
    for a in range(n2):
        out[perm[a]] = r[a]
    return out, sw, res


@njit(cache=True)
def _newton_run(W, q, mu, rho, op_p, op_i, op_x, blocks, orho, perm, qi, p, tol, rel_scale, sweeps, newton_iter,
                max_rounds):
    """NewtonSolver._run: rounds of NSGS sweeps (doubling) and Newton; (p, iterations, measure,
    whether a Newton iteration was taken: the rounding is then not the Python route's)."""
    res = np.inf
    its = 0
    slow = 0
    res_failed = np.inf
    res_prev = np.inf
    newton_used = False
    for rnd in range(max_rounds):
        if res <= tol:
            break
        if rnd >= 2 and res > 0.9 * res_prev:
            slow += 1
            if slow >= 2:
                break
        else:
            slow = 0
        res_prev = res
        if sweeps == 0 and rnd == 0:
            res = _measure(W, q, mu, rho, p, rel_scale)
            if res <= tol:
                break
        if sweeps:
            n_sw = sweeps * 2 ** min(rnd, 10)
            p_s, sw, res_s = _sweep_blocked(op_p, op_i, op_x, blocks, orho, perm, qi, mu, p, tol, n_sw, rel_scale)
            its += sw
            if res_s <= res:
                p = p_s
                res = res_s
            if res <= tol:
                break
        if newton_iter == 0 or res > 0.01 * res_failed:  # 0: NsgsSolver (its sweeps alone)
            continue
        p_n, it = _newton(W, q, mu, rho, p, tol, newton_iter, rel_scale)
        its += it
        # an iteration taken, kept or not, is LAPACK's rounding (its residual steers the rounds)
        newton_used = newton_used or it > 0
        res_n = _measure(W, q, mu, rho, p_n, rel_scale)
        res_failed = res if res_n > 0.5 * res else np.inf
        if res_n <= res:
            p = p_n
            res = res_n
    return p, its, res, newton_used


@njit(cache=True)
def _solve(Wl, qa, mus, rho, scale, res_tol, sweeps, newton_iter, max_rounds):
    """AutoSolver's solve of a problem of two or more planar contacts (NewtonSolver through
    PlanarIterativeSolver._solve and OneStepSolver.solve, no warm start): (ok, p, iterations,
    residual, Newton used)."""
    k = mus.size
    n2 = 2 * k
    # the contact-by-contact operator (lcp.contact.nsgs.InterleavedOperator): CSR of W[perm][:, perm]
    # without its zero entries, columns in order
    perm = np.empty(n2, dtype=np.int64)
    for j in range(k):
        perm[2 * j] = j
        perm[2 * j + 1] = k + j
    op_p = np.zeros(n2 + 1, dtype=np.int64)
    op_i = np.empty(n2 * n2, dtype=np.int64)
    op_x = np.empty(n2 * n2)
    t = 0
    for a in range(n2):
        for b in range(n2):
            x = Wl[perm[a], perm[b]]
            if x != 0.0:
                op_i[t] = b
                op_x[t] = x
                t += 1
        op_p[a + 1] = t
    op_i = op_i[:t]
    op_x = op_x[:t]
    blocks = np.empty((k, 4))
    orho = np.empty(n2)
    for j in range(k):
        blocks[j, 0] = Wl[j, j]
        blocks[j, 1] = Wl[j, k + j]
        blocks[j, 2] = Wl[k + j, j]
        blocks[j, 3] = Wl[k + j, k + j]
    for a in range(n2):
        orho[a] = rho[perm[a]]
    qi = np.empty(n2)
    for a in range(n2):
        qi[a] = qa[perm[a]]
    tol = 0.1 * res_tol * scale
    p = np.zeros(n2)
    its = 0
    target = res_tol
    rtol = 0.1 * res_tol
    rel = 0.0
    rel_scale = 0.0
    res = np.inf
    newton_used = False
    chk_res = np.nan
    chk_err = np.nan
    for _ in range(4):
        p, n_it, res, used = _newton_run(Wl, qa, mus, rho, op_p, op_i, op_x, blocks, orho, perm, qi, p, tol,
                                         rel_scale, sweeps, newton_iter, max_rounds)
        its += n_it
        newton_used = newton_used or used
        if res > tol:
            break
        if not _finite(p):
            return False, p, its, np.nan, newton_used
        chk_res, rel, chk_err = checks_blocked_dense(Wl, qa, mus, rho, p, SCALE_FLOOR * scale)
        if rel > rtol:
            rel_scale = scale
            continue
        if chk_err <= target:
            break
        tol *= 1e-2
    if not (res <= tol) or not (rel <= rtol):
        return False, p, its, np.nan, newton_used
    # OneStepSolver.solve's test (the same for NewtonSolver and AutoSolver: same residual_tol)
    pmax = 0.0
    for a in range(n2):
        pmax = max(pmax, abs(p[a]))
    sc = max(scale, pmax, 1e-300)
    if not math.isfinite(chk_res) or chk_res > res_tol * sc:
        return False, p, its, chk_res, newton_used
    if not chk_err <= target:
        return False, p, its, chk_res, newton_used
    return True, p, its, chk_res, newton_used


@njit(cache=True)
def _modes(Wl, qa, rho, p, scale, newton_used, md, margin):
    """The modes of the impulses p into md (ContactProblem.modes, rtol 1e-9 of each contact's
    scale, contact_scales); False where Newton iterations were taken and a mode's test quantity
    lies within ``margin`` (MODE_MARGIN, passed by the caller so that a test may change it) of its
    threshold (another LU's rounding must not be able to choose another branch than the Python
    solver's)."""
    k = md.size
    ap = np.abs(p)
    aw = matvec(np.abs(Wl), ap)
    u = matvec(Wl, p)
    for j in range(k):
        sN = max(max(abs(qa[j]) * rho[j], ap[j]), (COUPLING_FLOOR * rho[j]) * aw[j])
        sT = max(max(abs(qa[k + j]) * rho[k + j], ap[k + j]), (COUPLING_FLOOR * rho[k + j]) * aw[k + j])
        tol_p = 1e-9 * max(max(sN, sT), SCALE_FLOOR * scale)
        uT = (u[k + j] + qa[k + j]) * rho[k + j]
        if p[j] <= tol_p:
            md[j] = 0
        elif uT > tol_p:
            md[j] = 2
        elif uT < -tol_p:
            md[j] = 3
        else:
            md[j] = 1
        if newton_used:  # another LU's rounding must not be able to choose another branch
            lim = margin * tol_p
            if abs(p[j] - tol_p) <= lim or abs(abs(uT) - tol_p) <= lim:
                return False
    return True


@njit(cache=True)
def solve_planar(Wl, qa, mus, res_tol, pm):
    """The solve of one planar contact problem (Wl, qa, mus) of two or more contacts as
    :func:`planar_multi_step` solves it (``pm`` as there: AutoSolver's NSGS sweeps from zero, then
    semismooth Newton; no warm start), for the constant compiled loop's steps whose sweeps did not
    converge: (ok, p, iterations, residual); ok False where the solve or its test failed, or a mode
    lies within MODE_MARGIN of its threshold after Newton iterations."""
    n2 = qa.size
    rho = np.empty(n2)
    for a in range(n2):
        d = Wl[a, a]
        rho[a] = 1.0 / d if d > 0 else 1.0
    scale = 0.0
    for a in range(n2):
        scale = max(scale, abs(qa[a]) * rho[a])
    scale = max(scale, 1e-300)
    if not math.isfinite(scale):
        return False, np.zeros(n2), 0, np.nan
    ok, p, its, res, newton_used = _solve(Wl, qa, mus, rho, scale, res_tol, pm[1], pm[2], pm[3])
    if not ok:
        return False, p, its, res
    md = np.empty(mus.size, dtype=np.int64)
    return _modes(Wl, qa, rho, p, scale, newton_used, md, MODE_MARGIN), p, its, res


@njit(cache=True)
def planar_multi_step(act, na, m, n, r, o_W, o_H, o_SHt, o_b1, moving, v, vfree, dvf, uNm, mu, e, res_tol, pm,
                      istate, fstate, dv, P, MDo):
    """The contact solve of a step whose active contacts ``act[:na]`` (two or more; or one under
    ``"nsgs"``, whose Python solver runs the same sweeps) are planar, under ``"auto"`` (module
    docstring); ``pm`` = (largest count, NSGS sweeps, Newton iterations,
    rounds) of the solver (no Newton iterations and one round of its ``max_sweeps``: ``"nsgs"``).
    Fills dv (the step's velocity increment), P (the impulses, normals then tangents) and MDo (the
    modes); False where the Python side must solve the step."""
    k = na
    n2 = 2 * k
    idx = np.empty(n2, dtype=np.int64)
    for i in range(k):
        idx[i] = act[i]
        idx[k + i] = m + act[i]
    Ha = rows(o_H, r, n, idx)
    SHta = cols_f(o_SHt, n, idx)  # NumPy's S H'[:, idx]: its products by BLAS's gemv
    Wl = np.empty((n2, n2))
    for a in range(n2):
        for b in range(n2):
            Wl[a, b] = o_W[idx[a] + idx[b] * r]
    qa = matvec(Ha, vfree)
    if moving:
        for a in range(n2):
            qa[a] = qa[a] + o_b1[idx[a]]
    has_e = False
    for i in range(k):
        has_e = has_e or e[act[i]] != 0.0
    shift = np.zeros(k)
    if has_e:
        for i in range(k):
            shift[i] = e[act[i]] * min(uNm[act[i]], 0.0)
            qa[i] += shift[i]
    mus = np.empty(k)
    for i in range(k):
        mus[i] = mu[act[i]]
    rho = np.empty(n2)
    for a in range(n2):
        d = Wl[a, a]
        rho[a] = 1.0 / d if d > 0 else 1.0
    scale = 0.0
    for a in range(n2):
        scale = max(scale, abs(qa[a]) * rho[a])
    scale = max(scale, 1e-300)
    if not math.isfinite(scale):
        return False
    ok, p, its, res, newton_used = _solve(Wl, qa, mus, rho, scale, res_tol, pm[1], pm[2], pm[3])
    if not ok:
        return False
    md = np.empty(k, dtype=np.int64)
    if not _modes(Wl, qa, rho, p, scale, newton_used, md, MODE_MARGIN):
        return False
    sp = np.dot(SHta, p)
    w = np.empty(n)
    for a in range(n):
        dv[a] = dvf[a] + sp[a]
    for a in range(n):
        w[a] = v[a] + dv[a]
    # the branch refinement: r = H (v + dv) cancelled on the branch of the modes (solve_branch)
    rl = matvec(Ha, w)
    if moving:
        for a in range(n2):
            rl[a] = rl[a] + o_b1[idx[a]]
    if has_e:
        for i in range(k):
            rl[i] += shift[i]
    E = np.zeros((n2, n2))
    rhs = np.zeros(n2)
    for j in range(k):
        if md[j] == 0:
            E[j, j] = 1.0
            E[k + j, k + j] = 1.0
            continue
        for c in range(n2):
            E[j, c] = Wl[j, c]
        rhs[j] = -rl[j]
        if md[j] == 1:
            for c in range(n2):
                E[k + j, c] = Wl[k + j, c]
            rhs[k + j] = -rl[k + j]
        else:
            E[k + j, k + j] = 1.0
            E[k + j, j] = mus[j] if md[j] == 2 else -mus[j]
    refined = True
    try:
        dp = np.linalg.solve(E, rhs)
    except Exception:  # singular: the Python loop keeps the unrefined impulses
        refined = False
        dp = rhs
    if refined and _finite(dp):
        tot = 0.0
        for a in range(n2):
            tot += dp[a]
        # the refined impulse in every cone (contact_step.in_cones: the same test)
        big = 0.0
        for a in range(n2):
            big = max(big, abs(p[a] + dp[a]))
        tol = CONE_RTOL * big
        inside = True
        for j in range(k):
            pn = p[j] + dp[j]
            if pn < -tol or abs(p[k + j] + dp[k + j]) > mus[j] * pn + tol:
                inside = False
        if math.isfinite(tot) and inside:
            for a in range(n2):
                p[a] = p[a] + dp[a]
            sp = np.dot(SHta, dp)
            for a in range(n):
                dv[a] = dv[a] + sp[a]
    store_solve(istate, fstate, its, res, p, n2, md, k, P, MDo)
    return True
