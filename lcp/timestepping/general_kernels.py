"""The numba kernel of the compiled Moreau-Jean loop for general systems: the steps themselves.

Holds :func:`run_general` (steps k0 .. k_end - 1 of any system whose step data come from the C
function of :mod:`lcp.timestepping.codegen`) and the reasons it returns for. Imports NumPy and
numba (:mod:`lcp.numerics.jit`); never the set-up, the Python solvers, the result or anything
above :mod:`lcp.timestepping`. Each step, as the Python loop (:mod:`lcp.timestepping.python_loop`)
computes it:

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
- restitution shift, impacts, the Kahan-compensated sums of v and q (q' = T(q) v where the system
  has a kinematics map), every ``save_every``-th state.

Every other contact step (several active contacts, spatial contacts, another solver, a closed form
that fails its test) returns NEEDS_PYTHON with the step's data in the buffers: the Python side
solves it with the loop's own :class:`~lcp.timestepping.contact_step.ContactStep` and calls back
with the velocity increment (``forced``), and the kernel finishes that step and goes on.
"""
from __future__ import annotations

import math

import numpy as np

from lcp.numerics.jit import njit

__all__ = ["DONE", "NEEDS_PYTHON", "NONFINITE", "BAD_DATA", "REJECTED", "BUFFER_FULL", "run_general"]

#: reasons for which :func:`run_general` returns
DONE, NEEDS_PYTHON, NONFINITE, BAD_DATA, REJECTED, BUFFER_FULL = 0, 1, 2, 3, 4, 5

#: the floors of the contact scale (lcp.contact.law.COUPLING_FLOOR, SCALE_FLOOR) and the unit roundoff
_COUPLING_FLOOR = 1e-2
_SCALE_FLOOR = 1e-12
_EPS = 2.220446049250313e-16


@njit(cache=True)
def _enum_one(W00, W01, W10, W11, qN, qT, mu):
    """lcp.contact.planar_closed_form.planar_enum on floats (rtol 1e-12): (pN, pT, mode, n_distinct)."""
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
    dv and out = (pN, pT, mode); False where the Python side must solve the step."""
    iN = j
    iT = m + j
    qN = 0.0
    qT = 0.0
    for c in range(n):
        qN += o_H[iN + c * r] * vfree[c]
        qT += o_H[iT + c * r] * vfree[c]
    if moving:
        qN = qN + o_b1[iN]
        qT = qT + o_b1[iT]
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
    pN, pT, mode, nd = _enum_one(W00, W01, W10, W11, qN, qT, muj)
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
        if istate[9] == 0:
            istate[10] = k
        istate[9] += 1
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
    for a in range(n):
        dv[a] = dvf[a] + (o_SHt[a + iN * n] * pN + o_SHt[a + iT * n] * pT)
        w[a] = v[a] + dv[a]
    # the branch refinement: r = H (v + dv) cancelled on the branch of the mode
    if md != 0:
        rN = 0.0
        rTl = 0.0
        for c in range(n):
            rN += o_H[iN + c * r] * w[c]
            rTl += o_H[iT + c * r] * w[c]
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
            for a in range(n):
                dv[a] = dv[a] + (o_SHt[a + iN * n] * dN + o_SHt[a + iT * n] * dT)
    out[0] = pN
    out[1] = pT
    out[2] = md
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
def run_general(cfunc, argp, resp, iw, w, a_t, a_q, a_v, o_vf, o_S, o_SHt, o_W, o_gap, o_H, o_b0, o_b1,
                o_F0, o_F1, o_K1, o_C1, o_T, k0, k_end, every, h, th, close_tol, open_tol, res_tol, mu, e,
                closed_form, q, v, cq, cv, loaded, istate, fstate, lin, Q, V, PN, PT, MD, imp_t, imp_j, imp_p,
                dvf, vfree, uNm, uNf, act, forced, fdv):
    """Steps k0 .. k_end - 1 (module docstring); returns (step, reason).

    ``istate`` = [all_loaded, free_steps, solver_calls, iterations, max_iterations, open, stick,
    slide+, slide-, ambiguous, first ambiguous step, impacts, active count of a handed step, skip
    the force check of step k0]; ``fstate`` = [max residual]; ``lin`` the force check's
    linearisation (t, q, v, F, K, C; t NaN: none). When the reason is not DONE the state (q, v,
    sums, loaded) is that at the start of the returned step; for NEEDS_PYTHON the buffers hold its
    data, ``act[:istate[12]]`` its active contacts. With ``forced``, step k0 takes the velocity
    increment ``fdv`` (the Python side did the rest of it).
    """
    n = v.size
    nq = q.size
    m = mu.size
    r = o_H.size // n if n else 0  # contact rows: H is (r, n)
    moving = o_b0.size > 0
    check = o_F0.size > 0
    kin = o_T.size > 0
    dv = np.empty(n)
    wv = np.empty(n)
    vn = np.empty(n)
    qn = np.empty(nq)
    cqn = np.empty(nq)
    cvn = np.empty(n)
    inc = np.empty(n)
    miss = np.empty(n)
    size = np.empty(n)
    out = np.empty(3)
    cap = imp_t.size
    a_c = h * (1 - th)
    b_c = h * th
    for k in range(k0, k_end):
        tk = k * h
        row = (k + 1) // every - 1 if (k + 1) % every == 0 else -1
        if forced and k == k0:
            for a in range(n):
                dv[a] = fdv[a]
        else:
            if istate[11] + 1 > cap:
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
                if not (istate[13] and k == k0) and lin[0] == tk:
                    if _force_rejected(n, nq, lin, q, v, o_F0, miss, size):
                        return k, REJECTED
                istate[13] = 0
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
                vfree[a] = v[a] + dvf[a]
            # activation (lcp.timestepping.activation.Activation): the same sums in the same order
            na = 0
            if m:
                any_open = False
                for j in range(m):
                    sm = 0.0
                    sf = 0.0
                    for c in range(n):
                        sm += o_H[j + c * r] * v[c]
                        sf += o_H[j + c * r] * vfree[c]
                    if moving:
                        sm = sm + o_b0[j]
                        sf = sf + o_b1[j]
                    uNm[j] = sm
                    uNf[j] = sf
                    if (o_gap[j] + a_c * sm) + b_c * sf > 0.0:
                        any_open = True
                if not any_open:
                    for j in range(m):
                        act[na] = j
                        na += 1
                else:
                    any_loaded = False
                    for j in range(m):
                        any_loaded = any_loaded or loaded[j]
                    for j in range(m):
                        aa = a_c * uNm[j]
                        bb = b_c * uNf[j]
                        pred = (o_gap[j] + aa) + bb
                        sz = 0.0
                        for c in range(n):
                            sz += abs(o_H[j + c * r]) * abs(q[c])
                        sz = ((sz + abs(o_gap[j])) + abs(aa)) + abs(bb)
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
                istate[0] = 0
            elif closed_form and na == 1 and _closed_form_step(act[0], m, n, r, k, tk, h, o_W, o_H, o_SHt, o_b1,
                                                               moving, v, vfree, dvf, uNm, mu, e, res_tol,
                                                               istate, fstate, dv, wv, out):
                j = act[0]
                pN = out[0]
                pT = out[1]
                md = int(out[2])
                if istate[0] == 0:  # impacts (lcp.timestepping.outcome.record_impacts)
                    um = uNm[j]
                    if pN > 0 and not loaded[j] and um < 0 and -um > abs(uNf[j] - um):
                        c = istate[11]
                        imp_t[c] = tk + min(h, max(0.0, o_gap[j] / -um))
                        imp_j[c] = j
                        imp_p[c, 0] = pN
                        imp_p[c, 1] = pT
                        istate[11] = c + 1
                if m > 1:
                    for i in range(m):
                        loaded[i] = False
                loaded[j] = pN > 0
                istate[0] = 1 if (m == 1 and pN > 0) else 0
                if row >= 0:
                    PN[row, j] = pN
                    PT[row, j] = pT
                    MD[row, j] = md
                istate[5 + md] += 1
            else:
                istate[12] = na
                return k, NEEDS_PYTHON
        # compensated (Kahan) sums, as lcp.timestepping.assembly.kahan_add
        for a in range(n):
            y = dv[a] - cv[a]
            s = v[a] + y
            cvn[a] = (s - v[a]) - y
            vn[a] = s
        for a in range(n):
            inc[a] = (1 - th) * v[a] + th * vn[a]
        finite = True
        for a in range(nq):
            if kin:
                x = 0.0
                for c in range(n):
                    x += o_T[a + c * nq] * inc[c]
                x = h * x
            else:
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
        if not finite:
            return k, NONFINITE
        for a in range(nq):
            q[a] = qn[a]
            cq[a] = cqn[a]
        for a in range(n):
            v[a] = vn[a]
            cv[a] = cvn[a]
        if row >= 0:
            for a in range(nq):
                Q[row + 1, a] = q[a]
            for a in range(n):
                V[row + 1, a] = v[a]
    return k_end, DONE
