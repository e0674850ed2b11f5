"""The numba kernel of the compiled Moreau-Jean loop for general systems: the steps themselves.

Holds :func:`run_general` (steps k0 .. k_end - 1 of any system whose step data come from the C
function of :mod:`lcp.timestepping.codegen`) and the reasons it returns for. Imports NumPy, numba
(:mod:`lcp.numerics.jit`) and the compiled local solves of :mod:`lcp.contact`; never the set-up,
the Python solvers, the result or anything above :mod:`lcp.timestepping`. Each step, as the
Python loop (:mod:`lcp.timestepping.python_loop`) computes it:

- the step's data from the generated C function, called through its ctypes pointer (the same
  Function the Python loop evaluates in CasADi's virtual machine: the same bits); the free
  velocity increment ``dvf = v_free - v`` and ``v_free = v + dvf`` rounded as the loop rounds them;
- the step acceptance of forces that are not affine (:class:`lcp.timestepping.force_check.ForceStepCheck`:
  the previous step's linearisation against the force at the step's start);
- the activation rule with its tolerances and hysteresis (:mod:`lcp.timestepping.activation`), the
  same sums in the same order, with the moving contacts' rates b;
- one active planar contact under the closed-form solvers (``"auto"``, ``"enum"``): the closed form
  (:func:`lcp.contact.planar_closed_form.planar_enum`), its acceptance test, the modes and the
  branch refinement of :class:`lcp.timestepping.contact_step.ContactStep`;
- one active disk contact under the disk law's ``"auto"`` or ``"local"``: the local solve
  (:func:`lcp.contact.kernels.local_disk3`), the branch refinement and modes
  (:func:`lcp.contact.spatial_nsgs.refine_dense`), the solver's acceptance test and the stuck
  contact's correction of :class:`~lcp.timestepping.contact_step.ContactStep`;
- restitution shift, impacts, the Kahan-compensated sums of v and q, every ``save_every``-th state;
- with Newton-Euler kinematics q' = T(q) v: :func:`lcp.model.kinematics.advance_positions` (T w
  and the quaternions' blocks B from the compiled increment of
  :func:`lcp.timestepping.codegen.kinematics_library`, then NumPy's operations: the compensated
  sum, the exponential map, the normalisation) and the activation's sizes |H_N| 1 max|q| by
  NumPy's pairwise sums.

- two to 40 active disk-law contacts under ``"auto"``: NSGS, its refinement, the acceptance test and
  the all-stick correction (:mod:`lcp.timestepping.multi_kernels`).
- two to 40 active planar contacts under ``"auto"`` on operators that change each step: the
  Python solver's NSGS rounds and semismooth Newton, its tests, the modes and the branch
  refinement (:mod:`lcp.timestepping.planar_multi_kernels`).

Every other contact step (another solver, more contacts, a closed form, NSGS or Newton solve
that fails its test) returns NEEDS_PYTHON with the step's data in the buffers: the Python side
solves it with the loop's own :class:`~lcp.timestepping.contact_step.ContactStep` and calls back
with the velocity increment (``forced``), and the kernel finishes that step and goes on.
"""
from __future__ import annotations

import math

import numpy as np

from lcp.contact.kernels import local_disk3
from lcp.contact.spatial_nsgs import refine_dense, residual_blocked_dense
from lcp.numerics.jit import njit
from lcp.timestepping.compiled_kernels import all_closing, enum_one
from lcp.timestepping.control_kernels import control_vector
from lcp.timestepping.step_products import cols as _cols, matvec as _matvec, rows as _rows, seqmv as _seqmv
from lcp.timestepping.kinematic_kernels import advance, amax_abs, kinematic_sizes
from lcp.timestepping.multi_kernels import cone_multi_step, record_multi
from lcp.timestepping.planar_multi_kernels import planar_multi_step

__all__ = ["DONE", "NEEDS_PYTHON", "NONFINITE", "BAD_DATA", "REJECTED", "BUFFER_FULL", "PROJECTION_FAILED",
           "run_general"]

#: reasons for which :func:`run_general` returns
DONE, NEEDS_PYTHON, NONFINITE, BAD_DATA, REJECTED, BUFFER_FULL, PROJECTION_FAILED = 0, 1, 2, 3, 4, 5, 6

#: the floors of the contact scale (lcp.contact.law.COUPLING_FLOOR, SCALE_FLOOR) and the unit roundoff
_COUPLING_FLOOR = 1e-2
_SCALE_FLOOR = 1e-12
_EPS = 2.220446049250313e-16


@njit(cache=True)
def _error_one(W00, W01, W10, W11, qN, qT, mu, rN, rT):
    """ContactProblem.error of one planar contact (the Siconos-normalised natural-map error)."""
    if not (math.isfinite(rN) and math.isfinite(rT)):
        return np.nan
    uN, uT = W00 * rN + W01 * rT + qN, W10 * rN + W11 * rT + qT
    zN, zT = rN - uN - mu * abs(uT), rT - uT
    aT = abs(zT)
    if aT <= mu * zN and zN >= 0.0:
        pN, pT = zN, zT
    elif mu * aT <= -zN:
        pN = pT = 0.0
    else:
        pN = (zN + mu * aT) / (1.0 + mu * mu)
        pT = math.copysign(mu * pN, zT)
    err = math.hypot(rN - pN, rT - pT)
    scale = max(math.hypot(rN, rT), math.hypot(uN, uT), math.hypot(qN, qT))
    return err / scale if scale > _EPS else err


@njit(cache=True)
def _closed_form_step(j, m, n, r, k, tk, h, o_W, o_H, o_SHt, o_b1, moving, v, vfree, dvf, uNm, mu, e, res_tol,
                      istate, fstate, dv, w, out):
    """One active planar contact j by the closed form, as ContactStep.solve with EnumSolver: fills
    dv and out = (pN, pT, mode); False where the Python side must solve the step (also where a
    diagonal entry of W is not positive: enum_one finds no case there, as EnumSolver)."""
    iN = j
    iT = m + j
    idx = np.empty(2, dtype=np.int64)
    idx[0] = iN
    idx[1] = iT
    Ha = _rows(o_H, r, n, idx)
    SHta = _cols(o_SHt, n, idx)
    qa = _matvec(Ha, vfree)
    if moving:
        qa[0] = qa[0] + o_b1[iN]
        qa[1] = qa[1] + o_b1[iT]
    qN = qa[0]
    qT = qa[1]
    shift = 0.0
    has_e = e[j] != 0.0
    if has_e:
        shift = e[j] * min(uNm[j], 0.0)
        qN += shift
    W00 = o_W[iN + iN * r]
    W01 = o_W[iN + iT * r]
    W10 = o_W[iT + iN * r]
    W11 = o_W[iT + iT * r]
    muj = mu[j]
    pN, pT, mode, nd = enum_one(W00, W01, W10, W11, qN, qT, muj)
    if mode < 0:
        return False
    rhoN = 1.0 / W00 if W00 > 0 else 1.0
    rhoT = 1.0 / W11 if W11 > 0 else 1.0
    scale = max(max(abs(qN) * rhoN, abs(qT) * rhoT), 1e-300)
    uN, uT = W00 * pN + W01 * pT + qN, W10 * pN + W11 * pT + qT
    s = muj * max(pN, 0.0)
    rT = pT - min(max(pT - rhoT * uT, -s), s)
    res = max(abs(min(pN, rhoN * uN)), abs(rT))
    sc = max(scale, max(abs(pN), abs(pT)), 1e-300)
    if not math.isfinite(res) or res > res_tol * sc:
        return False
    if not _error_one(W00, W01, W10, W11, qN, qT, muj, pN, pT) <= res_tol:
        return False
    istate[2] += 1
    istate[3] += 4
    istate[4] = max(istate[4], 4)
    if nd > 1:
        if istate[10] == 0:
            istate[11] = k
        istate[10] += 1
    fstate[0] = max(fstate[0], res)
    # modes (ContactProblem.modes, one contact): thresholds 1e-9 of the contact's own scale
    tol_p = 1e-9 * max(abs(qN) * rhoN, abs(qT) * rhoT, abs(pN), abs(pT),
                       _COUPLING_FLOOR * rhoN * (abs(W00 * pN) + abs(W01 * pT)),
                       _COUPLING_FLOOR * rhoT * (abs(W10 * pN) + abs(W11 * pT)), _SCALE_FLOOR * scale)
    uTm = (W10 * pN + W11 * pT + qT) * rhoT
    if pN <= tol_p:
        md = 0
    elif uTm > tol_p:
        md = 2
    elif uTm < -tol_p:
        md = 3
    else:
        md = 1
    pp = np.empty(2)
    pp[0] = pN
    pp[1] = pT
    sp = _seqmv(SHta, pp)
    for a in range(n):
        dv[a] = dvf[a] + sp[a]
        w[a] = v[a] + dv[a]
    # the branch refinement: r = H (v + dv) cancelled on the branch of the mode
    if md != 0:
        rl = _matvec(Ha, w)
        rN = rl[0]
        rTl = rl[1]
        if moving:
            rN = rN + o_b1[iN]
            rTl = rTl + o_b1[iT]
        if has_e:
            rN += shift
        ok = True
        if md == 1:
            det = W00 * W11 - W01 * W10
            if det == 0.0:
                ok = False
                dN = dT = 0.0
            else:
                dN = (-rN * W11 + rTl * W01) / det
                dT = (-rTl * W00 + rN * W10) / det
        else:
            sg = 1.0 if md == 2 else -1.0
            aa = W00 - sg * muj * W01
            if aa == 0.0:
                ok = False
                dN = dT = 0.0
            else:
                dN = -rN / aa
                dT = -sg * muj * dN
        if ok and math.isfinite(dN + dT):
            pN = pN + dN
            pT = pT + dT
            pp[0] = dN
            pp[1] = dT
            sp = _seqmv(SHta, pp)
            for a in range(n):
                dv[a] = dv[a] + sp[a]
    out[0] = pN
    out[1] = pT
    out[2] = 0.0
    out[3] = md
    return True


@njit(cache=True)
def _disk_error(Wl, qa, mu, p):
    """ContactProblem.error of one disk contact (lcp.contact.law.natural_map_error, dims = [2])."""
    u = np.empty(3)
    for a in range(3):
        u[a] = Wl[a, 0] * p[0] + Wl[a, 1] * p[1] + Wl[a, 2] * p[2] + qa[a]
    zN = p[0] - u[0] - mu * math.hypot(u[1], u[2])
    z0 = p[1] - u[1]
    z1 = p[2] - u[2]
    aT = math.hypot(z0, z1)
    inside = aT <= mu * zN and zN >= 0
    polar = mu * aT <= -zN
    rN = (zN + mu * aT) / (1.0 + mu * mu)
    f = 0.0 if (inside or polar) else mu * rN / (aT if aT > 0 else 1.0)
    pN = zN if inside else (0.0 if polar else rN)
    pT0 = z0 if inside else z0 * f
    pT1 = z1 if inside else z1 * f
    err = math.sqrt((p[0] - pN) ** 2 + ((p[1] - pT0) ** 2 + (p[2] - pT1) ** 2))
    scale = max(math.sqrt(p[0] ** 2 + p[1] ** 2 + p[2] ** 2), math.sqrt(u[0] ** 2 + u[1] ** 2 + u[2] ** 2),
                math.sqrt(qa[0] ** 2 + qa[1] ** 2 + qa[2] ** 2))
    return err / scale if scale > _EPS else err


@njit(cache=True)
def _disk_step(j, m, n, r, toff, o_W, o_H, o_SHt, o_b1, moving, v, vfree, dvf, uNm, mu, e, res_tol, istate, fstate,
               dv, w, out):
    """One active disk contact j by the local solve, as ContactStep.solve with the ``"auto"`` (or
    ``"local"``) disk-law solver: the exact local solve (local_disk3), the branch refinement and its
    modes (refine_dense), the solver's acceptance test, the stuck contact's velocity correction.
    Fills dv and out = (pN, pT0, pT1, mode); False where the Python side must solve the step."""
    idx = np.empty(3, dtype=np.int64)
    idx[0] = j
    idx[1] = m + toff[j]
    idx[2] = m + toff[j] + 1
    Ha = _rows(o_H, r, n, idx)
    SHta = _cols(o_SHt, n, idx)
    qa = _matvec(Ha, vfree)
    if moving:
        for a in range(3):
            qa[a] = qa[a] + o_b1[idx[a]]
    shift = 0.0
    has_e = e[j] != 0.0
    if has_e:
        shift = e[j] * min(uNm[j], 0.0)
        qa[0] += shift
    Wl = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            Wl[a, b] = o_W[idx[a] + idx[b] * r]
    muj = mu[j]
    pN, pT0, pT1, mode, _ = local_disk3(Wl, qa[0], qa[1], qa[2], muj, 0.0, 0.0)
    if mode < 0:
        return False
    dN = Wl[0, 0]
    dTm = max(Wl[1, 1], Wl[2, 2])
    rhoN = np.array([1.0 / dN if dN > 0 else 1.0])
    rhoT = np.array([1.0 / dTm if dTm > 0 else 1.0])
    scale = max(max(abs(qa[0]) * rhoN[0], abs(qa[1]) * rhoT[0], abs(qa[2]) * rhoT[0]), 1e-300)
    mus = np.array([muj])
    dims = np.array([2], dtype=np.int64)
    toff1 = np.zeros(1, dtype=np.int64)
    p0 = np.array([pN, pT0, pT1])
    p, md = refine_dense(Wl, qa, mus, dims, toff1, rhoN, rhoT, scale, p0, 3, 1e-9)
    if not math.isfinite(p[0] + p[1] + p[2]):
        return False
    res = residual_blocked_dense(Wl, qa, mus, dims, toff1, rhoN, rhoT, p)
    sc = max(scale, max(abs(p[0]), abs(p[1]), abs(p[2])), 1e-300)
    if not math.isfinite(res) or res > res_tol * sc:
        return False
    if not _disk_error(Wl, qa, muj, p) <= res_tol:
        return False
    pv = p.copy()
    sp = _seqmv(SHta, pv)
    for a in range(n):
        dv[a] = dvf[a] + sp[a]
    if md[0] == 1:  # stuck: one correction on the velocities themselves (ContactStep.solve)
        for a in range(n):
            w[a] = v[a] + dv[a]
        rl = _matvec(Ha, w)
        if moving:
            for b in range(3):
                rl[b] = rl[b] + o_b1[idx[b]]
        if has_e:
            rl[0] += shift
        try:
            dp = np.linalg.solve(Wl, -rl)
        except Exception:  # singular: the Python side takes its least-squares step
            return False
        if not math.isfinite(dp[0] + dp[1] + dp[2]):
            return False
        for b in range(3):
            pv[b] = pv[b] + dp[b]
        sp = _seqmv(SHta, dp)
        for a in range(n):
            dv[a] = dv[a] + sp[a]
    istate[2] += 1
    istate[3] += 1
    istate[4] = max(istate[4], 1)
    fstate[0] = max(fstate[0], res)
    out[0] = pv[0]
    out[1] = pv[1]
    out[2] = pv[2]
    out[3] = md[0]
    return True


@njit(cache=True)
def _force_rejected(n, nq, lin, q, v, F, miss, size):
    """ForceStepCheck's test of the previous step's linearisation (lin: t, q0, v0, F0, K0, C0)."""
    q0 = lin[1:1 + nq]
    v0 = lin[1 + nq:1 + nq + n]
    F0 = lin[1 + nq + n:1 + nq + 2 * n]
    K0 = lin[1 + nq + 2 * n:1 + nq + 2 * n + n * n]
    C0 = lin[1 + nq + 2 * n + n * n:]
    big = 0.0
    for i in range(n):
        dq = 0.0
        dvv = 0.0
        for c in range(n):
            dq += K0[i + c * n] * (q[c] - q0[c])
            dvv += C0[i + c * n] * (v[c] - v0[c])
        Fl = F0[i] - dq - dvv
        miss[i] = abs(F[i] - Fl)
        size[i] = max(abs(F0[i]), abs(F[i]), abs(Fl), abs(dq), abs(dvv))
        big = max(big, size[i])
    worst = 0
    ratio = -1.0
    finite = True
    for i in range(n):
        size[i] = max(size[i], 1e-8 * big + 1e-300)
        if not math.isfinite(miss[i]):
            finite = False
        x = miss[i] / size[i]
        if x > ratio:
            ratio = x
            worst = i
    return (not finite) or miss[worst] > 0.5 * size[worst]


@njit(cache=True)
def _project(pfunc, pargp, presp, piw, pw, p_t, p_q, p_w, p_L, p_qo, p_r, p_s, p_mu, t, q, v, o_H, r, nb, m,
             ploaded, ptol, max_evals, ell, h, close_tol, closed, opening, kin, out):
    """PositionProjection.project after a step (the Python loop's call of it, with its closed and
    opening masks); the projected q goes to ``p_qo``; out = (ok, evaluations, violation)."""
    n = v.size
    if m:
        HN = _rows(o_H, r, n, np.arange(m))
        uN = _matvec(HN, v)
        aN = _matvec(np.abs(HN), np.abs(v))
        for j in range(m):
            opening[j] = uN[j] > close_tol * aN[j]
            closed[j] = ploaded[j] and not opening[j]
    p_t[0] = t
    for a in range(q.size):
        p_q[a] = q[a]
    if kin:  # n_q != n_v: one length for every coordinate (the Python loop's reach)
        vmax = amax_abs(v) if n else 0.0
        for a in range(q.size):
            p_L[a] = ell + h * vmax
    else:
        for a in range(n):
            p_L[a] = ell + h * abs(v[a])
    for j in range(m):
        closed[j] = closed[j] and not opening[j]  # hold: closed and free
        p_w[j] = 1.0 if closed[j] else 0.0
    ok = False
    evals = 0
    while evals < max_evals:
        if pfunc(pargp.ctypes.data, presp.ctypes.data, piw.ctypes.data, pw.ctypes.data, 0) != 0:
            break
        evals += 1
        bil_ok = True
        for i in range(nb):
            if not abs(p_r[i]) <= ptol * p_s[i]:
                bil_ok = False
        changed = False
        closed_ok = True
        for j in range(m):
            lg = ptol * p_s[nb + j]
            inw = p_w[j] != 0.0
            if inw and not abs(p_r[nb + j]) <= lg:
                closed_ok = False
        for j in range(m):
            lg = ptol * p_s[nb + j]
            inw = p_w[j] != 0.0
            pull = inw and not closed[j] and p_mu[nb + j] < -lg
            pen = (not inw) and (not opening[j]) and p_r[nb + j] < -lg
            if pull:
                p_w[j] = 0.0
                changed = True
            elif pen:
                p_w[j] = 1.0
                changed = True
        for a in range(q.size):
            p_q[a] = p_qo[a]
        if bil_ok and closed_ok and not changed:
            ok = True
            break
    viol = 0.0
    for i in range(nb):
        viol = max(viol, abs(p_r[i]))
    if m:
        gmin = np.inf
        for j in range(m):
            gmin = min(gmin, p_r[nb + j])
        viol = max(viol, -gmin, 0.0)
    out[0] = 1.0 if ok else 0.0
    out[1] = evals
    out[2] = viol


@njit(cache=True)
def run_general(cfunc, argp, resp, iw, w, a_t, a_q, a_v, o_vf, o_S, o_SHt, o_W, o_gap, o_H, o_b0, o_b1,
                o_F0, o_F1, o_K1, o_C1, kin, kfunc, kargp, kresp, kiw, kw, k_t, k_q, k_w, k_rate, k_B, quats,
                k0, k_end, every, h, th, close_tol, open_tol, res_tol, mu, e,
                dims, toff, closed_form, disk_local, cone_multi, max_sweeps, planar_multi, q, v, cq, cv, loaded, istate,
                fstate, lin, Q, V, PN, PT, MD,
                imp_t, imp_j, imp_p, dvf, vfree, uNm, uNf, act, forced, fdv, project, pfunc, pargp, presp, piw, pw,
                p_t, p_q, p_w, p_L, p_qo, p_r, p_s, p_mu, nb, ptol, max_evals, ell, ploaded, ctrl,
                cfn=None, cargp=None, cresp=None, ciw=None, cw=None, c_t=None, c_q=None, c_B=None, c_f0=None,
                c_f1=None, cimp=None):
    """Steps k0 .. k_end - 1 (module docstring); returns (step, reason).

    ``istate`` = [all_loaded, free_steps, solver_calls, iterations, max_iterations, open, stick,
    slide+, slide-, slide, ambiguous, first ambiguous step, impacts, active count of a handed step,
    skip the force check of step k0, projections, projection iterations, the failed projection's
    evaluations, steps with several contacts solved here]; ``cone_multi``: steps with 2 to
    ``cone_multi`` active disk-law contacts are solved here (:func:`lcp.timestepping.multi_kernels.cone_multi_step`,
    at most ``max_sweeps`` NSGS sweeps; 0: none); ``planar_multi`` = (largest count, sweeps, Newton
    iterations, rounds): steps with 2 to ``planar_multi[0]`` active planar contacts are solved here
    (:func:`lcp.timestepping.planar_multi_kernels.planar_multi_step`; 0: none), and with one where
    there is no closed form (``"nsgs"``) and no bilateral constraint; ``fstate`` = [max
    residual, worst violation after a projection, violation of a failed projection]; ``lin`` the force check's
    linearisation (t, q, v, F, K, C; t NaN: none). When the reason is not DONE the state (q, v,
    sums, loaded) is that at the start of the returned step; for NEEDS_PYTHON the buffers hold its
    data, ``act[:istate[13]]`` its active contacts. With ``forced``, step k0 takes the velocity
    increment ``fdv`` (the Python side did the rest of it). With ``project``, the positions after
    each step are projected by the compiled update ``pfunc`` (PositionProjection's Function) with
    the working-set rule of :meth:`PositionProjection.project
    <lcp.timestepping.projection.PositionProjection.project>`; ``ploaded`` are the contacts
    loaded in the step and not bounced off (the Python loop's ``loaded``). ``ctrl``: per step k
    the control correction c_k (B u's exact impulse less its theta-weighted one), added as S c_k to
    the free velocity increment; no rows: no control schedule. ``cfn`` ... ``cimp``: a control
    whose B(t, q) depends on q, c_k computed each step from the compiled
    :func:`lcp.timestepping.compiled_control.control_function` on its buffers and the step's impulse
    ``cimp[k]`` (:func:`~lcp.timestepping.control_kernels.control_vector`); None: no such control.
    """
    n = v.size
    nq = q.size
    m = mu.size
    r = o_H.size // n if n else 0  # contact rows: H is (r, n)
    moving = o_b0.size > 0
    check = o_F0.size > 0
    ksz = np.empty(m)
    dv = np.empty(n)
    wv = np.empty(n)
    vn = np.empty(n)
    qn = np.empty(nq)
    cqn = np.empty(nq)
    cvn = np.empty(n)
    inc = np.empty(n)
    miss = np.empty(n)
    size = np.empty(n)
    out = np.empty(4)
    pout = np.empty(3)
    closed = np.zeros(m, dtype=np.bool_)
    opening = np.zeros(m, dtype=np.bool_)
    allm = np.arange(m)
    cap = imp_t.size
    room = min(max(m, 1), cap)  # impacts one step may record
    nmax = m + int(np.sum(dims)) if (cone_multi or planar_multi[0]) else 0
    pmul = np.empty(nmax)
    mdmul = np.empty(max(m, 1), dtype=np.int64)
    a_c = h * (1 - th)
    b_c = h * th
    for k in range(k0, k_end):
        tk = k * h
        row = (k + 1) // every - 1 if (k + 1) % every == 0 else -1
        if forced and k == k0:
            for a in range(n):
                dv[a] = fdv[a]
        else:
            if istate[12] + room > cap:
                return k, BUFFER_FULL
            a_t[0] = tk
            for a in range(nq):
                a_q[a] = q[a]
            for a in range(n):
                a_v[a] = v[a]
            if cfunc(argp.ctypes.data, resp.ctypes.data, iw.ctypes.data, w.ctypes.data, 0) != 0:
                return k, BAD_DATA
            good = True
            for a in range(o_S.size):
                good = good and math.isfinite(o_S[a])
            for a in range(n):
                good = good and math.isfinite(o_vf[a])
            if not good:
                return k, BAD_DATA
            if check:
                if not (istate[14] and k == k0) and lin[0] == tk:
                    if _force_rejected(n, nq, lin, q, v, o_F0, miss, size):
                        return k, REJECTED
                istate[14] = 0
                lin[0] = tk + h
                b = 1
                for a in range(nq):
                    lin[b + a] = q[a]
                b += nq
                for a in range(n):
                    lin[b + a] = v[a]
                    lin[b + n + a] = o_F1[a]
                b += 2 * n
                for a in range(n * n):
                    lin[b + a] = o_K1[a]
                    lin[b + n * n + a] = o_C1[a]
            for a in range(n):
                dvf[a] = o_vf[a] - v[a]
            if ctrl.shape[0]:  # a control schedule: S c_k (StepAssembly._control_correction)
                cor = _matvec(_rows(o_S, n, n, np.arange(n)), ctrl[k])
                for a in range(n):
                    dvf[a] = dvf[a] + cor[a]
            elif cimp is not None:  # the same with B(t, q): c_k at this step's q
                if not control_vector(cfn, cargp, cresp, ciw, cw, c_t, c_q, c_B, c_f0, c_f1, cimp[k], tk, q, h, th,
                                      wv):
                    return k, BAD_DATA
                cor = _matvec(_rows(o_S, n, n, np.arange(n)), wv)
                for a in range(n):
                    dvf[a] = dvf[a] + cor[a]
            for a in range(n):
                vfree[a] = v[a] + dvf[a]
            # activation (lcp.timestepping.activation.Activation): the same sums in the same order
            na = 0
            if m:
                HN = _rows(o_H, r, n, allm)
                um = _matvec(HN, v)
                uf = _matvec(HN, vfree)
                for j in range(m):
                    sm = um[j]
                    sf = uf[j]
                    if moving:
                        sm = sm + o_b0[j]
                        sf = sf + o_b1[j]
                    uNm[j] = sm
                    uNf[j] = sf
                any_open = not all_closing(m, o_gap, uNm, uNf, a_c, b_c)
                if not any_open:
                    for j in range(m):
                        act[na] = j
                        na += 1
                else:
                    any_loaded = False
                    for j in range(m):
                        any_loaded = any_loaded or loaded[j]
                    if n == nq:
                        szq = _matvec(np.abs(HN), np.abs(q))
                    else:  # Newton-Euler kinematics: the rows' sizes times q's largest entry
                        kinematic_sizes(o_H, r, n, m, q, ksz)
                        szq = ksz
                    for j in range(m):
                        aa = a_c * uNm[j]
                        bb = b_c * uNf[j]
                        pred = (o_gap[j] + aa) + bb
                        sz = ((szq[j] + abs(o_gap[j])) + abs(aa)) + abs(bb)
                        closing = pred <= close_tol * sz
                        if any_loaded and loaded[j] and o_gap[j] + aa <= open_tol * sz:
                            closing = True
                        if closing:
                            act[na] = j
                            na += 1
            if na == 0:
                for a in range(n):
                    dv[a] = dvf[a]
                istate[1] += 1
                for j in range(m):
                    loaded[j] = False
                    ploaded[j] = False
                istate[0] = 0
            elif na == 1 and ((closed_form and _closed_form_step(act[0], m, n, r, k, tk, h, o_W, o_H, o_SHt, o_b1,
                                                                  moving, v, vfree, dvf, uNm, mu, e, res_tol,
                                                                  istate, fstate, dv, wv, out))
                              or (disk_local and dims[act[0]] == 2
                                  and _disk_step(act[0], m, n, r, toff, o_W, o_H, o_SHt, o_b1, moving, v, vfree,
                                                 dvf, uNm, mu, e, res_tol, istate, fstate, dv, wv, out))):
                j = act[0]
                pN = out[0]
                md = int(out[3])
                if istate[0] == 0:  # impacts (lcp.timestepping.outcome.record_impacts)
                    um = uNm[j]
                    if pN > 0 and not loaded[j] and um < 0 and -um > abs(uNf[j] - um):
                        c = istate[12]
                        imp_t[c] = tk + min(h, max(0.0, o_gap[j] / -um))
                        imp_j[c] = j
                        imp_p[c, 0] = pN
                        imp_p[c, 1] = out[1]
                        imp_p[c, 2] = out[2]
                        istate[12] = c + 1
                if m > 1:
                    for i in range(m):
                        loaded[i] = False
                loaded[j] = pN > 0
                istate[0] = 1 if (m == 1 and pN > 0) else 0
                if project:
                    for i in range(m):
                        ploaded[i] = False
                    ploaded[j] = pN > 0 and (e[j] == 0 or uNm[j] >= 0)
                if row >= 0:
                    PN[row, j] = pN
                    for a in range(dims[j]):
                        PT[row, toff[j] + a] = out[1 + a]
                    MD[row, j] = md
                istate[5 + md] += 1
            elif ((2 <= na <= cone_multi
                   and cone_multi_step(act, na, m, n, r, o_W, o_H, o_SHt, o_b1, moving, v, vfree, dvf, uNm, mu, e,
                                       dims, toff, res_tol, max_sweeps, istate, fstate, dv, pmul, mdmul))
                  # one contact: "nsgs" by name, without bilateral constraints (with them its problem
                  # may be redundant, the split of its impulses the solver's: the Python loop's then)
                  or ((2 if closed_form or nb > 0 else 1) <= na <= planar_multi[0]
                      and planar_multi_step(act, na, m, n, r, o_W, o_H, o_SHt, o_b1, moving, v, vfree, dvf, uNm, mu,
                                            e, res_tol, planar_multi, istate, fstate, dv, pmul, mdmul))):
                record_multi(act, na, m, tk, h, row, pmul, mdmul, dims, toff, e, o_gap, uNm, uNf, loaded, ploaded,
                             project, istate, imp_t, imp_j, imp_p, PN, PT, MD)
            else:
                istate[13] = na
                return k, NEEDS_PYTHON
        # compensated (Kahan) sums, as lcp.timestepping.assembly.kahan_add
        for a in range(n):
            y = dv[a] - cv[a]
            s = v[a] + y
            cvn[a] = (s - v[a]) - y
            vn[a] = s
        for a in range(n):
            inc[a] = (1 - th) * v[a] + th * vn[a]
        if kin:  # q + h T(q) v_theta, unit quaternions by the exponential map (advance_positions)
            if not advance(kfunc, kargp, kresp, kiw, kw, k_t, k_q, k_w, k_rate, k_B, quats, tk, q, inc, h, cq, qn,
                            cqn):
                return k, NONFINITE
        else:
            for a in range(nq):
                x = h * inc[a]
                y = x - cq[a]
                s = q[a] + y
                cqn[a] = (s - q[a]) - y
                qn[a] = s
        tot = 0.0
        for a in range(nq):
            tot += qn[a]
        for a in range(n):
            tot += vn[a]
        finite = math.isfinite(tot)
        if not finite:  # a sum that overflows on finite entries is looked at entry by entry
            finite = True
            for a in range(nq):
                finite = finite and math.isfinite(qn[a])
            for a in range(n):
                finite = finite and math.isfinite(vn[a])
        if not finite:
            return k, NONFINITE
        for a in range(nq):
            q[a] = qn[a]
            cq[a] = cqn[a]
        for a in range(n):
            v[a] = vn[a]
            cv[a] = cvn[a]
        if project:
            _project(pfunc, pargp, presp, piw, pw, p_t, p_q, p_w, p_L, p_qo, p_r, p_s, p_mu, tk + h, q, v, o_H, r, nb,
                     m, ploaded, ptol, max_evals, ell, h, close_tol, closed, opening, kin, pout)
            istate[15] += 1
            istate[16] += int(pout[1])
            if pout[0] == 0.0 or not math.isfinite(pout[2]):
                fstate[2] = pout[2]
                istate[17] = int(pout[1])
                return k, PROJECTION_FAILED
            for a in range(nq):
                q[a] = p_qo[a]
                cq[a] = 0.0
            fstate[1] = max(fstate[1], pout[2])
        if row >= 0:
            for a in range(nq):
                Q[row + 1, a] = q[a]
            for a in range(n):
                V[row + 1, a] = v[a]
    return k_end, DONE
