"""Moreau-Jean for constant planar systems with several contacts (or none): all steps in one compiled call.

The Python loop (:mod:`lcp.timestepping.python_loop`) pays 10-30 microseconds of interpreter work
per step (NumPy calls on small arrays, the solver's bookkeeping), which dominates the cost of a
step with few contacts or easy contact problems. For a constant system (constant mass matrix and
kinematics, affine time-independent forces) every operator of the step is a fixed matrix, and the
whole loop runs as one numba function (:mod:`lcp.timestepping.compiled_kernels`, whose docstring
lists what a step computes). This module holds the rest of that path: whether it applies
(:func:`applicable`), the operators packed into the kernel's arrays once per (system, h, theta)
(CSR/CSC arrays, the LU factors, W interleaved contact by contact), the steps handed to Python, and
the result (:func:`moreau_jean_loop`). Imports the kernels, the contact step's fallback rule and
the outcome's notes of :mod:`lcp.timestepping`, :mod:`lcp.contact` and :mod:`lcp.result`; never the
path choice (:mod:`lcp.timestepping.moreau_jean`), the Python loop or anything above
:mod:`lcp.timestepping`.

Where the kernel's NSGS does not reach the tolerance within its sweeps under ``"auto"`` (two or
more active contacts), the step is first finished by the compiled NSGS-then-Newton of
:func:`lcp.timestepping.planar_multi_kernels.solve_planar` (AutoSolver's algorithm, from zero where
the Python solver warm-starts: the two solves differ within the solver's tolerance, and the branch
refinement below, the same as the Python step's, makes both exact on the branch, so the runs agree
to rounding; counted in ``stats.kernel_multi_steps``, with no note; the bead column's 23 to 198
such steps now cost 0.3-0.4 ms less each, warm: benchmarks/compiled_routes.py). Where that fails
its test, or the compiled step cannot finish otherwise (the closed form finds no admissible case,
or the branch sweeps do not converge), that one step is handed to the Python solver (with the
loop's fallbacks: the same one-step problem, solver object and exact branch refinement) and the
compiled loop resumes after it. Every such step is counted in ``stats.fallbacks`` and named in the
message: no step is silently wrong.

A control schedule on a constant drift with a constant B (``StepAssembly.control_matrix``: a
pushed block, a controlled chain, a pushed body without contact) runs here too, with any number of
contacts: the kernel adds S B int u
over each step (the impulses computed before the run) to the drift's increment, both by NumPy's
products of the assembly's dense matrices (:mod:`lcp.timestepping.control_kernels`), as the Python
loop's ``StepAssembly.at``.

Results equal the Python loop's to rounding (the sums run in another order than BLAS's).
Without numba (:data:`lcp.numerics.jit.HAVE_NUMBA` False) the Python loop runs instead.
"""
from __future__ import annotations

import math
import weakref

import numpy as np

from lcp.contact.problem import MODE_NAMES, ContactProblem, ModeArray
from lcp.contact.solver_base import StepSolution
from lcp.numerics.jit import HAVE_NUMBA, njit
from lcp.timestepping.activation import CLOSE_ULPS, EPS, OPEN_ULPS
from lcp.timestepping.compiled_kernels import (BRANCH_MAX_SWEEPS, BUFFER_FULL, DONE, NONFINITE,
                                               run_steps)
from lcp.timestepping.contact_step import count_solve, retry_with_fallback
from lcp.timestepping.outcome import ambiguity_note, free_velocity_overflows, nonfinite_message
from lcp.timestepping.projection import violation_function
from lcp.result import STATUS_MESSAGES, Impact, SimulationResult, SolverStats

__all__ = ["AUTO_MAX_SWEEPS", "BRANCH_MAX_SWEEPS", "applicable", "control_arrays", "free_velocity_data", "moreau_jean_loop",
           "operator_arrays"]

#: NSGS sweeps of ``"auto"`` in the compiled step before the step goes to the Python solver
#: (NSGS then semismooth Newton), which handles slowly converging problems better
AUTO_MAX_SWEEPS = 500

#: the message of a step whose stopped sweeps the compiled Newton finish solved
NEWTON_MESSAGE = "compiled NSGS-Newton"


def applicable(asm, solver, options) -> bool:
    """Whether the compiled loop runs this simulation: numba installed; a constant planar system
    (affine time-independent forces, no control schedule) with at least two contacts, or a
    controlled constant one (a control schedule on a constant drift with a constant B:
    ``asm.control_matrix``) with any number of contacts (none: the kernel's free steps alone, the
    same arithmetic as the Python loop's), or a constant one without contact (a dense S or a
    constant increment: the Python loop's products, :func:`control_arrays`), or with one contact
    under ``"nsgs"`` (the Python loop's to rounding, as with several); the solver ``"auto"`` or
    ``"nsgs"`` (as a name or as a plain instance) without an ``error_tol``."""
    from lcp.contact.solvers import AutoSolver, NsgsSolver

    sys_ = asm.sys
    controlled = getattr(asm, "control_matrix", None) is not None
    one_nsgs = sys_.n_contacts == 1 and type(solver) is NsgsSolver  # "auto" has the compiled step's closed form
    if not (HAVE_NUMBA and (controlled or sys_.n_contacts != 1 or one_nsgs) and not sys_.is_spatial
            and asm.matrices_constant and (controlled or (sys_.is_constant and asm.schedule is None))):
        return False
    if sys_.n_contacts == 0 and not controlled and not (asm.dv_const is not None or isinstance(asm.S, np.ndarray)):
        return False  # no contact, a sparse S: the CSR sums would not be the Python loop's bits
    if type(solver) is AutoSolver:
        return solver.iterative.error_tol is None
    if type(solver) is NsgsSolver:
        return solver.error_tol is None and solver.compiled
    return False


def newton_params(solver):
    """(largest count, NSGS sweeps, Newton iterations, rounds) of the plain ``"auto"`` solver's
    NewtonSolver (compiled sweeps, no error target, the same residual_tol), for the steps whose
    compiled sweeps did not converge (:func:`lcp.timestepping.planar_multi_kernels.solve_planar`);
    None for any other solver (the Python solver takes those steps)."""
    from lcp.contact.solvers import AutoSolver, NewtonSolver

    if type(solver) is not AutoSolver or solver.error_tol is not None:
        return None
    it = solver.iterative
    if (type(it) is not NewtonSolver or not it.compiled or it.error_tol is not None
            or it.residual_tol != solver.residual_tol):
        return None
    return np.array([0, it.sweeps, it.newton_iter, it.max_rounds], dtype=np.int64)


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


def _unused_fv():
    z = np.zeros(0)
    e0 = _empty_csr(0)
    lu0 = (*e0, z, *e0, z, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    return (z, *e0, *e0, *e0, *e0, *lu0, *e0, *e0, z)


def free_velocity_data(asm):
    """(mode, fv): how the kernels compute the free velocity of a constant system (mode 0: a
    constant increment; 1: affine through S; 2: through the LU factors of the sparse W_h) and the
    tuple of arrays :func:`lcp.timestepping.compiled_kernels.free_velocity` reads. Shared by the
    planar and the spatial compiled loops."""
    n, h, th = asm.n, float(asm.h), float(asm.theta)
    if asm.dv_const is not None:  # the kernels never write to the unused (empty) members: shared
        return 0, (np.asarray(asm.dv_const, dtype=float).ravel(), *_UNUSED_FV)
    z = np.zeros(0)
    e0 = _empty_csr(0)
    lu0 = (*e0, z, *e0, z, np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64))
    Kq, Cv = asm.Kq, asm.Cv
    hK = asm._hhK if asm.sparse else ((h * h) * th) * Kq
    if asm.sparse and asm._lu is not None:
        mode, S, lu = 2, e0, _lu_parts(asm._lu, n)
    else:
        mode, S, lu = 1, _csr(asm.S), lu0
    nb = asm.T.shape[1]
    Tc = _csr(asm.T) if nb else _empty_csr(n)
    Gc = _csr(asm.G) if nb else e0
    return mode, (z, np.asarray(asm.F0, dtype=float).ravel(), *_csr(Kq), *_csr(Cv), *_csr(hK), *S, *lu, *Tc, *Gc,
                  np.asarray(asm.phi_t, dtype=float).ravel() if nb else z)


_UNUSED_FV = _unused_fv()  # the free-velocity tuple's members beyond the constant increment (mode 0)


def operator_arrays(asm):
    """The compressed arrays of H (CSR), S H' (CSC) and W (CSR) of a constant assembly: read from
    :attr:`StepAssembly.arrays` for independent bodies (no SciPy matrix built), else converted."""
    arrays = getattr(asm, "arrays", None)
    if arrays is not None:
        return arrays["H"], arrays["SHt_csc"], arrays["W"]
    return _csr(asm.H), _csc(asm.SHt), _csr(asm.W)


def control_arrays(asm, n_steps):
    """(dense operators, the control's impulse over each step k, (n_steps, nu)) of a controlled
    constant system (``asm.control_matrix``), or (None, None). The operators are B, S, Kq, Cv,
    h^2 theta Kq, T, G, F0 and phi_t of the assembly, C-ordered (Kq and Cv empty where the drift's
    force is constant; all but B empty where S is sparse), for the kernel's NumPy products; the
    impulses are ``StepAssembly.control_increment``'s, elementwise on all steps at once (the same
    bits)."""
    B = getattr(asm, "control_matrix", None)
    h, th = float(asm.h), float(asm.theta)
    if B is None:
        if not (asm.m == 0 and asm.dv_const is None and isinstance(asm.S, np.ndarray)):
            return None, None
        # a constant system without contact or control: the same dense products with no control
        # column, so that its steps are the Python loop's bits (the CSR sums are not BLAS's)
        B, imp = np.zeros((asm.n, 0)), np.zeros((n_steps, 0))
    else:
        t = np.arange(n_steps) * h
        sch = asm.schedule
        imp = np.ascontiguousarray(sch.integral(t + h) - sch.integral(t), dtype=float)
    e2, e1 = np.zeros((0, 0)), np.zeros(0)

    def dense(X):
        return np.ascontiguousarray(X, dtype=float)

    B = dense(B)
    if not isinstance(asm.S, np.ndarray):
        return (B, e2, e2, e2, e2, e2, e2, e1, e1), imp
    Kq, Cv = (e2, e2) if asm.force_constant else (dense(asm.Kq), dense(asm.Cv))
    nb = asm.T.shape[1]
    return (B, dense(asm.S), Kq, Cv, dense(((h * h) * th) * asm.Kq), dense(asm.T) if nb else e2,
            dense(asm.G) if nb else e2, dense(asm.F0).ravel(), dense(asm.phi_t).ravel() if nb else e1), imp


def _pack_new(asm):
    m = asm.m
    mode, fv = free_velocity_data(asm)
    (Hp, Hi, Hx), SHtc, Wc = operator_arrays(asm)
    Wp, Wi, Wx, blocks, rho = _interleave_compiled(*Wc, m)
    end = Hp[m]  # |H_N|: the leading m rows of H's CSR arrays
    gap0 = np.asarray(asm.gap0, dtype=float).ravel()
    sysm = asm.sys
    ct = (Hp, Hi, Hx, Hp[:m + 1].copy(), Hi[:end].copy(), np.abs(Hx[:end]), np.abs(gap0), gap0, *SHtc,
          Wp, Wi, Wx, blocks, rho, np.asarray(sysm.mu, dtype=float), np.asarray(sysm.e, dtype=float))
    # no operator entry couples two contacts: one sweep solves every local problem exactly
    blockdiag = bool(np.all(Wi // 2 == np.repeat(np.arange(Wp.size - 1) // 2, np.diff(Wp))))
    return mode, fv, ct, blockdiag


# ----------------------------------------------------------------------------- the Python side
class _PythonStep:
    """One step solved by the Python solver (with the loop's fallback and exact branch refinement)."""

    def __init__(self, asm, solver, fallback):
        self.asm, self.solver, self.fallback = asm, solver, fallback
        self.cache, self.fallbacks = {}, {}
        self.newton = newton_params(solver)
        self.newton_steps = 0

    def _compiled_newton(self, pb, stats):
        """The step's problem (two or more contacts) solved by the compiled NSGS-then-Newton of
        :func:`lcp.timestepping.planar_multi_kernels.solve_planar` (AutoSolver's algorithm, from
        zero), or None where it does not apply or fails its test (the Python solver then takes it)."""
        if self.newton is None or pb.k < 2:
            return None
        from lcp.timestepping.planar_multi_kernels import solve_planar

        W = pb.W.toarray() if hasattr(pb.W, "toarray") else pb.W
        ok, p, its, res = solve_planar(np.ascontiguousarray(W, dtype=float), np.ascontiguousarray(pb.q, dtype=float),
                                       np.ascontiguousarray(pb.mu, dtype=float), float(self.solver.residual_tol),
                                       self.newton)
        if not ok:
            return None
        self.newton_steps += 1
        sol = StepSolution(p, 0, NEWTON_MESSAGE, int(its), 0, float(res))
        count_solve(stats, sol)
        return sol

    def solve(self, k, q, v, active, qa, stats, newton=False):
        """(p, modes, sol, fallback name or None) of step k; p is None when every solver failed.
        ``newton``: try the compiled Newton finish first (the kernel's sweeps stopped)."""
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
        sol = self._compiled_newton(pb, stats) if newton else None
        if sol is not None:
            stats.max_residual = max(stats.max_residual, sol.residual)
            return self._finish(v, pb, sol.p, active, H, SHta, Ha, dvf) + (sol, None)
        sol = solver.solve(pb)
        count_solve(stats, sol)
        used = None
        if not sol.success:
            sol, used, _ = retry_with_fallback(solver, pb, sol, active.size, self.fallback, self.fallbacks)
        if not sol.success:
            return None, None, sol, None
        if sol.message.startswith("fallback"):
            used = used or "lemke"
        stats.ambiguous_steps += int(sol.ambiguous)
        stats.max_residual = max(stats.max_residual, sol.residual)
        return self._finish(v, pb, sol.p, active, H, SHta, Ha, dvf) + (sol, used)

    def _finish(self, v, pb, p, active, H, SHta, Ha, dvf):
        """(p refined on the branch of its modes, the modes), the Python loop's arithmetic."""
        m = self.asm.m
        md = pb.modes(p)
        dv = dvf + SHta @ p
        r = Ha @ (v + dv)
        e = self.asm.sys.e[active]
        if np.any(e):
            r[: active.size] += e * np.minimum(H[:m][active] @ v, 0.0)
        dp = pb.with_q(r).solve_branch(md)
        if dp is not None and math.isfinite(float(dp.sum())):
            p = p + dp
        return p, md


def moreau_jean_loop(asm, q0, v0, n_steps: int, every: int, solver, fallback: bool,
                     compiled: bool = True) -> SimulationResult:
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
    kernel = run_steps if compiled else getattr(run_steps, "py_func", run_steps)
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
    close_tol, open_tol = CLOSE_ULPS * EPS, OPEN_ULPS * EPS
    stats = SolverStats()
    status, message = 0, STATUS_MESSAGES[0]
    py = _PythonStep(asm, solver, fallback)
    handed, first_hand, n_fb, first_fb = 0, None, 0, None
    cB, imp = control_arrays(asm, n_steps)
    k, forced = 0, False
    while True:
        k, reason = kernel(k, n_steps, every, mode, fv, ct, h, th, close_tol, open_tol, res_tol, max_sweeps,
                           use_enum, blockdiag, q, v, cq, cv, loaded, r, istate, fstate, Q, V, PN, PT, MD, imp_t, imp_j, imp_p,
                           act, qa, forced, fp, fmd, cB, imp)
        forced = False
        if reason == DONE:
            break
        if reason == BUFFER_FULL:
            c = imp_t.size
            imp_t = np.concatenate([imp_t, np.empty(c)])
            imp_j = np.concatenate([imp_j, np.empty(c, dtype=np.int64)])
            imp_p = np.concatenate([imp_p, np.empty((c, 2))])
            continue
        if reason == NONFINITE:
            status, message = -2, f"{STATUS_MESSAGES[-2]} Step {k} (t = {k * h:.10g})."
            break
        # the compiled step could not finish: the Python solver takes this step
        if free_velocity_overflows(v + asm.at(k * h, q, v)[0]):  # as the Python loop: no solver for infinities
            status, message = -2, nonfinite_message(k, h)
            break
        na = int(istate[13])
        active = act[:na].copy()
        its = int(istate[12])
        why = (f"branch refinement sweeps did not converge after {BRANCH_MAX_SWEEPS} sweeps" if its < 0 else
               f"compiled NSGS stopped after {its} sweeps (residual {fstate[1]:.3g})" if not (use_enum and na == 1)
               else "closed form: no admissible case")
        # where NSGS stopped, the compiled Newton finish first (AutoSolver's algorithm; steps counted
        # in stats.kernel_multi_steps), the Python solver where it fails
        p, md, sol, used = py.solve(k, q, v, active, qa[:2 * na].copy(), stats, newton=its >= 0 and na >= 2)
        if p is None:
            status = -1
            message = f"{STATUS_MESSAGES[-1]} Step {k} (t = {k * h:.10g}), solver '{solver.name}': {sol.message}"
            break
        if sol.message != NEWTON_MESSAGE:
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
    stats.kernel_multi_steps = py.newton_steps
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
