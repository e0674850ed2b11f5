"""The numba kernels of the compiled Moreau-Jean loop: the steps themselves, no Python per step.

Holds :func:`run_steps` (steps k0 .. k_end - 1 of a constant planar system on the arrays packed by
:mod:`lcp.timestepping.compiled_loop`) and the compiled pieces it calls, and the reasons it returns
for (DONE, NEEDS_PYTHON, NONFINITE, BUFFER_FULL). Imports NumPy, numba (:mod:`lcp.numerics.jit`)
and the per-contact kernels of :mod:`lcp.contact`; never the set-up, the Python solvers, the result
or anything above :mod:`lcp.timestepping`. Each step, as the Python loop computes it:

- free velocity: constant, or affine in (q, v) through S (dense) or the factors of W_h (sparse
  assembly), exactly as :class:`lcp.timestepping.assembly.StepAssembly` computes it;
- the activation rule with its tolerances and hysteresis (:mod:`lcp.timestepping.activation`), the
  same sums in the same order as the Python loop;
- the contact problem of the active contacts by nonsmooth Gauss-Seidel with the exact local planar
  solves of :mod:`lcp.contact.nsgs` on the whole operator W (contact-by-contact CSR; the inactive contacts
  hold zero impulse, so the sweep sees exactly the active set's problem), warm-started from the
  previous step's impulses, accepted at the same natural-map residual as the Python solvers
  (0.1 ``residual_tol`` times the problem's impulse scale, and times each contact's own scale,
  :meth:`lcp.contact.problem.ContactProblem.stop_measure`); ``"auto"`` with a single active
  contact takes the closed form (open, stick, slide+, slide-) with its ambiguity count;
- the modes and the branch refinement of the Python loop: the local velocity of the actual
  post-step velocity, r = H (v + dv), is cancelled on the branch of the modes. Where the loop
  solves the branch's linear system directly, this path solves it by Gauss-Seidel sweeps over the
  contacts (each an exact 2 x 2 or sliding-line solve, :func:`lcp.contact.problem.planar_refine`'s
  formulas) until a sweep changes the correction by less than 1e-8 of itself: the correction is of
  the order of the solver's tolerance, so this lands on the branch solution to rounding, as the
  direct solve does; where the sweeps do not converge (a stack of blocks couples each contact to
  its neighbours as strongly as to itself) and at most ``BRANCH_DIRECT_MAX`` contacts are active,
  the branch system is solved directly by elimination;
- restitution shift, Kahan-compensated sums of v and q, impacts, every ``save_every``-th state
  with its impulses and modes.

Where a step cannot be finished here (NSGS does not reach the tolerance within its sweeps, the
closed form finds no admissible case, or the branch sweeps do not converge) the kernel returns
NEEDS_PYTHON with that step's active set and local free velocity.
"""
from __future__ import annotations

import math

import numpy as np

from lcp.timestepping.activation import LIST_MAX_CONTACTS
from lcp.contact.law import SCALE_FLOOR
from lcp.contact.kernels import contact_residual, contact_scale, local_planar, row_absdot, row_dot
from lcp.numerics.jit import njit
from lcp.timestepping.contact_step import CONE_RTOL
from lcp.timestepping.control_kernels import constant_control_dv, dense_mv

__all__ = ["BRANCH_MAX_SWEEPS", "BRANCH_DIRECT_MAX", "DONE", "NEEDS_PYTHON", "NONFINITE", "BUFFER_FULL",
           "activate", "all_closing", "enum_one", "free_velocity", "run_steps"]

#: Gauss-Seidel sweeps of the branch refinement before the step goes to the exact Python solve
BRANCH_MAX_SWEEPS = 60
#: largest number of active contacts whose branch system is solved directly where the sweeps
#: do not converge (a dense elimination, (2 k)^3 / 3 flops); above it the step goes to Python
BRANCH_DIRECT_MAX = 48

#: reasons for which :func:`run_steps` returns: all steps done, one step for the Python solver,
#: a non-finite state, the impacts' buffer full
DONE, NEEDS_PYTHON, NONFINITE, BUFFER_FULL = 0, 1, 2, 3


@njit(cache=True)
def _csr_matvec(p, i, x, v, out):
    for r in range(p.size - 1):
        s = 0.0
        for a in range(p[r], p[r + 1]):
            s += x[a] * v[i[a]]
        out[r] = s


@njit(cache=True)
def _lu_solve(Lp, Li, Lx, Ld, Up, Ui, Ux, Ud, perm_r, perm_c, b, work, out):
    n = b.size
    for a in range(n):
        work[perm_r[a]] = b[a]
    for c in range(n):  # L: lower, by columns
        zc = work[c] / Ld[c]
        work[c] = zc
        for a in range(Lp[c], Lp[c + 1]):
            work[Li[a]] -= Lx[a] * zc
    for c in range(n - 1, -1, -1):  # U: upper, by columns
        zc = work[c] / Ud[c]
        work[c] = zc
        for a in range(Up[c], Up[c + 1]):
            work[Ui[a]] -= Ux[a] * zc
    for a in range(n):
        out[a] = work[perm_c[a]]


@njit(cache=True, inline="always")
def _free_dv(mode, fv, h, th, q, v, dvf, rhs, t1, t2):
    """dv_free of StepAssembly.at for a constant system, into ``dvf``."""
    (dv_const, F0, Kp, Ki, Kx, Cp, Ci, Cx, hKp, hKi, hKx, Sp, Si, Sx,
     Lp, Li, Lx, Ld, Up, Ui, Ux, Ud, perm_r, perm_c, Tp, Ti, Tx, Gp, Gi, Gx, phi_t) = fv
    n = q.size
    if mode == 0:
        for a in range(n):
            dvf[a] = dv_const[a]
        return
    # Fth = F0 + Kq q + Cv v; rhs = h Fth + (h^2 theta Kq) v
    _csr_matvec(Kp, Ki, Kx, q, t1)
    for a in range(n):
        rhs[a] = F0[a] + t1[a]
    _csr_matvec(Cp, Ci, Cx, v, t1)
    for a in range(n):
        rhs[a] = h * (rhs[a] + t1[a])
    _csr_matvec(hKp, hKi, hKx, v, t1)
    for a in range(n):
        rhs[a] = rhs[a] + t1[a]
    if mode == 1:
        _csr_matvec(Sp, Si, Sx, rhs, dvf)
    else:
        _lu_solve(Lp, Li, Lx, Ld, Up, Ui, Ux, Ud, perm_r, perm_c, rhs, t1, dvf)
    nb = phi_t.size
    if nb:  # bilateral constraints: dv += T (-phi_t - G v)
        c = np.empty(nb)
        _csr_matvec(Gp, Gi, Gx, v, c)
        for a in range(nb):
            c[a] = -phi_t[a] - c[a]
        _csr_matvec(Tp, Ti, Tx, c, t1)
        for a in range(n):
            dvf[a] = dvf[a] + t1[a]


#: the free velocity of a constant system (the spatial loop, lcp.timestepping.compiled_spatial, shares it)
free_velocity = _free_dv


@njit(cache=True)
def _sparse_control(mode, fv, B, u, t1, t2, dvf):
    """dvf += S (B u) for the control's impulse u over the step where S is sparse (its CSR arrays:
    SciPy's product sums each row in order; or the factors of W_h, to rounding)."""
    (dv_const, F0, Kp, Ki, Kx, Cp, Ci, Cx, hKp, hKi, hKx, Sp, Si, Sx,
     Lp, Li, Lx, Ld, Up, Ui, Ux, Ud, perm_r, perm_c, Tp, Ti, Tx, Gp, Gi, Gx, phi_t) = fv
    c = dense_mv(B, u)
    if mode == 1:
        _csr_matvec(Sp, Si, Sx, c, t2)
    else:
        _lu_solve(Lp, Li, Lx, Ld, Up, Ui, Ux, Ud, perm_r, perm_c, c, t1, t2)
    for a in range(dvf.size):
        dvf[a] = dvf[a] + t2[a]


@njit(cache=True, inline="always")
def all_closing(m, gap, uNm, uNf, a_c, b_c):
    """Whether every contact's predicted gap (gap + a_c u_N-) + b_c u_Nf is <= 0, decided as the
    Python rule decides it (:class:`lcp.timestepping.activation.Activation`), NaN included: up to
    :data:`~lcp.timestepping.activation.LIST_MAX_CONTACTS` contacts by Python's max over the list (a later entry replaces the
    largest only where it compares greater, so a NaN counts only in the first place), beyond by
    NumPy's max (a NaN anywhere wins). A state that overflowed then takes the Python loop's path:
    no contact closes, and the step ends non-finite."""
    top = 0.0
    nan = False
    for j in range(m):
        pred = (gap[j] + a_c * uNm[j]) + b_c * uNf[j]
        if j == 0 or pred > top:
            top = pred
        if pred != pred:
            nan = True
    if m > LIST_MAX_CONTACTS and nan:
        return False
    return top <= 0.0


@njit(cache=True, inline="always")
def _activate(m, n, Hp, Hi, Hx, aHp, aHi, aHx, gap0, absg0, q, v, vfree, loaded, a_c, b_c, close_tol, open_tol,
              uNm, uNf, gap, absq, act):
    """The activation rule of :class:`lcp.timestepping.activation.Activation` on constant contact
    rows (CSR H and |H|): the same sums in the same order. Fills uNm, uNf, gap and the active
    indices ``act``; returns their number (the compiled many-contact and spatial loops share it)."""
    for j in range(m):
        uNm[j] = row_dot(Hp, Hi, Hx, v, j)
        uNf[j] = row_dot(Hp, Hi, Hx, vfree, j)
        gap[j] = gap0[j] + row_dot(Hp, Hi, Hx, q, j)
    na = 0
    if all_closing(m, gap, uNm, uNf, a_c, b_c):
        for j in range(m):
            act[na] = j
            na += 1
        return na
    any_loaded = False
    for j in range(m):
        any_loaded = any_loaded or loaded[j]
    for a in range(n):
        absq[a] = abs(q[a])
    for j in range(m):
        aa = a_c * uNm[j]
        bb = b_c * uNf[j]
        pred = (gap[j] + aa) + bb
        size = row_dot(aHp, aHi, aHx, absq, j) + absg0[j]
        size = ((size + abs(gap[j])) + abs(aa)) + abs(bb)
        closing = pred <= close_tol * size
        if any_loaded and loaded[j] and gap[j] + aa <= open_tol * size:
            closing = True
        if closing:
            act[na] = j
            na += 1
    return na


#: the activation rule on constant rows (the spatial loop, lcp.timestepping.compiled_spatial, shares it)
activate = _activate


@njit(cache=True)
def _enum1(W00, W01, W10, W11, qN, qT, mu):
    """lcp.contact.problem.planar_enum on floats (rtol 1e-12): (pN, pT, mode, n_distinct); no case
    where a diagonal entry of W is not positive (a degenerate contact row, as EnumSolver)."""
    if not (W00 > 0.0 and W11 > 0.0):
        return np.nan, np.nan, -1, 0
    scale = max(max(abs(qN) / W00, abs(qT) / W11), 1e-300)
    tol = 1e-12 * scale
    open_ok = (qN / W00) >= -tol
    det = W00 * W11 - W01 * W10
    det_ok = det > 0
    dets = det if det_ok else 1.0
    pN_st = (-qN * W11 + qT * W01) / dets
    pT_st = (-qT * W00 + qN * W10) / dets
    st_ok = det_ok and (pN_st >= -tol) and (abs(pT_st) <= mu * pN_st + tol)
    a_p = W00 - mu * W01
    ok_p = a_p > 0
    pN_p = -qN / (a_p if ok_p else 1.0)
    uT_p = (W10 - mu * W11) * pN_p + qT
    sp_ok = ok_p and (pN_p >= -tol) and ((uT_p / W11) > -tol)
    a_m = W00 + mu * W01
    ok_m = a_m > 0
    pN_m = -qN / (a_m if ok_m else 1.0)
    uT_m = (W10 + mu * W11) * pN_m + qT
    sm_ok = ok_m and (pN_m >= -tol) and ((uT_m / W11) < tol)
    if open_ok:
        pN, pT, mode = 0.0, 0.0, 0
    elif st_ok:
        pN, pT, mode = pN_st, pT_st, 1
    elif sp_ok:
        pN, pT, mode = pN_p, -mu * pN_p, 2
    elif sm_ok:
        pN, pT, mode = pN_m, mu * pN_m, 3
    else:
        return np.nan, np.nan, -1, 0
    far = 1e-9 * scale
    nd = 1
    if open_ok and (abs(0.0 - pN) + abs(0.0 - pT)) > far:
        nd += 1
    if st_ok and (abs(pN_st - pN) + abs(pT_st - pT)) > far:
        nd += 1
    if sp_ok and (abs(pN_p - pN) + abs(-mu * pN_p - pT)) > far:
        nd += 1
    if sm_ok and (abs(pN_m - pN) + abs(mu * pN_m - pT)) > far:
        nd += 1
    return pN, pT, mode, nd


#: the one-contact planar closed form (the general loop, lcp.timestepping.general_kernels, shares it)
enum_one = _enum1


@njit(cache=True)
def _branch_direct(act, na, md, mu, Wp, Wi, Wx, rloc, dpi):
    """The branch refinement's linear system solved directly (Gaussian elimination with partial
    pivoting on the dense system of the closed contacts' unknowns), where Gauss-Seidel sweeps
    converge too slowly (a stack of blocks: every contact coupled to its neighbours as strongly
    as to itself). The same equations as the sweeps: a stuck contact cancels its local velocity,
    a sliding one its normal velocity with p_T = -+mu p_N. Returns False if the system is singular."""
    m2 = dpi.size
    col = np.full(m2, -1, dtype=np.int64)  # unknown of each interleaved row (-1: none)
    sgn = np.zeros(m2)  # factor of the normal unknown in the tangent entry of a sliding contact
    nu = 0
    for t in range(na):
        j = act[t]
        mo = md[t]
        if mo == 0:
            continue
        col[2 * j] = nu
        nu += 1
        if mo == 1:
            col[2 * j + 1] = nu
            nu += 1
        else:
            sgn[2 * j] = -mu[j] if mo == 2 else mu[j]
    if nu == 0:
        return True
    A = np.zeros((nu, nu))
    b = np.zeros(nu)
    for t in range(na):
        j = act[t]
        mo = md[t]
        if mo == 0:
            continue
        for comp in range(2 if mo == 1 else 1):
            row = 2 * j + comp
            eq = col[row]
            b[eq] = -rloc[row]
            for p in range(Wp[row], Wp[row + 1]):
                c = Wi[p]
                i = c // 2
                base = col[2 * i]
                if base < 0:
                    continue
                if c % 2 == 0:
                    A[eq, base] += Wx[p]
                elif col[2 * i + 1] >= 0:
                    A[eq, col[2 * i + 1]] += Wx[p]
                else:  # sliding: p_T = sgn p_N
                    A[eq, base] += Wx[p] * sgn[2 * i]
    for k in range(nu):
        piv = k
        big = abs(A[k, k])
        for r in range(k + 1, nu):
            if abs(A[r, k]) > big:
                big = abs(A[r, k])
                piv = r
        if big == 0.0:
            return False
        if piv != k:
            for c in range(nu):
                A[k, c], A[piv, c] = A[piv, c], A[k, c]
            b[k], b[piv] = b[piv], b[k]
        for r in range(k + 1, nu):
            f = A[r, k] / A[k, k]
            if f != 0.0:
                for c in range(k, nu):
                    A[r, c] -= f * A[k, c]
                b[r] -= f * b[k]
    for k in range(nu - 1, -1, -1):
        x = b[k]
        for c in range(k + 1, nu):
            x -= A[k, c] * b[c]
        b[k] = x / A[k, k]
    for t in range(na):
        j = act[t]
        mo = md[t]
        if mo == 0:
            continue
        dpi[2 * j] = b[col[2 * j]]
        dpi[2 * j + 1] = b[col[2 * j + 1]] if mo == 1 else sgn[2 * j] * b[col[2 * j]]
    for t in range(na):
        j = act[t]
        if not (math.isfinite(dpi[2 * j]) and math.isfinite(dpi[2 * j + 1])):
            return False
    return True


@njit(cache=True)
def _shtp(Cp, Ci, Cx, act, na, m, r, out):
    """out = (S H') p for the impulses r (contact-by-contact) of the active contacts."""
    out[:] = 0.0
    for t in range(na):
        j = act[t]
        pN = r[2 * j]
        pT = r[2 * j + 1]
        if pN != 0.0:
            for a in range(Cp[j], Cp[j + 1]):
                out[Ci[a]] += Cx[a] * pN
        if pT != 0.0:
            for a in range(Cp[m + j], Cp[m + j + 1]):
                out[Ci[a]] += Cx[a] * pT


@njit(cache=True)
def _relative_residual(act, na, qi, r, Wp, Wi, Wx, mu, rho, floor):
    """max over the active contacts of the natural-map residual relative to the contact's own scale
    (:func:`lcp.contact.nsgs.contact_scale`; ContactProblem.relative_residual)."""
    rel = 0.0
    for t in range(na):
        j = act[t]
        iN = 2 * j
        iT = iN + 1
        uN = qi[iN] + row_dot(Wp, Wi, Wx, r, iN)
        uT = qi[iT] + row_dot(Wp, Wi, Wx, r, iT)
        c = contact_residual(r[iN], r[iT], uN, uT, mu[j], rho[iN], rho[iT])
        if c > 0.0:
            rel = max(rel, c / contact_scale(r[iN], r[iT], qi[iN], qi[iT], rho[iN], rho[iT],
                                              row_absdot(Wp, Wi, Wx, r, iN), row_absdot(Wp, Wi, Wx, r, iT), floor))
    return rel


@njit(cache=True)
def run_steps(k0, k_end, every, mode, fv, ct, h, th, close_tol, open_tol, res_tol, max_sweeps, use_enum, blockdiag,
         q, v, cq, cv, loaded, r, istate, fstate, Q, V, PN, PT, MD, imp_t, imp_j, imp_p,
         act, qa, forced, fp, fmd, cB=None, imp=None):
    """Steps k0 .. k_end - 1 (see the module docstring); returns (step, reason).

    ``istate`` = [all_loaded, free_steps, solver_calls, iterations, max_iterations, open, stick,
    slide+, slide-, ambiguous, first ambiguous step, impacts, sweeps of the last failure];
    ``fstate`` = [max residual, residual of the last failure]. When the reason is not DONE the
    state (q, v, sums, loaded) is that at the start of the returned step; for NEEDS_PYTHON,
    ``act[:na]`` and ``qa[:2 na]`` (blocked: normals then tangents, restitution shift included)
    hold its active set and free local velocity, ``na = istate[13]``. With ``forced``, step k0
    takes the impulses ``fp`` (blocked over all contacts) and modes ``fmd`` instead of solving.
    ``cB`` (B, S, Kq, Cv, h^2 theta Kq, T, G, F0, phi_t of the assembly, dense; S empty where sparse)
    and ``imp`` (per step the impulse of a scheduled control, (steps, nu)):
    S B imp[k] is added to the free velocity increment (None: no control).
    """
    (Hp, Hi, Hx, aHp, aHi, aHx, absg0, gap0, Cp, Ci, Cx, Wp, Wi, Wx, blocks, rho, mu, e) = ct
    dv_const = fv[0]
    n = q.size
    m = mu.size
    dvf = np.empty(n)
    vfree = np.empty(n)
    rhs = np.empty(n)
    t1 = np.empty(n)
    t2 = np.empty(n)
    dv = np.empty(n)
    w = np.empty(n)
    vn = np.empty(n)
    qn = np.empty(n)
    cqn = np.empty(n)
    cvn = np.empty(n)
    absq = np.empty(n)
    uNm = np.empty(m)
    uNf = np.empty(m)
    gap = np.empty(m)
    qi = np.zeros(2 * m)
    dpi = np.zeros(2 * m)
    rloc = np.zeros(2 * m)
    md = np.empty(m, dtype=np.int8)
    uTs = np.empty(m)
    cap = imp_t.size
    a_c = h * (1 - th)
    b_c = h * th
    for k in range(k0, k_end):
        if istate[11] + m > cap:
            return k, BUFFER_FULL
        tk = k * h
        if mode == 0:  # constant: copied here (a call that takes fv costs more than the copy)
            for a in range(n):
                dvf[a] = dv_const[a]
        elif imp is not None and cB[1].size:  # a control schedule, dense S: the Python loop's products
            constant_control_dv(cB, imp[k], h, q, v, t1, dvf)
        else:
            _free_dv(mode, fv, h, th, q, v, dvf, rhs, t1, t2)
            if imp is not None:  # a control schedule, sparse S: + S B int u
                _sparse_control(mode, fv, cB[0], imp[k], t1, t2, dvf)
        for a in range(n):
            vfree[a] = v[a] + dvf[a]
        # activation (lcp.timestepping.activation.Activation): the same sums in the same order
        na = _activate(m, n, Hp, Hi, Hx, aHp, aHi, aHx, gap0, absg0, q, v, vfree, loaded, a_c, b_c, close_tol,
                      open_tol, uNm, uNf, gap, absq, act)
        row = (k + 1) // every - 1 if (k + 1) % every == 0 else -1
        # inactive contacts hold zero impulse (the sweeps then see the active set's problem)
        t = 0
        for j in range(m):
            if t < na and act[t] == j:
                t += 1
            else:
                r[2 * j] = 0.0
                r[2 * j + 1] = 0.0
        if na == 0:
            for a in range(n):
                dv[a] = dvf[a]
            istate[1] += 1
            for j in range(m):
                loaded[j] = False
            istate[0] = 0
        else:
            has_e = False
            for t in range(na):
                if e[act[t]] != 0.0:
                    has_e = True
            scale = 0.0
            cmin = np.inf  # the smallest contact scale of the free velocities
            for t in range(na):
                j = act[t]
                qN = uNf[j]  # H_N v_free, computed by the activation
                if has_e:
                    qN += e[j] * min(uNm[j], 0.0)
                qT = row_dot(Hp, Hi, Hx, vfree, m + j)
                qi[2 * j] = qN
                qi[2 * j + 1] = qT
                cj = max(abs(qN) * rho[2 * j], abs(qT) * rho[2 * j + 1])
                scale = max(scale, cj)
                cmin = min(cmin, cj)
            scale = max(scale, 1e-300)
            gfloor = SCALE_FLOOR * scale
            cmin = max(cmin, gfloor)
            tol = 0.1 * res_tol * scale
            rtol = 0.1 * res_tol
            its = 0
            res = 0.0
            rel_ok = False
            ok = True
            if forced and k == k0:
                for t in range(na):
                    j = act[t]
                    r[2 * j] = fp[j]
                    r[2 * j + 1] = fp[m + j]
                    md[t] = fmd[j]
            elif use_enum and na == 1:
                j = act[0]
                pN, pT, mo, nd = _enum1(blocks[j, 0], blocks[j, 1], blocks[j, 2], blocks[j, 3],
                                        qi[2 * j], qi[2 * j + 1], mu[j])
                its = 4
                if mo < 0:
                    ok = False
                else:
                    r[2 * j] = pN
                    r[2 * j + 1] = pT
                    uN = blocks[j, 0] * pN + blocks[j, 1] * pT + qi[2 * j]
                    uT = blocks[j, 2] * pN + blocks[j, 3] * pT + qi[2 * j + 1]
                    res = contact_residual(pN, pT, uN, uT, mu[j], rho[2 * j], rho[2 * j + 1])
                    if not (res <= res_tol * max(scale, abs(pN), abs(pT))):
                        ok = False
                    if ok and nd > 1:
                        if istate[9] == 0:
                            istate[10] = k
                        istate[9] += 1
            else:
                res = np.inf
                change = np.inf
                for sweep in range(1, max_sweeps + 1):
                    its = sweep
                    change = 0.0
                    for t in range(na):
                        j = act[t]
                        iN = 2 * j
                        iT = iN + 1
                        W00, W01, W10, W11 = blocks[j, 0], blocks[j, 1], blocks[j, 2], blocks[j, 3]
                        rN, rT = r[iN], r[iT]
                        if blockdiag:  # no other contact enters: the local problem is the contact's own
                            qN = qi[iN]
                            qT = qi[iT]
                        else:
                            qN = qi[iN] + row_dot(Wp, Wi, Wx, r, iN) - W00 * rN - W01 * rT
                            qT = qi[iT] + row_dot(Wp, Wi, Wx, r, iT) - W10 * rN - W11 * rT
                        if W00 <= 0.0:
                            continue
                        pN, pT, mo = local_planar(W00, W01, W10, W11, qN, qT, mu[j])
                        if mo < 0:  # no closed-form case: one projected natural-map step
                            uN = W00 * rN + W01 * rT + qN
                            uT = W10 * rN + W11 * rT + qT
                            pN = max(rN - rho[iN] * uN, 0.0)
                            s = mu[j] * pN
                            pT = min(max(rT - rho[iT] * uT, -s), s)
                        change = max(change, abs(pN - rN), abs(pT - rT))
                        r[iN] = pN
                        r[iT] = pT
                    if change <= tol or blockdiag:
                        res = 0.0
                        for t in range(na):
                            j = act[t]
                            if blockdiag:  # the row's two entries, in CSR's column order
                                uN = qi[2 * j] + (blocks[j, 0] * r[2 * j] + blocks[j, 1] * r[2 * j + 1])
                                uT = blocks[j, 2] * r[2 * j] + blocks[j, 3] * r[2 * j + 1]
                            else:
                                uN = qi[2 * j] + row_dot(Wp, Wi, Wx, r, 2 * j)
                                uT = row_dot(Wp, Wi, Wx, r, 2 * j + 1)
                            uTs[t] = uT
                            uT = qi[2 * j + 1] + uT
                            res = max(res, contact_residual(r[2 * j], r[2 * j + 1], uN, uT, mu[j],
                                                             rho[2 * j], rho[2 * j + 1]))
                        # and contact by contact, on each contact's own scale (lcp.contact.nsgs.contact_scale);
                        # below rtol times the smallest scale of the free velocities it holds already
                        if res <= tol and (res <= rtol * cmin or _relative_residual(act, na, qi, r, Wp, Wi, Wx, mu, rho, gfloor)
                                           <= rtol):
                            rel_ok = True
                            break
                if not rel_ok and change > tol and not blockdiag:
                    # the sweeps ran out: the residual of the last one decides (as lcp.contact.nsgs.nsgs_sweeps)
                    res = 0.0
                    for t in range(na):
                        j = act[t]
                        uN = qi[2 * j] + row_dot(Wp, Wi, Wx, r, 2 * j)
                        uT = row_dot(Wp, Wi, Wx, r, 2 * j + 1)
                        uTs[t] = uT
                        uT = qi[2 * j + 1] + uT
                        res = max(res, contact_residual(r[2 * j], r[2 * j + 1], uN, uT, mu[j],
                                                         rho[2 * j], rho[2 * j + 1]))
                    rel_ok = res <= tol and (res <= rtol * cmin
                                             or _relative_residual(act, na, qi, r, Wp, Wi, Wx, mu, rho, gfloor) <= rtol)
                if not rel_ok:
                    ok = False
            if ok and not (forced and k == k0):
                # modes of the solution (ContactProblem.modes, rtol 1e-9 of each contact's scale);
                # W_T r from the residual's pass
                for t in range(na):
                    j = act[t]
                    if blockdiag:
                        aN = abs(blocks[j, 0] * r[2 * j]) + abs(blocks[j, 1] * r[2 * j + 1])
                        aT = abs(blocks[j, 2] * r[2 * j]) + abs(blocks[j, 3] * r[2 * j + 1])
                    else:
                        aN = row_absdot(Wp, Wi, Wx, r, 2 * j)
                        aT = row_absdot(Wp, Wi, Wx, r, 2 * j + 1)
                    tol_p = 1e-9 * contact_scale(r[2 * j], r[2 * j + 1], qi[2 * j], qi[2 * j + 1], rho[2 * j],
                                                  rho[2 * j + 1], aN, aT, gfloor)
                    if use_enum and na == 1:
                        uTs[t] = row_dot(Wp, Wi, Wx, r, 2 * j + 1)
                    uT = (uTs[t] + qi[2 * j + 1]) * rho[2 * j + 1]
                    if r[2 * j] <= tol_p:
                        md[t] = 0
                    elif uT > tol_p:
                        md[t] = 2
                    elif uT < -tol_p:
                        md[t] = 3
                    else:
                        md[t] = 1
            if ok:
                # dv = dv_free + S H' p, then the branch refinement on r = H (v + dv)
                _shtp(Cp, Ci, Cx, act, na, m, r, t1)
                for a in range(n):
                    dv[a] = dvf[a] + t1[a]
                    w[a] = v[a] + dv[a]
                if not (forced and k == k0):
                    for t in range(na):
                        j = act[t]
                        rN = row_dot(Hp, Hi, Hx, w, j)
                        if has_e:
                            rN += e[j] * min(uNm[j], 0.0)
                        rloc[2 * j] = rN
                        rloc[2 * j + 1] = row_dot(Hp, Hi, Hx, w, m + j)
                        dpi[2 * j] = 0.0
                        dpi[2 * j + 1] = 0.0
                    singular = False
                    converged = False
                    for sweep in range(BRANCH_MAX_SWEEPS):
                        change = 0.0
                        big = 0.0
                        for t in range(na):
                            j = act[t]
                            mo = md[t]
                            if mo == 0:
                                continue
                            iN = 2 * j
                            iT = iN + 1
                            W00, W01, W10, W11 = blocks[j, 0], blocks[j, 1], blocks[j, 2], blocks[j, 3]
                            xN, xT = dpi[iN], dpi[iT]
                            if blockdiag:
                                cN = rloc[iN]
                                cT = rloc[iT]
                            else:
                                cN = rloc[iN] + row_dot(Wp, Wi, Wx, dpi, iN) - W00 * xN - W01 * xT
                                cT = rloc[iT] + row_dot(Wp, Wi, Wx, dpi, iT) - W10 * xN - W11 * xT
                            if mo == 1:
                                det = W00 * W11 - W01 * W10
                                if det == 0.0:
                                    singular = True
                                    break
                                yN = (-cN * W11 + cT * W01) / det
                                yT = (-cT * W00 + cN * W10) / det
                            else:
                                sg = 1.0 if mo == 2 else -1.0
                                aa = W00 - sg * mu[j] * W01
                                if aa == 0.0:
                                    singular = True
                                    break
                                yN = -cN / aa
                                yT = -sg * mu[j] * yN
                            change = max(change, abs(yN - xN), abs(yT - xT))
                            big = max(big, abs(yN), abs(yT))
                            dpi[iN] = yN
                            dpi[iT] = yT
                        if singular:
                            break
                        if change <= 1e-8 * big or big == 0.0 or blockdiag:
                            converged = True
                            break
                    if singular:  # the loop keeps the unrefined impulses where the branch is singular
                        for t in range(na):
                            j = act[t]
                            dpi[2 * j] = 0.0
                            dpi[2 * j + 1] = 0.0
                    elif not converged and na <= BRANCH_DIRECT_MAX and _branch_direct(act, na, md, mu, Wp, Wi, Wx,
                                                                                 rloc, dpi):
                        converged = True
                    if not singular and not converged:
                        ok = False
                        its = -its - 1  # marks the branch sweeps as the cause
                    else:
                        finite = True
                        for t in range(na):
                            j = act[t]
                            finite = finite and math.isfinite(dpi[2 * j]) and math.isfinite(dpi[2 * j + 1])
                        # the refined impulse in every cone (contact_step.in_cones, the same test): on
                        # the singular branch of redundant contacts the refinement may move their split out
                        if finite:
                            big = 0.0
                            for t in range(na):
                                j = act[t]
                                big = max(big, abs(r[2 * j] + dpi[2 * j]), abs(r[2 * j + 1] + dpi[2 * j + 1]))
                            tol = CONE_RTOL * big
                            for t in range(na):
                                j = act[t]
                                pn = r[2 * j] + dpi[2 * j]
                                if pn < -tol or abs(r[2 * j + 1] + dpi[2 * j + 1]) > mu[j] * pn + tol:
                                    finite = False
                        if finite:
                            _shtp(Cp, Ci, Cx, act, na, m, dpi, t1)
                            for t in range(na):
                                j = act[t]
                                r[2 * j] = r[2 * j] + dpi[2 * j]
                                r[2 * j + 1] = r[2 * j + 1] + dpi[2 * j + 1]
                            for a in range(n):
                                dv[a] = dv[a] + t1[a]
            if not ok:
                istate[12] = its
                istate[13] = na
                fstate[1] = res
                for t in range(na):
                    j = act[t]
                    qa[t] = qi[2 * j]
                    qa[na + t] = qi[2 * j + 1]
                return k, NEEDS_PYTHON
            if not (forced and k == k0):
                istate[3] += its
                istate[4] = max(istate[4], its)
                fstate[0] = max(fstate[0], res)
            istate[2] += 1
            # impacts (lcp.timestepping.outcome.record_impacts), before the loads are updated
            if istate[0] == 0:
                for t in range(na):
                    j = act[t]
                    pN = r[2 * j]
                    um = uNm[j]
                    if pN > 0 and not loaded[j] and um < 0 and -um > abs(uNf[j] - um):
                        c = istate[11]
                        imp_t[c] = tk + min(h, max(0.0, gap[j] / -um))
                        imp_j[c] = j
                        imp_p[c, 0] = pN
                        imp_p[c, 1] = r[2 * j + 1]
                        istate[11] = c + 1
            if na < m:
                for j in range(m):
                    loaded[j] = False
            all_now = na == m
            for t in range(na):
                j = act[t]
                loaded[j] = r[2 * j] > 0
                all_now = all_now and loaded[j]
            istate[0] = 1 if all_now else 0
            if row >= 0:
                for t in range(na):
                    j = act[t]
                    PN[row, j] = r[2 * j]
                    PT[row, j] = r[2 * j + 1]
                    MD[row, j] = md[t]
            for t in range(na):
                istate[5 + md[t]] += 1
        # compensated (Kahan) sums, as lcp.timestepping.assembly.kahan_add
        finite = True
        for a in range(n):
            y = dv[a] - cv[a]
            s = v[a] + y
            cvn[a] = (s - v[a]) - y
            vn[a] = s
        for a in range(n):
            y = h * ((1 - th) * v[a] + th * vn[a]) - cq[a]
            s = q[a] + y
            cqn[a] = (s - q[a]) - y
            qn[a] = s
            finite = finite and math.isfinite(s) and math.isfinite(vn[a])
        if not finite:
            return k, NONFINITE
        for a in range(n):
            q[a] = qn[a]
            v[a] = vn[a]
            cq[a] = cqn[a]
            cv[a] = cvn[a]
        if row >= 0:
            for a in range(n):
                Q[row + 1, a] = q[a]
                V[row + 1, a] = v[a]
    return k_end, DONE
