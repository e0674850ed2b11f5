"""numba pieces of the compiled loops for control schedules: NumPy's products, repeated exactly.

Holds :func:`dense_mv` (A @ x as NumPy computes it for a C-ordered A), :func:`control_vector` (the
compiled general loop's per-step correction c_k of a control whose B(t, q) depends on q, from the
compiled :func:`lcp.timestepping.compiled_control.control_function` called on its buffers) and
:func:`constant_control_dv` (the free velocity increment of a controlled constant system in the
constant compiled loop: the drift's, then S B int u, with the dense matrices of
:class:`~lcp.timestepping.assembly.StepAssembly`). Imports NumPy and numba
(:mod:`lcp.numerics.jit`) only; never the set-up, the loops or anything above
:mod:`lcp.timestepping`.
"""
from __future__ import annotations

import numpy as np

from lcp.numerics.jit import njit

__all__ = ["constant_control_dv", "control_vector", "dense_mv"]


@njit(cache=True)
def dense_mv(A, x):
    """A @ x as NumPy computes it for a C-ordered A: BLAS's gemv (numba calls the same BLAS, so the
    sums round the same way), a single short row summed in order (as BLAS's dot of it)."""
    if A.shape[0] == 1 and A.shape[1] <= 16:
        out = np.zeros(1)
        s = 0.0
        for c in range(A.shape[1]):
            s += A[0, c] * x[c]
        out[0] = s
        return out
    if A.shape[0] == 1:
        out = np.empty(1)
        out[0] = np.dot(A[0], x)
        return out
    return np.dot(A, x)


@njit(cache=True)
def constant_control_dv(ctl, u, h, q, v, t1, dvf):
    """The free velocity increment of a controlled constant system into ``dvf``, as
    ``StepAssembly.at`` computes it with its ``control_matrix`` B: Fth = F0 (+ Kq q + Cv v),
    S (h Fth + h^2 theta Kq v) (+ T (-phi_t - G v)), then + S (B u) for the control's impulse u
    over the step. ``ctl`` = (B, S, Kq, Cv, h^2 theta Kq, T, G, F0, phi_t), dense and C-ordered (Kq
    and Cv empty: a constant drift force; T, G, phi_t empty: no bilateral constraint)."""
    (Bd, Sd, Kq, Cv, hK, Td, Gd, F0, phi_t) = ctl
    n = F0.size
    if Kq.size:
        kq = dense_mv(Kq, q)
        cv = dense_mv(Cv, v)
        for a in range(n):
            t1[a] = (F0[a] + kq[a]) + cv[a]
    else:
        for a in range(n):
            t1[a] = F0[a]
    hk = dense_mv(hK, v)
    for a in range(n):
        t1[a] = h * t1[a] + hk[a]
    dvf[:] = dense_mv(Sd, t1)
    if phi_t.size:
        gv = dense_mv(Gd, v)
        c = np.empty(phi_t.size)
        for a in range(phi_t.size):
            c[a] = -phi_t[a] - gv[a]
        tc = dense_mv(Td, c)
        for a in range(n):
            dvf[a] = dvf[a] + tc[a]
    if Bd.shape[1] == 0:  # no control (a constant system without contact): the drift's arithmetic alone
        return
    su = dense_mv(Sd, dense_mv(Bd, u))
    for a in range(n):
        dvf[a] = dvf[a] + su[a]


@njit(cache=True)
def control_vector(cfunc, argp, resp, iw, w, c_t, c_q, c_B, c_f0, c_f1, imp, tk, q, h, th, out):
    """c = B(t, q) imp - h ((1 - theta) f0 + theta f1) at t = ``tk`` into ``out`` (n), the compiled
    :func:`control_function` evaluated on its buffers; False where its call fails.

    B imp is NumPy's product (:func:`dense_mv`), the rest elementwise, as
    :meth:`StepAssembly._control_correction <lcp.timestepping.assembly.StepAssembly>`."""
    n = out.size
    nu = imp.size
    c_t[0] = tk
    for a in range(q.size):
        c_q[a] = q[a]
    if cfunc(argp.ctypes.data, resp.ctypes.data, iw.ctypes.data, w.ctypes.data, 0) != 0:
        return False
    B = np.empty((n, nu))
    for a in range(n):
        for c in range(nu):
            B[a, c] = c_B[a + c * n]
    bu = dense_mv(B, imp)
    a_c = 1 - th
    for a in range(n):
        out[a] = bu[a] - h * (a_c * c_f0[a] + th * c_f1[a])
    return True
