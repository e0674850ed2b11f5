"""Moreau-Jean for constant planar systems with several contacts: all steps in one compiled call.

The Python loop (:func:`lcp.timestepping.moreau_jean`) pays 10-30 microseconds of interpreter work
per step (NumPy calls on small arrays, the solver's bookkeeping), which dominates the cost of a
step with few contacts or easy contact problems. For a constant system (constant mass matrix and
kinematics, affine time-independent forces) every operator of the step is a fixed matrix, and the
whole loop runs here as one numba function:

- free velocity: constant, or affine in (q, v) through S (dense) or the factors of W_h (sparse
  assembly), exactly as :class:`lcp.timestepping.assembly.StepAssembly` computes it;
- the activation rule with its tolerances and hysteresis (CLOSE_ULPS, OPEN_ULPS), the same sums
  in the same order as the Python loop;
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

Where the compiled step cannot finish (NSGS does not reach the tolerance within its sweeps, the
closed form finds no admissible case, or the branch sweeps do not converge), that one step is
handed to the Python solver (with the loop's fallbacks: the same one-step problem, solver object
and exact branch refinement) and the compiled loop resumes after it. Every such step is counted
in ``stats.fallbacks`` and named in the message: no step is silently wrong.

Results equal the Python loop's to rounding (the sums run in another order than BLAS's).
Without numba (:data:`lcp.numerics.jit.HAVE_NUMBA` False) the Python loop runs instead.
"""
from __future__ import annotations

import math
import weakref

import numpy as np

from lcp.contact.problem import MODE_NAMES, ContactProblem, ModeArray
from lcp.contact.law import SCALE_FLOOR
from lcp.numerics.jit import HAVE_NUMBA, njit
from lcp.contact.kernels import contact_residual, contact_scale, local_planar, row_absdot, row_dot
from lcp.timestepping.projection import violation_function
from lcp.result import STATUS_MESSAGES, Impact, SimulationResult, SolverStats

__all__ = ["AUTO_MAX_SWEEPS", "BRANCH_MAX_SWEEPS", "applicable", "moreau_jean_loop"]

#: NSGS sweeps of ``"auto"`` in the compiled step before the step goes to the Python solver
#: (NSGS then semismooth Newton), which handles slowly converging problems better
AUTO_MAX_SWEEPS = 500
#: Gauss-Seidel sweeps of the branch refinement before the step goes to the exact Python solve
BRANCH_MAX_SWEEPS = 60
#: largest number of active contacts whose branch system is solved directly where the sweeps
#: do not converge (a dense elimination, (2 k)^3 / 3 flops); above it the step goes to Python
BRANCH_DIRECT_MAX = 48
_EPS = float(np.finfo(float).eps)

# reasons for which the kernel returns before the last step
_DONE, _NEEDS_PYTHON, _NONFINITE, _BUFFER_FULL = 0, 1, 2, 3


def applicable(asm, solver, options) -> bool:
    """Whether the compiled loop runs this simulation: numba installed; a constant planar system
    (affine time-independent forces, no control schedule) with at least two contacts; the solver
    ``"auto"`` or ``"nsgs"`` (as a name or as a plain instance) without an ``error_tol``."""
    from lcp.contact.solvers import AutoSolver, NsgsSolver

    sys_ = asm.sys
    if not (HAVE_NUMBA and sys_.n_contacts >= 2 and not sys_.is_spatial and sys_.is_constant
            and asm.matrices_constant and asm.schedule is None):
        return False
    if type(solver) is AutoSolver:
        return solver.iterative.error_tol is None
    if type(solver) is NsgsSolver:
        return solver.error_tol is None and solver.compiled
    return False


def _csr(A):
    """(indptr, indices, data) of A in CSR (exact zeros dropped: they add nothing to a sum)."""
    if not hasattr(A, "tocsr"):  # dense: NumPy alone (SciPy's constructors cost more on small matrices)
        A = np.asarray(A, dtype=float)
        rows, cols = np.nonzero(A)
        indptr = np.zeros(A.shape[0] + 1, dtype=np.int64)
        np.cumsum(np.bincount(rows, minlength=A.shape[0]), out=indptr[1:])
        return indptr, cols.astype(np.int64), A[rows, cols]
    return _compressed(A.tocsr())


def _csc(A):
    """(indptr, indices, data) of A in CSC."""
    if not hasattr(A, "tocsc"):
        return _csr(np.asarray(A, dtype=float).T)
    return _compressed(A.tocsc())


def _compressed(M):
    """The compressed arrays (pointers, indices, values; int64, float) of a CSR or CSC matrix, copied,
    exact zeros dropped and indices sorted."""
    if not (M.has_sorted_indices and M.data.dtype == np.float64):
        import scipy.sparse as sp

        # a plain copy built from the arrays (M may be a subclass whose copy() fails), sorted
        cls = sp.csr_matrix if M.format == "csr" else sp.csc_matrix
        M = cls((np.array(M.data, dtype=float), M.indices.copy(), M.indptr.copy()), shape=M.shape)
        M.sort_indices()
    # sorted (what every assembly here builds): the arrays themselves, without SciPy's
    # constructors (the largest part of this conversion's cost otherwise)
    ptr, idx, val = M.indptr, M.indices, M.data
    keep = val != 0.0
    pointers = np.zeros(ptr.size, dtype=np.int64)
    if keep.all():
        np.copyto(pointers, ptr)
        return pointers, idx.astype(np.int64), val.copy()
    major = np.repeat(np.arange(ptr.size - 1), np.diff(ptr))
    np.cumsum(np.bincount(major[keep], minlength=ptr.size - 1), out=pointers[1:])
    return pointers, idx[keep].astype(np.int64), val[keep]


def _empty_csr(rows):
    return np.zeros(rows + 1, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros(0)


def _lu_parts(lu, n):
    """The SuperLU factors as strictly triangular CSC parts, diagonals and permutations:
    Pr A Pc = L U, so A x = b is z[perm_r] = b, L U y = z, x = y[perm_c]."""
    import scipy.sparse as sp

    out = []
    for F in (lu.L, lu.U):
        F = sp.csc_matrix(F)
        d = F.diagonal().astype(float)
        off = (F - sp.diags(d)).tocsc()
        out.append((_csc(off), d))
    (Lp, Li, Lx), Ld = out[0]
    (Up, Ui, Ux), Ud = out[1]
    return (Lp, Li, Lx, Ld, Up, Ui, Ux, Ud, lu.perm_r.astype(np.int64), lu.perm_c.astype(np.int64))


def _interleaved(W, m):
    """W (blocked: normals, then tangents; dense or sparse) in contact-by-contact CSR, its diagonal
    2 x 2 blocks and the natural-map weights rho = 1/W_ii (as :class:`lcp.contact.nsgs.InterleavedOperator`)."""
    return _interleave_compiled(*_csr(W), m)


@njit(cache=True)
def _interleave_compiled(Wp, Wi, Wx, m):
    """:func:`_interleaved` of W given by its CSR arrays, in one compiled pass: blocked row or column
    r becomes 2 r (normal) or 2 (r - m) + 1 (tangent), exact zeros dropped, columns sorted."""
    rows = 2 * m
    ptr = np.zeros(rows + 1, dtype=np.int64)
    for r in range(rows):
        t = 2 * r if r < m else 2 * (r - m) + 1
        for a in range(Wp[r], Wp[r + 1]):
            if Wx[a] != 0.0:
                ptr[t + 1] += 1
    for t in range(rows):
        ptr[t + 1] += ptr[t]
    idx = np.empty(ptr[rows], dtype=np.int64)
    val = np.empty(ptr[rows])
    fill = ptr[:rows].copy()
    blocks = np.zeros((m, 4))
    for r in range(rows):
        t = 2 * r if r < m else 2 * (r - m) + 1
        for a in range(Wp[r], Wp[r + 1]):
            if Wx[a] != 0.0:
                c = Wi[a]
                u = 2 * c if c < m else 2 * (c - m) + 1
                idx[fill[t]] = u
                val[fill[t]] = Wx[a]
                fill[t] += 1
                if t // 2 == u // 2:  # the contact's own 2 x 2 block: [NN, NT, TN, TT]
                    blocks[t // 2, 2 * (t % 2) + u % 2] = Wx[a]
    for t in range(rows):  # insertion sort of each row by column
        for s in range(ptr[t] + 1, ptr[t + 1]):
            c = idx[s]
            x = val[s]
            b = s - 1
            while b >= ptr[t] and idx[b] > c:
                idx[b + 1] = idx[b]
                val[b + 1] = val[b]
                b -= 1
            idx[b + 1] = c
            val[b + 1] = x
    rho = np.empty(rows)
    for j in range(m):
        for k in range(2):
            d = blocks[j, 3 * k]
            rho[2 * j + k] = 1.0 / d if d > 0 else 1.0
    return ptr, idx, val, blocks, rho


_PACKS = weakref.WeakKeyDictionary()  # system -> {(h, theta): packed data}: repeated runs pay nothing


def _pack(asm):
    """The kernel's constant data: (free-velocity mode, fv tuple, contact tuple), once per
    (system, h, theta)."""
    key = (float(asm.h), float(asm.theta))
    per_system = _PACKS.setdefault(asm.sys, {})
    if key not in per_system:
        if len(per_system) > 8:
            per_system.clear()
        per_system[key] = _pack_new(asm)
    return per_system[key]


def _pack_new(asm):
    n, m, h, th = asm.n, asm.m, float(asm.h), float(asm.theta)
    z = np.zeros(0)
    e0 = _empty_csr(0)
    lu0 = (*e0, z, *e0, z, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    if asm.dv_const is not None:
        mode = 0
        fv = (np.asarray(asm.dv_const, dtype=float).ravel(), z, *e0, *e0, *e0, *e0, *lu0, *e0, *e0, z)
    else:
        Kq, Cv = asm.Kq, asm.Cv
        hK = asm._hhK if asm.sparse else ((h * h) * th) * Kq
        if asm.sparse and asm._lu is not None:
            mode, S, lu = 2, e0, _lu_parts(asm._lu, n)
        else:
            mode, S, lu = 1, _csr(asm.S), lu0
        nb = asm.T.shape[1]
        Tc = _csr(asm.T) if nb else _empty_csr(n)
        Gc = _csr(asm.G) if nb else e0
        fv = (z, np.asarray(asm.F0, dtype=float).ravel(), *_csr(Kq), *_csr(Cv), *_csr(hK), *S, *lu, *Tc, *Gc,
              np.asarray(asm.phi_t, dtype=float).ravel() if nb else z)
    arrays = getattr(asm, "arrays", None)  # independent bodies: the compressed arrays, no SciPy matrix
    if arrays is not None:
        (Hp, Hi, Hx), SHtc, Wc = arrays["H"], arrays["SHt_csc"], arrays["W"]
    else:
        (Hp, Hi, Hx), SHtc, Wc = _csr(asm.H), _csc(asm.SHt), _csr(asm.W)
    Wp, Wi, Wx, blocks, rho = _interleave_compiled(*Wc, m)
    end = Hp[m]  # |H_N|: the leading m rows of H's CSR arrays
    gap0 = np.asarray(asm.gap0, dtype=float).ravel()
    sysm = asm.sys
    ct = (Hp, Hi, Hx, Hp[:m + 1].copy(), Hi[:end].copy(), np.abs(Hx[:end]), np.abs(gap0), gap0, *SHtc,
          Wp, Wi, Wx, blocks, rho, np.asarray(sysm.mu, dtype=float), np.asarray(sysm.e, dtype=float))
    # no operator entry couples two contacts: one sweep solves every local problem exactly
    blockdiag = bool(np.all(Wi // 2 == np.repeat(np.arange(Wp.size - 1) // 2, np.diff(Wp))))
    return mode, fv, ct, blockdiag


# ----------------------------------------------------------------------------- compiled pieces
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


@njit(cache=True)
def _enum1(W00, W01, W10, W11, qN, qT, mu):
    """lcp.contact.problem.planar_enum on floats (rtol 1e-12): (pN, pT, mode, n_distinct)."""
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
def _run(k0, k_end, every, mode, fv, ct, h, th, close_tol, open_tol, res_tol, max_sweeps, use_enum, blockdiag,
         q, v, cq, cv, loaded, r, istate, fstate, Q, V, PN, PT, MD, imp_t, imp_j, imp_p,
         act, qa, forced, fp, fmd):
    """Steps k0 .. k_end - 1 (see the module docstring); returns (step, reason).

    ``istate`` = [all_loaded, free_steps, solver_calls, iterations, max_iterations, open, stick,
    slide+, slide-, ambiguous, first ambiguous step, impacts, sweeps of the last failure];
    ``fstate`` = [max residual, residual of the last failure]. When the reason is not _DONE the
    state (q, v, sums, loaded) is that at the start of the returned step; for _NEEDS_PYTHON,
    ``act[:na]`` and ``qa[:2 na]`` (blocked: normals then tangents, restitution shift included)
    hold its active set and free local velocity, ``na = istate[13]``. With ``forced``, step k0
    takes the impulses ``fp`` (blocked over all contacts) and modes ``fmd`` instead of solving.
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
            return k, _BUFFER_FULL
        tk = k * h
        if mode == 0:  # constant: copied here (a call that takes fv costs more than the copy)
            for a in range(n):
                dvf[a] = dv_const[a]
        else:
            _free_dv(mode, fv, h, th, q, v, dvf, rhs, t1, t2)
        for a in range(n):
            vfree[a] = v[a] + dvf[a]
        # activation (lcp.timestepping.moreau_jean._Activation): the same sums in the same order
        any_open = False
        for j in range(m):
            uNm[j] = row_dot(Hp, Hi, Hx, v, j)
            uNf[j] = row_dot(Hp, Hi, Hx, vfree, j)
            gap[j] = gap0[j] + row_dot(Hp, Hi, Hx, q, j)
            if (gap[j] + a_c * uNm[j]) + b_c * uNf[j] > 0.0:
                any_open = True
        na = 0
        if not any_open:
            for j in range(m):
                act[na] = j
                na += 1
        else:
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
                return k, _NEEDS_PYTHON
            if not (forced and k == k0):
                istate[3] += its
                istate[4] = max(istate[4], its)
                fstate[0] = max(fstate[0], res)
            istate[2] += 1
            # impacts (lcp.timestepping.moreau_jean._record_impacts), before the loads are updated
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
            return k, _NONFINITE
        for a in range(n):
            q[a] = qn[a]
            v[a] = vn[a]
            cq[a] = cqn[a]
            cv[a] = cvn[a]
        if row >= 0:
            for a in range(n):
                Q[row + 1, a] = q[a]
                V[row + 1, a] = v[a]
    return k_end, _DONE


# ----------------------------------------------------------------------------- the Python side
class _PythonStep:
    """One step solved by the Python solver (with the loop's fallback and exact branch refinement)."""

    def __init__(self, asm, solver, fallback, fallback_for):
        self.asm, self.solver, self.fallback, self.fallback_for = asm, solver, fallback, fallback_for
        self.cache, self.fallbacks = {}, {}

    def solve(self, k, q, v, active, qa, stats):
        """(p, modes, sol, fallback name or None) of step k; p is None when every solver failed."""
        asm, solver = self.asm, self.solver
        m, h = asm.m, asm.h
        dvf, SHt, W, _, H = asm.at(k * h, q, v)
        key = active.tobytes()
        local = self.cache.get(key)
        if local is None:
            idx = np.concatenate([active, m + active])
            template = ContactProblem(W[np.ix_(idx, idx)], np.zeros(idx.size), asm.sys.mu[active], key=tuple(active))
            local = self.cache[key] = (idx, H[idx], SHt[:, idx], template)
        idx, Ha, SHta, template = local
        pb = template.with_q(qa)
        sol = solver.solve(pb)
        stats.iterations += sol.iterations
        stats.max_iterations = max(stats.max_iterations, sol.iterations)
        stats.qp_solves += sol.qp_solves
        used = None
        if not sol.success and self.fallback and sol.status != -3:
            fb = self.fallbacks.setdefault(active.size, self.fallback_for(solver, active.size))
            if fb is not None:
                sol2 = fb.solve(pb)
                if sol2.success:
                    used, sol = fb.name, sol2
        if not sol.success:
            return None, None, sol, None
        if sol.message.startswith("fallback"):
            used = used or "lemke"
        stats.ambiguous_steps += int(sol.ambiguous)
        stats.max_residual = max(stats.max_residual, sol.residual)
        p = sol.p
        md = pb.modes(p)
        dv = dvf + SHta @ p
        r = Ha @ (v + dv)
        e = asm.sys.e[active]
        if np.any(e):
            r[: active.size] += e * np.minimum(H[:m][active] @ v, 0.0)
        dp = pb.with_q(r).solve_branch(md)
        if dp is not None and math.isfinite(float(dp.sum())):
            p = p + dp
        return p, md, sol, used


def moreau_jean_loop(asm, q0, v0, n_steps: int, every: int, solver, fallback: bool, ulps, fallback_for,
                     ambiguity_note, compiled: bool = True) -> SimulationResult:
    """Moreau-Jean on a constant planar system by the compiled loop (module docstring).

    Parameters
    ----------
    asm : lcp.timestepping.assembly.StepAssembly
        The step's constant data (``applicable(asm, solver, options)`` must hold).
    q0, v0 : ndarray
        Checked initial state.
    n_steps, every : int
        Number of steps, and the saving period (``save_every``).
    solver : OneStepSolver
        ``"auto"`` or ``"nsgs"``; the Python solver of the steps the compiled step cannot finish.
    fallback : bool
        MoreauJeanOptions.fallback: retry a failed Python step with the other exact solver.
    ulps : (float, float)
        CLOSE_ULPS and OPEN_ULPS of the activation rule.
    fallback_for, ambiguity_note : callable
        The loop's choice of fallback solver and its sentence on ambiguous steps.
    compiled : bool
        False runs the kernel as plain Python (numba's ``py_func``; slow, for tests).

    Examples
    --------
    >>> import lcp
    >>> res = lcp.simulate(lcp.scenes.block_chain(4), 0.1, h=1e-3)
    >>> res.solver, res.status
    ('auto (compiled)', 0)
    """
    sys_ = asm.sys
    n, m, h, th = asm.n, asm.m, float(asm.h), float(asm.theta)
    n_saved = n_steps // every
    if n_saved > 50_000_000:
        raise ValueError(f"{n_saved} saved states would not fit in memory: raise save_every")
    mode, fv, ct, blockdiag = _pack(asm)
    kernel = _run if compiled else getattr(_run, "py_func", _run)
    from lcp.contact.solvers import AutoSolver

    use_enum = type(solver) is AutoSolver
    max_sweeps = AUTO_MAX_SWEEPS if use_enum else int(solver.max_sweeps)
    res_tol = float(solver.residual_tol)
    Q = np.empty((n_saved + 1, n))
    V = np.empty((n_saved + 1, n))
    PN = np.zeros((n_saved, m))
    PT = np.zeros((n_saved, m))
    MD = np.full((n_saved, m), -1, dtype=np.int8)
    Q[0], V[0] = q0, v0
    q, v = np.array(q0, dtype=float), np.array(v0, dtype=float)
    cq, cv = np.zeros(n), np.zeros(n)
    loaded = np.zeros(m, dtype=np.bool_)
    r = np.zeros(2 * m)
    istate = np.zeros(14, dtype=np.int64)
    fstate = np.zeros(2)
    cap = max(64, 4 * m)
    imp_t, imp_j, imp_p = np.empty(cap), np.empty(cap, dtype=np.int64), np.empty((cap, 2))
    act, qa = np.empty(m, dtype=np.int64), np.empty(2 * m)
    fp, fmd = np.zeros(2 * m), np.full(m, -1, dtype=np.int8)
    close_tol, open_tol = ulps[0] * _EPS, ulps[1] * _EPS
    stats = SolverStats()
    status, message = 0, STATUS_MESSAGES[0]
    py = _PythonStep(asm, solver, fallback, fallback_for)
    handed, first_hand, n_fb, first_fb = 0, None, 0, None
    k, forced = 0, False
    while True:
        k, reason = kernel(k, n_steps, every, mode, fv, ct, h, th, close_tol, open_tol, res_tol, max_sweeps,
                           use_enum, blockdiag, q, v, cq, cv, loaded, r, istate, fstate, Q, V, PN, PT, MD, imp_t, imp_j, imp_p,
                           act, qa, forced, fp, fmd)
        forced = False
        if reason == _DONE:
            break
        if reason == _BUFFER_FULL:
            c = imp_t.size
            imp_t = np.concatenate([imp_t, np.empty(c)])
            imp_j = np.concatenate([imp_j, np.empty(c, dtype=np.int64)])
            imp_p = np.concatenate([imp_p, np.empty((c, 2))])
            continue
        if reason == _NONFINITE:
            status, message = -2, f"{STATUS_MESSAGES[-2]} Step {k} (t = {k * h:.10g})."
            break
        # the compiled step could not finish: the Python solver takes this step
        na = int(istate[13])
        active = act[:na].copy()
        its = int(istate[12])
        why = (f"branch refinement sweeps did not converge after {BRANCH_MAX_SWEEPS} sweeps" if its < 0 else
               f"compiled NSGS stopped after {its} sweeps (residual {fstate[1]:.3g})" if not (use_enum and na == 1)
               else "closed form: no admissible case")
        p, md, sol, used = py.solve(k, q, v, active, qa[:2 * na].copy(), stats)
        if p is None:
            status = -1
            message = f"{STATUS_MESSAGES[-1]} Step {k} (t = {k * h:.10g}), solver '{solver.name}': {sol.message}"
            break
        handed += 1
        first_hand = first_hand or (k, why)
        if used is not None:
            n_fb += 1
            first_fb = first_fb or (k, sol.message if used == "lemke" else why, used)
        fp[:] = 0.0
        fp[active], fp[m + active] = p[:na], p[na:]
        fmd[active] = md
        forced = True
    # ------------------------------------------------------------------ the result
    done = k
    stats.steps = done
    stats.free_steps = int(istate[1])
    stats.solver_calls = int(istate[2])
    stats.iterations += int(istate[3])
    stats.max_iterations = max(stats.max_iterations, int(istate[4]))
    stats.max_residual = max(stats.max_residual, float(fstate[0]))
    stats.ambiguous_steps += int(istate[9])
    for code in range(4):
        stats.mode_counts[MODE_NAMES[code]] += int(istate[5 + code])
    stats.fallbacks = handed
    if handed:
        k1, why = first_hand
        message += (f" {handed} step(s) were solved by the Python solver '{solver.name}' instead of the compiled "
                    f"loop, the first at step {k1} (t = {k1 * h:.10g}) after: {why}.")
    if n_fb:
        k1, why, name = first_fb
        message += (f" {n_fb} of them by the fallback solver '{name}', the first at step {k1} "
                    f"(t = {k1 * h:.10g}) after: {why}")
    if status == 0:
        first = (int(istate[10]), int(istate[10]) * h) if istate[9] else None
        message += ambiguity_note(stats.ambiguous_steps, first)
    last = done // every
    t = every * h * np.arange(last + 1)
    Qc = Q[:last + 1]
    names = [c.name for c in sys_.contacts]
    impacts = [Impact(float(imp_t[i]), int(imp_j[i]), names[int(imp_j[i])], float(imp_p[i, 0]), float(imp_p[i, 1]))
               for i in range(int(istate[11]))]
    return SimulationResult(t=t, q=Qc, v=V[:last + 1], p_N=PN[:last], p_T=PT[:last], modes=ModeArray.of(MD[:last]),
                            status=status, message=message, stats=stats, method="moreau-jean",
                            solver=f"{solver.name} (compiled)", h=h, theta=th, impacts=impacts,
                            violation=lambda: violation_function(sys_)(Qc, t))
