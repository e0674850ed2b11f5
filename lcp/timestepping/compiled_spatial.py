"""Moreau-Jean for constant systems of independent spatial contacts: all steps in one compiled call.

The spatial twin of :mod:`lcp.timestepping.compiled_loop`, for the case where the Delassus
operator W is block-diagonal by contact (no operator entry couples two contacts: pucks, boxes or
independent bodies each on its own floor) and every contact has a two-dimensional tangent (the
Coulomb disk). The contact problem of a step then splits into one 3 x 3 problem per active
contact, solved exactly by :func:`lcp.contact.kernels.local_disk3` (open, stick, or slide with
its direction): no Gauss-Seidel sweep is needed, and what NSGS, the local solver or Newton would
return in the Python loop is this solution to rounding. Each step, as the Python loop
(:mod:`lcp.timestepping.python_loop` with :class:`~lcp.timestepping.contact_step.ContactStep`)
computes it:

- the free velocity (constant, or affine in (q, v): :func:`lcp.timestepping.compiled_kernels.free_velocity`);
- the activation rule of :mod:`lcp.timestepping.activation`, the same sums in the same order;
- the restitution shift of approaching contacts, the exact local solves (warm direction: the
  contact's previous tangential impulse), accepted at the solvers' residual tolerance;
- the branch refinement of :meth:`ConeContactProblem.refine_modes
  <lcp.contact.disk_branches.DiskBranches.refine_modes>` (Newton on the equations of the
  contact's mode, at most three steps, kept while they lower the branch equations without raising
  the Coulomb residual; modes at 1e-9 of the problem's impulse scale), contact by contact;
- where every active contact sticks, the correction of the contact step on the velocities
  themselves (the local velocity of the post-step velocity cancelled);
- impacts, loads, Kahan-compensated sums, every ``save_every``-th state.

A step the kernel cannot finish (no admissible local case, or a residual above tolerance) is
handed to the Python contact step (:class:`~lcp.timestepping.contact_step.ContactStep`, with its
solver and fallbacks) and the kernel resumes after it; such steps are counted and named in the
message. Coupled spatial contacts (W not block-diagonal) run the Python loop.

Imports the kernels and the packing of :mod:`lcp.timestepping.compiled_loop`, the contact step,
the outcome's notes, :mod:`lcp.contact.kernels` and :mod:`lcp.result`; never the path choice
(:mod:`lcp.timestepping.moreau_jean`), the Python loop or anything above :mod:`lcp.timestepping`.
"""
from __future__ import annotations

import math
import weakref

import numpy as np

from lcp.contact.kernels import disk_residual, local_disk3, row_dot, solve3
from lcp.contact.modes import MODE_NAMES, ModeArray
from lcp.numerics.jit import HAVE_NUMBA, njit
from lcp.result import STATUS_MESSAGES, Impact, SimulationResult
from lcp.timestepping.activation import CLOSE_ULPS, EPS, OPEN_ULPS
from lcp.timestepping.compiled_kernels import (
    BUFFER_FULL,
    DONE,
    NEEDS_PYTHON,
    NONFINITE,
    activate,
    free_velocity,
)
from lcp.timestepping.compiled_loop import free_velocity_data, operator_arrays
from lcp.timestepping.contact_step import ContactStep
from lcp.timestepping.outcome import RunNotes, free_velocity_overflows, nonfinite_message
from lcp.timestepping.projection import violation_function

__all__ = ["applicable", "contact_blocks", "moreau_jean_spatial", "run_spatial_steps"]

#: Newton steps of the branch refinement (as ConeContactProblem.refine_modes)
REFINE_ITERATIONS = 3


def applicable(asm, solver, options) -> bool:
    """Whether this path runs the simulation: numba installed; a constant system (constant
    matrices, no control schedule, no bilateral constraint) whose contacts all have two tangents
    and whose W is block-diagonal by contact; the solver ``"auto"`` or ``"nsgs"`` of the disk law
    (a plain instance) or ``"local"`` for one contact."""
    from lcp.contact.spatial_solvers import ConeAutoSolver, ConeNsgsSolver, LocalSolver

    sys_ = asm.sys
    if not (HAVE_NUMBA and sys_.n_contacts >= 1 and sys_.is_spatial and sys_.is_constant
            and asm.matrices_constant and asm.schedule is None and sys_.n_bilateral == 0
            and sys_.n_tangent == 2 * sys_.n_contacts):  # (one or two tangents each: two each)
        return False
    kind = type(solver)
    if not (kind is ConeAutoSolver or (kind is ConeNsgsSolver and solver.polish)
            or (kind is LocalSolver and solver.polish and sys_.n_contacts == 1)):
        return False
    return _pack(asm) is not None


def contact_blocks(Wp, Wi, Wx, m):
    """Each contact's 3 x 3 block of W (blocked layout: normals 0..m-1, then the tangents
    contact by contact from m) from W's CSR arrays, or None where an entry couples two contacts."""
    blocks, ok = _contact_blocks(Wp, Wi, Wx, m)
    return blocks if ok else None


@njit(cache=True)
def _contact_blocks(Wp, Wi, Wx, m):
    blocks = np.zeros((m, 3, 3))
    for r in range(Wp.size - 1):
        jr = r if r < m else (r - m) // 2
        lr = 0 if r < m else 1 + (r - m) % 2
        for a in range(Wp[r], Wp[r + 1]):
            c = Wi[a]
            if Wx[a] == 0.0:
                continue
            jc = c if c < m else (c - m) // 2
            if jc != jr:
                return blocks, False
            blocks[jr, lr, 0 if c < m else 1 + (c - m) % 2] = Wx[a]
    return blocks, True


@njit(cache=True)
def _weights(blocks):
    """The natural-map weights of ConeContactProblem (1/W_NN, 1/max diag W_TT; 1 where not
    positive) and whether each block is isotropic, diag(w_N, w_T, w_T) (a point mass on its floor:
    the closed form of :func:`_isotropic` applies)."""
    m = blocks.shape[0]
    rhoN = np.ones(m)
    rhoT = np.ones(m)
    iso = np.zeros(m, dtype=np.bool_)
    for j in range(m):
        B = blocks[j]
        dN = B[0, 0]
        dT = max(B[1, 1], B[2, 2])
        if dN > 0:
            rhoN[j] = 1.0 / dN
        if dT > 0:
            rhoT[j] = 1.0 / dT
        off = False
        for a in range(3):
            for b in range(3):
                if a != b and B[a, b] != 0.0:
                    off = True
        iso[j] = not off and B[1, 1] == B[2, 2] and dN > 0 and dT > 0
    return rhoN, rhoT, iso


@njit(cache=True)
def _dense_csr(A):
    """(indptr, indices, data) of a dense matrix in CSR, exact zeros dropped (as compiled_loop's
    conversion, in one compiled pass: NumPy's takes several calls of fixed cost)."""
    rows, cols = A.shape
    ptr = np.zeros(rows + 1, dtype=np.int64)
    for i in range(rows):
        c = 0
        for j in range(cols):
            if A[i, j] != 0.0:
                c += 1
        ptr[i + 1] = ptr[i] + c
    idx = np.empty(ptr[rows], dtype=np.int64)
    val = np.empty(ptr[rows])
    t = 0
    for i in range(rows):
        for j in range(cols):
            if A[i, j] != 0.0:
                idx[t] = j
                val[t] = A[i, j]
                t += 1
    return ptr, idx, val


def _operator_arrays(asm):
    """H (CSR), S H' (CSC) and W (CSR) as compressed arrays; dense operators in one compiled pass each."""
    if getattr(asm, "arrays", None) is None and not asm.sparse:
        dense = [np.ascontiguousarray(x, dtype=float) for x in (asm.H, asm.SHt.T, asm.W)]
        return tuple(_dense_csr(x) for x in dense)
    return operator_arrays(asm)


_PACKS = weakref.WeakKeyDictionary()  # system -> {(h, theta): packed data or None}


def _pack(asm):
    """(free-velocity mode, fv tuple, contact tuple) of a block-diagonal spatial system, or None
    where W couples contacts; once per (system, h, theta)."""
    key = (float(asm.h), float(asm.theta))
    per_system = _PACKS.setdefault(asm.sys, {})
    if key not in per_system:
        if len(per_system) > 8:
            per_system.clear()
        per_system[key] = _pack_new(asm)
    return per_system[key]


def _pack_new(asm):
    m = asm.m
    (Hp, Hi, Hx), SHtc, (Wp, Wi, Wx) = _operator_arrays(asm)
    blocks = contact_blocks(Wp, Wi, Wx, m)
    if blocks is None:
        return None
    mode, fv = free_velocity_data(asm)
    rhoN, rhoT, iso = _weights(blocks)
    end = Hp[m]
    gap0 = np.asarray(asm.gap0, dtype=float).ravel()
    sys_ = asm.sys
    ct = (Hp, Hi, Hx, Hp[:m + 1].copy(), Hi[:end].copy(), np.abs(Hx[:end]), np.abs(gap0), gap0, *SHtc,
          blocks, rhoN, rhoT, np.asarray(sys_.mu, dtype=float), np.asarray(sys_.e, dtype=float), iso)
    return mode, fv, ct


# ----------------------------------------------------------------------------- the kernels
@njit(cache=True)
def _branch(md, B, mu, x0, x1, x2, u0, u1, u2, J):
    """The equations F of the contact's branch ``md`` at x (u = B x + q) and J = dF/dx (3 x 3, into
    J), as :func:`lcp.contact.spatial_nsgs._branch_dense` for one contact; returns F."""
    if md == 0:  # open: p = 0
        for a in range(3):
            for b in range(3):
                J[a, b] = 1.0 if a == b else 0.0
        return x0, x1, x2
    for b in range(3):
        J[0, b] = B[0, b]
    if md == 1:  # stick: u = 0
        for b in range(3):
            J[1, b] = B[1, b]
            J[2, b] = B[2, b]
        return u0, u1, u2
    nu = math.hypot(u1, u2)  # slide: p_T + mu p_N u_T / |u_T| = 0
    if not nu > 0.0:
        nu = 1.0
    n0 = u1 / nu
    n1 = u2 / nu
    c = mu * x0 / nu
    g00 = c * (1.0 - n0 * n0)
    g01 = c * (0.0 - n0 * n1)
    g11 = c * (1.0 - n1 * n1)
    for b in range(3):
        J[1, b] = g00 * B[1, b] + g01 * B[2, b]
        J[2, b] = g01 * B[1, b] + g11 * B[2, b]
    J[1, 1] += 1.0
    J[2, 2] += 1.0
    J[1, 0] += mu * n0
    J[2, 0] += mu * n1
    return u0, x1 + mu * x0 * n0, x2 + mu * x0 * n1


@njit(cache=True)
def _mode(x0, u1, u2, rhoT, tol):
    """The contact's mode (modes_blocked): open, stick or slide at ``tol``."""
    if x0 <= tol:
        return 0
    if math.hypot(u1 * rhoT, u2 * rhoT) > tol:
        return 4
    return 1


@njit(cache=True)
def _isotropic(wN, wT, rhoN, rhoT, qN, qT0, qT1, mu):
    """The exact solution of one contact with W_jj = diag(wN, wT, wT) (a point mass on its floor):
    open where q_N >= 0 (to local_disk3's tolerance), stick where the impulse cancelling q lies in
    the disk, else slide with p_N = -q_N / w_N and p_T = -mu p_N q_T / |q_T| (u_T stays parallel to
    q_T). Returns (p_N, p_T0, p_T1, mode)."""
    nq = math.hypot(qT0, qT1)
    tol = 1e-13 * max(abs(qN) * rhoN, nq * rhoT, 1e-300)
    if qN * rhoN >= -tol:
        return 0.0, 0.0, 0.0, 0
    pN = -qN / wN
    if nq / wT <= mu * pN + tol:
        return pN, -qT0 / wT, -qT1 / wT, 1
    f = mu * pN / nq
    return pN, -f * qT0, -f * qT1, 4


@njit(cache=True)
def _refine(B, q0, q1, q2, mu, rhoN, rhoT, mtol, r_ok, x0, x1, x2, J):
    """ConeContactProblem.refine_modes on one contact's block: Newton on its branch, each step
    kept while it lowers the branch equations without raising the residual above ``r_ok``.
    Returns (p, mode, residual of p)."""
    u0 = q0 + (B[0, 0] * x0 + B[0, 1] * x1 + B[0, 2] * x2)
    u1 = q1 + (B[1, 0] * x0 + B[1, 1] * x1 + B[1, 2] * x2)
    u2 = q2 + (B[2, 0] * x0 + B[2, 1] * x1 + B[2, 2] * x2)
    md = _mode(x0, u1, u2, rhoT, mtol)
    res = disk_residual(x0, x1, x2, u0, u1, u2, mu, rhoN, rhoT)
    F0, F1, F2 = _branch(md, B, mu, x0, x1, x2, u0, u1, u2, J)
    f_best = max(abs(F0), abs(F1), abs(F2))
    b0, b1, b2 = x0, x1, x2
    y0, y1, y2 = x0, x1, x2
    changed = False
    for _ in range(REFINE_ITERATIONS):
        if f_best == 0.0:
            break
        d0, d1, d2, ok = solve3(J, -F0, -F1, -F2)
        if not ok:
            break
        y0, y1, y2 = y0 + d0, y1 + d1, y2 + d2
        v0 = q0 + (B[0, 0] * y0 + B[0, 1] * y1 + B[0, 2] * y2)
        v1 = q1 + (B[1, 0] * y0 + B[1, 1] * y1 + B[1, 2] * y2)
        v2 = q2 + (B[2, 0] * y0 + B[2, 1] * y1 + B[2, 2] * y2)
        F0, F1, F2 = _branch(md, B, mu, y0, y1, y2, v0, v1, v2, J)
        fx = max(abs(F0), abs(F1), abs(F2))
        if not fx < f_best:
            break
        ry = disk_residual(y0, y1, y2, v0, v1, v2, mu, rhoN, rhoT)
        if ry <= r_ok:
            b0, b1, b2, f_best, res = y0, y1, y2, fx, ry
            u1, u2 = v1, v2
            changed = True
    if changed:
        md = _mode(b0, u1, u2, rhoT, mtol)
    return b0, b1, b2, md, res


@njit(cache=True)
def _add_shtp(Cp, Ci, Cx, j, m, p0, p1, p2, out):
    """out += (S H') p of contact j's impulse (p_N, p_T0, p_T1): its three columns of S H' (CSC)."""
    _add_column(Cp, Ci, Cx, j, p0, out)
    _add_column(Cp, Ci, Cx, m + 2 * j, p1, out)
    _add_column(Cp, Ci, Cx, m + 2 * j + 1, p2, out)


@njit(cache=True, inline="always")
def _add_column(Cp, Ci, Cx, c, pc, out):
    if pc != 0.0:
        for a in range(Cp[c], Cp[c + 1]):
            out[Ci[a]] += Cx[a] * pc


@njit(cache=True)
def run_spatial_steps(k0, k_end, every, mode, fv, ct, h, th, close_tol, open_tol, res_tol,
                      q, v, cq, cv, loaded, pl, istate, fstate, Q, V, PN, PT, MD, imp_t, imp_j, imp_p,
                      act, forced, fp, fmd):
    """Steps k0 .. k_end - 1 (module docstring); returns (step, reason).

    ``istate`` = [all_loaded, free_steps, solver_calls, iterations, max_iterations, open, stick,
    slide+, slide-, slide, impacts, active contacts of a step handed to Python];
    ``fstate`` = [max residual]. ``pl`` (m x 3) holds each contact's last impulse (its warm
    direction). When the reason is not DONE the state is that at the start of the returned step;
    for NEEDS_PYTHON ``act[:istate[11]]`` is its active set. With ``forced``, step k0 takes the
    impulses ``fp`` (m x 3) and modes ``fmd`` instead of solving.
    """
    (Hp, Hi, Hx, aHp, aHi, aHx, absg0, gap0, Cp, Ci, Cx, blocks, rhoN, rhoT, mu, e, iso) = ct
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
    ql = np.empty((m, 3))
    p = np.empty((m, 3))
    md = np.empty(m, dtype=np.int8)
    J = np.empty((3, 3))
    cap = imp_t.size
    a_c = h * (1 - th)
    b_c = h * th
    for k in range(k0, k_end):
        if istate[10] + m > cap:
            return k, BUFFER_FULL
        tk = k * h
        if mode == 0:
            for a in range(n):
                dvf[a] = dv_const[a]
        else:
            free_velocity(mode, fv, h, th, q, v, dvf, rhs, t1, t2)
        for a in range(n):
            vfree[a] = v[a] + dvf[a]
        # activation (lcp.timestepping.activation.Activation): the same sums in the same order
        na = activate(m, n, Hp, Hi, Hx, aHp, aHi, aHx, gap0, absg0, q, v, vfree, loaded, a_c, b_c, close_tol,
                      open_tol, uNm, uNf, gap, absq, act)
        row = (k + 1) // every - 1 if (k + 1) % every == 0 else -1
        for a in range(n):
            dv[a] = dvf[a]
        if na == 0:
            istate[1] += 1
            for j in range(m):
                loaded[j] = False
            istate[0] = 0
        else:
            # the local free velocities (restitution shift on approaching contacts) and the scale
            scale = 0.0
            for t in range(na):
                j = act[t]
                qN = uNf[j]
                if e[j] != 0.0:
                    qN += e[j] * min(uNm[j], 0.0)
                ql[t, 0] = qN
                ql[t, 1] = row_dot(Hp, Hi, Hx, vfree, m + 2 * j)
                ql[t, 2] = row_dot(Hp, Hi, Hx, vfree, m + 2 * j + 1)
                scale = max(scale, abs(qN) * rhoN[j], abs(ql[t, 1]) * rhoT[j], abs(ql[t, 2]) * rhoT[j])
            scale = max(scale, 1e-300)
            all_stick = False
            if forced and k == k0:
                for t in range(na):
                    j = act[t]
                    p[t, 0], p[t, 1], p[t, 2] = fp[j, 0], fp[j, 1], fp[j, 2]
                    md[t] = fmd[j]
            else:
                ok = True
                pmax = 0.0
                r0 = 0.0
                for t in range(na):
                    j = act[t]
                    B = blocks[j]
                    if iso[j]:
                        pN, pT0, pT1, mo = _isotropic(B[0, 0], B[1, 1], rhoN[j], rhoT[j], ql[t, 0], ql[t, 1],
                                                      ql[t, 2], mu[j])
                    else:
                        pN, pT0, pT1, mo, res = local_disk3(B, ql[t, 0], ql[t, 1], ql[t, 2], mu[j], -pl[j, 1],
                                                            -pl[j, 2])
                    if mo < 0:
                        ok = False
                        break
                    p[t, 0], p[t, 1], p[t, 2] = pN, pT0, pT1
                    pmax = max(pmax, abs(pN), abs(pT0), abs(pT1))
                    # the Coulomb residual of the solution, from u = W p + q (as the solvers' check)
                    u0 = ql[t, 0] + (B[0, 0] * pN + B[0, 1] * pT0 + B[0, 2] * pT1)
                    u1 = ql[t, 1] + (B[1, 0] * pN + B[1, 1] * pT0 + B[1, 2] * pT1)
                    u2 = ql[t, 2] + (B[2, 0] * pN + B[2, 1] * pT0 + B[2, 2] * pT1)
                    r0 = max(r0, disk_residual(pN, pT0, pT1, u0, u1, u2, mu[j], rhoN[j], rhoT[j]))
                if ok and not r0 <= res_tol * max(scale, pmax):
                    ok = False
                if not ok:
                    istate[11] = na
                    return k, NEEDS_PYTHON
                # the branch refinement and the modes (ConeContactProblem.refine_modes)
                mtol = 1e-9 * max(scale, pmax)
                r_ok = max(r0, 1e-15 * max(scale, pmax))
                worst = 0.0
                all_stick = True
                for t in range(na):
                    j = act[t]
                    if iso[j]:  # the closed form is the branch's solution: its modes, no Newton step
                        x0, x1, x2 = p[t, 0], p[t, 1], p[t, 2]
                        B = blocks[j]
                        u0 = ql[t, 0] + B[0, 0] * x0
                        u1 = ql[t, 1] + B[1, 1] * x1
                        u2 = ql[t, 2] + B[2, 2] * x2
                        mo = _mode(x0, u1, u2, rhoT[j], mtol)
                        res = disk_residual(x0, x1, x2, u0, u1, u2, mu[j], rhoN[j], rhoT[j])
                    else:
                        x0, x1, x2, mo, res = _refine(blocks[j], ql[t, 0], ql[t, 1], ql[t, 2], mu[j], rhoN[j],
                                                      rhoT[j], mtol, r_ok, p[t, 0], p[t, 1], p[t, 2], J)
                    p[t, 0], p[t, 1], p[t, 2] = x0, x1, x2
                    md[t] = mo
                    worst = max(worst, res)
                    all_stick = all_stick and mo == 1
                fstate[0] = max(fstate[0], worst)
                istate[3] += 1
                istate[4] = max(istate[4], 1)
            for t in range(na):
                j = act[t]
                _add_shtp(Cp, Ci, Cx, j, m, p[t, 0], p[t, 1], p[t, 2], dv)
            if not (forced and k == k0) and all_stick:
                # every contact stuck: one correction on the velocities themselves (ContactStep.solve)
                for a in range(n):
                    w[a] = v[a] + dv[a]
                for a in range(n):
                    t1[a] = 0.0
                for t in range(na):
                    j = act[t]
                    r0_ = row_dot(Hp, Hi, Hx, w, j)
                    if e[j] != 0.0:
                        r0_ += e[j] * min(uNm[j], 0.0)
                    d0, d1, d2, okd = solve3(blocks[j], -r0_, -row_dot(Hp, Hi, Hx, w, m + 2 * j),
                                             -row_dot(Hp, Hi, Hx, w, m + 2 * j + 1))
                    if okd:
                        p[t, 0] += d0
                        p[t, 1] += d1
                        p[t, 2] += d2
                        _add_shtp(Cp, Ci, Cx, j, m, d0, d1, d2, t1)
                for a in range(n):
                    dv[a] = dv[a] + t1[a]
            if not (forced and k == k0):  # a step handed to Python was counted there
                istate[2] += 1
            # impacts (lcp.timestepping.outcome.record_impacts), before the loads are updated
            if istate[0] == 0:
                for t in range(na):
                    j = act[t]
                    um = uNm[j]
                    if p[t, 0] > 0 and not loaded[j] and um < 0 and -um > abs(uNf[j] - um):
                        c = istate[10]
                        imp_t[c] = tk + min(h, max(0.0, gap[j] / -um))
                        imp_j[c] = j
                        imp_p[c, 0] = p[t, 0]
                        imp_p[c, 1] = p[t, 1]
                        imp_p[c, 2] = p[t, 2]
                        istate[10] = c + 1
            if na < m:
                for j in range(m):
                    loaded[j] = False
            all_now = na == m
            for t in range(na):
                j = act[t]
                loaded[j] = p[t, 0] > 0
                all_now = all_now and loaded[j]
                pl[j, 0], pl[j, 1], pl[j, 2] = p[t, 0], p[t, 1], p[t, 2]
                istate[5 + md[t]] += 1
            istate[0] = 1 if all_now else 0
            if row >= 0:
                for t in range(na):
                    j = act[t]
                    PN[row, j] = p[t, 0]
                    PT[row, 2 * j] = p[t, 1]
                    PT[row, 2 * j + 1] = p[t, 2]
                    MD[row, j] = md[t]
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


# ----------------------------------------------------------------------------- the Python side
def moreau_jean_spatial(asm, q0, v0, n_steps: int, every: int, solver, fallback: bool,
                        compiled: bool = True) -> SimulationResult:
    """Moreau-Jean on a constant system of independent spatial contacts (module docstring).

    Parameters
    ----------
    asm : lcp.timestepping.assembly.StepAssembly
        The step's constant data (``applicable(asm, solver, options)`` must hold).
    q0, v0 : ndarray
        Checked initial state.
    n_steps, every : int
        Number of steps, and the saving period (``save_every``).
    solver : ConeSolver
        The disk-law solver of the steps the kernel hands to Python (with the loop's fallbacks).
    fallback : bool
        MoreauJeanOptions.fallback.
    compiled : bool
        False runs the kernel as plain Python (numba's ``py_func``; slow, for tests).

    Examples
    --------
    >>> import casadi as ca, lcp
    >>> q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    >>> puck = lcp.System(q, v, mass=ca.SX.eye(3), force=ca.vertcat(0, 0, -9.81),
    ...                   contacts=[lcp.Contact(gap=q[2], tangent=ca.vertcat(q[0], q[1]), mu=0.3)])
    >>> res = lcp.simulate(puck, 0.1, h=1e-3, q0=[0, 0, 0], v0=[1.0, 0.5, 0])
    >>> res.solver, res.status
    ('auto (compiled)', 0)
    """
    sys_ = asm.sys
    n, m, h, th = asm.n, asm.m, float(asm.h), float(asm.theta)
    n_saved = n_steps // every
    if n_saved > 50_000_000:
        raise ValueError(f"{n_saved} saved states would not fit in memory: raise save_every")
    mode, fv, ct = _pack(asm)
    kernel = run_spatial_steps if compiled else getattr(run_spatial_steps, "py_func", run_spatial_steps)
    Q = np.empty((n_saved + 1, n))
    V = np.empty((n_saved + 1, n))
    PN = np.zeros((n_saved, m))
    PT = np.zeros((n_saved, 2 * m))
    MD = np.full((n_saved, m), -1, dtype=np.int8)
    Q[0], V[0] = q0, v0
    q, v = np.array(q0, dtype=float), np.array(v0, dtype=float)
    cq, cv = np.zeros(n), np.zeros(n)
    loaded = np.zeros(m, dtype=np.bool_)
    pl = np.zeros((m, 3))
    istate = np.zeros(12, dtype=np.int64)
    fstate = np.zeros(1)
    cap = max(64, 4 * m)
    imp_t, imp_j, imp_p = np.empty(cap), np.empty(cap, dtype=np.int64), np.empty((cap, 3))
    act = np.empty(m, dtype=np.int64)
    fp, fmd = np.zeros((m, 3)), np.full(m, -1, dtype=np.int8)
    close_tol, open_tol = CLOSE_ULPS * EPS, OPEN_ULPS * EPS
    notes = RunNotes()
    stats = notes.stats
    status, message = 0, STATUS_MESSAGES[0]
    step = None
    handed, first_hand = 0, None
    k, forced = 0, False
    while True:
        k, reason = kernel(k, n_steps, every, mode, fv, ct, h, th, close_tol, open_tol, float(solver.residual_tol),
                           q, v, cq, cv, loaded, pl, istate, fstate, Q, V, PN, PT, MD, imp_t, imp_j, imp_p,
                           act, forced, fp, fmd)
        forced = False
        if reason == DONE:
            break
        if reason == BUFFER_FULL:
            c = imp_t.size
            imp_t = np.concatenate([imp_t, np.empty(c)])
            imp_j = np.concatenate([imp_j, np.empty(c, dtype=np.int64)])
            imp_p = np.concatenate([imp_p, np.empty((c, 3))])
            continue
        if reason == NONFINITE:
            status, message = -2, f"{STATUS_MESSAGES[-2]} Step {k} (t = {k * h:.10g})."
            break
        # NEEDS_PYTHON: the Python contact step (solver, fallbacks, refinement) takes this step
        active = act[:int(istate[11])].copy()
        if step is None:
            step = ContactStep(sys_, asm, solver, fallback, notes)
        dvf, SHt, W, _, H = asm.at(k * h, q, v)
        if free_velocity_overflows(v + dvf):  # as the Python loop: no solver for infinities
            status, message = -2, nonfinite_message(k, h)
            break
        _, p, md, _, sol = step.solve(k, k * h, active, v, v + dvf, dvf, SHt, W, H, H[:m] @ v)
        if p is None:
            status = -1
            message = f"{STATUS_MESSAGES[-1]} Step {k} (t = {k * h:.10g}), solver '{solver.name}': {sol.message}"
            break
        handed += 1
        first_hand = first_hand or k
        na = active.size
        fp[:] = 0.0
        fp[active, 0] = p[:na]
        fp[active, 1] = p[na::2]
        fp[active, 2] = p[na + 1::2]
        fmd[active] = md
        forced = True
    done = k
    stats.steps = done
    stats.free_steps = int(istate[1])
    stats.solver_calls += int(istate[2])
    stats.iterations += int(istate[3])
    stats.max_iterations = max(stats.max_iterations, int(istate[4]))
    stats.max_residual = max(stats.max_residual, float(fstate[0]))
    for code in range(5):
        stats.mode_counts[MODE_NAMES[code]] += int(istate[5 + code])
    stats.fallbacks += handed
    message = notes.message(status, message)
    if handed:
        message += (f" {handed} step(s) were solved by the Python solver '{solver.name}' instead of the compiled "
                    f"loop, the first at step {first_hand} (t = {first_hand * h:.10g}).")
    last = done // every
    t = every * h * np.arange(last + 1)
    Qc = Q[:last + 1]
    names = [c.name for c in sys_.contacts]
    impacts = [Impact(float(imp_t[i]), int(imp_j[i]), names[int(imp_j[i])], float(imp_p[i, 0]), imp_p[i, 1:].copy())
               for i in range(int(istate[10]))]
    impacts = sorted(notes.impacts + impacts, key=lambda x: x.t) if notes.impacts else impacts
    return SimulationResult(t=t, q=Qc, v=V[:last + 1], p_N=PN[:last], p_T=PT[:last], modes=ModeArray.of(MD[:last]),
                            status=status, message=message, stats=stats, method="moreau-jean",
                            solver=f"{solver.name} (compiled)", h=h, theta=th, impacts=impacts,
                            violation=lambda: violation_function(sys_)(Qc, t))
