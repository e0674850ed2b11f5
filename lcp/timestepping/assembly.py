"""The per-step assembly of Moreau-Jean: free velocity, Delassus operator and contact Jacobian.

Shared by the time-stepping loop (:mod:`lcp.timestepping`) and the batch path (:mod:`lcp.sweeps.batch`).
"""
from __future__ import annotations

import weakref

import casadi as ca
import numpy as np
from lcp.timestepping.force_check import ForceStepCheck, nonfinite_cause
from lcp.numerics.lazy import sparse as sp
from lcp.numerics.block_diagonal import block_inverse
from lcp.numerics.casadi_eval import evaluate_into, evaluate_kept

__all__ = ["StepAssembly", "kahan_add", "one_step_fn", "SPARSE_MIN_CONTACT_ROWS", "SPARSE_DROP_TOL"]

#: constant systems with at least this many contact rows (2 per contact) are assembled sparsely
SPARSE_MIN_CONTACT_ROWS = 200
#: relative size below which an entry of S H' is dropped in the sparse assembly (rounding level)
SPARSE_DROP_TOL = 1e-18


class StepAssembly:
    """The data of one Moreau-Jean step, built once when it is constant.

    For a state (t, q, v) at the start of a step of size h, the theta-method's velocity update with
    the bilateral constraints eliminated is

        v+ = v_free + S H' p,    u = H v+ = W p + H v_free,    W = H S H',

    where p stacks the contact impulses ``[p_N, p_T]`` and u the local velocities; :meth:`at`
    returns ``(v_free - v, S H', W, gaps, H)``. When the mass matrix and the contact and constraint
    kinematics are constant and the forces affine (``matrices_constant``), S, W and H are computed
    once here and only the forces are evaluated per step; when moreover nothing depends on time or
    on the state, the free-velocity increment itself is a constant. Otherwise every call evaluates
    :func:`one_step_fn`. Time stepping and the batch path share this object.

    Parameters
    ----------
    system : lcp.model.system.System
    h : float
        Step size.
    theta : float
        Theta of the theta-method, in [1/2, 1].

    Examples
    --------
    >>> import numpy as np, lcp
    >>> from lcp.timestepping.assembly import StepAssembly
    >>> scene = lcp.scenes.jean_pratt()
    >>> asm = StepAssembly(scene.system, h=1e-3, theta=0.5)
    >>> dv, SHt, W, gap, H = asm.at(0.0, np.zeros(2), np.array([1.0, 0.0]))
    >>> W.shape, asm.matrices_constant
    ((2, 2), True)
    """

    def __init__(self, system, h: float, theta: float):
        if getattr(system, "is_controlled", False):
            raise ValueError("the system has a control input: give a control schedule (control=..., or "
                             "system.with_control(schedule))")
        self.sys, self.h, self.theta = system, h, theta
        # a control schedule's impulse over each step is integrated exactly (see _control_correction)
        self.schedule = getattr(system, "control_schedule", None)
        self.n, self.m = system.n, system.n_contacts
        self.rows = system.n_contact_rows  # m normal rows, then the tangent rows (one or two per contact)
        self.constant = system.is_constant
        self.dv_const = None
        # the matrices (S, W, ...) are constant also when only an additive F(t) varies: then the
        # forces are evaluated per step and nothing else is rebuilt
        self.matrices_constant = (system.mass_is_constant and system.kinematics_is_constant
                                  and system.force_is_affine)
        # forces not affine in (q, v): each step's linearisation is checked at the next
        # (lcp.timestepping.force_check); a control schedule's forces are integrated exactly instead
        self.force_check = (ForceStepCheck(system, h) if not system.force_is_affine and self.schedule is None
                            else None)
        # many contacts, no bilateral constraints: assemble sparsely (memory grows with nnz(W))
        self.sparse = (self.matrices_constant and self.rows >= SPARSE_MIN_CONTACT_ROWS
                       and system.n_bilateral == 0)
        if self.sparse:
            self._init_sparse(h, theta)
        elif self.matrices_constant:
            self._init_constant(h, theta)
            self.force_constant = not system.force_depends_on_state
            # constant forces, no springs, no bilateral constraints: the free velocity increment
            # itself is constant
            self.dv_const = (self.S @ (h * self.F0) if self.constant and self.force_constant
                             and not self.Kq.any() and not self.T.shape[1] else None)
        # a scheduled control on a constant drift with a constant B (a pushed block, a controlled
        # chain): the drift's constant arithmetic plus S B int u over the step (see control_increment)
        self.control_matrix = (_constant_control(system) if self.matrices_constant and self.schedule is not None
                               else None)
        if self.control_matrix is not None:
            # a control constant in time (one piece) makes a constant system too: stepped the same way
            self.dv_const = None
            drift = system.control_drift
            self.F0 = drift.force(np.zeros(getattr(drift, "n_q", self.n)), np.zeros(self.n))
            self.force_constant = not drift.force_depends_on_state

    def _init_constant(self, h, th):
        """The constant data of a small system: the system's step data at (0, 0, 0), then S, T,
        S H' and W from :func:`_constant_core` (the operations of :func:`one_step_function`, so the
        same numbers to the last bit, without building that function for every system). Both
        evaluations run on NumPy buffers: converting arguments and results to CasADi matrices
        would cost more than the evaluations."""
        sys_, n, nb, m = self.sys, self.n, self.sys.n_bilateral, self.m
        fn = sys_.step_data_fn
        core, offsets, layout = _constant_core(sys_)
        # the nonzeros of A, F, K, C, G, phi_t, gap, H, then h and theta: the core's one argument
        data = np.empty(offsets[-1] + 2)
        data[-2:] = h, th
        evaluate_into(fn, [None, None, None], [data[offsets[i]:offsets[i + 1]] for i in range(8)])  # at (0, 0, 0)
        #: the mass matrix's nonzeros (CasADi's order): the state check of a constant system reads them
        self.mass_nonzeros = data[:offsets[1]]
        out = np.empty(layout[-1][0] + layout[-1][1] * layout[-1][2])
        evaluate_kept(core, [data], [out])  # the core is shared by every system of this structure
        # dense results, column-major as CasADi writes them: transposed copies of (columns, rows)
        S, T, SHt, W, F, K, C, G, phi_t, gap, H = (out[a:a + nr * nc].reshape(nc, nr).T for a, nr, nc in layout)
        if not (np.isfinite(S).all() and np.isfinite(F).all()):
            raise FloatingPointError("singular iteration matrix: the mass matrix is singular on the "
                                     "constraint manifold")
        self.S, self.T, self.SHt, self.W, self.H = S.copy(), T.copy(), SHt.copy(), W.copy(), H.copy()
        self.gap0 = gap.reshape(m)  # gaps are affine here: g(q) = g(0) + H_N q
        self.F0 = F.reshape(n)
        # F = F0 + Kq q + Cv v (affine, no t); C order, as every array here: NumPy's products of a
        # transposed view may round differently
        self.Kq, self.Cv = -np.ascontiguousarray(K), -np.ascontiguousarray(C)
        self.G, self.phi_t = G.copy(), phi_t.reshape(nb)

    def _init_sparse(self, h, th):
        """The constant data of a large system, sparse: W_h = A + h theta C + (h theta)^2 K is
        factorized once (SuperLU), S is applied through the factors, and S H' and W = H S H' are
        kept sparse. Entries of S H' below ``SPARSE_DROP_TOL`` times its largest entry are dropped:
        for springs between neighbours they decay geometrically away from the contact (ratio about
        (h theta)^2 k / m), so the operator is banded to rounding level. Independent bodies (W_h
        block diagonal with small blocks) skip SuperLU: S is W_h's block inverse, sparse itself."""
        from scipy.sparse.linalg import LinearOperator, splu

        sys_, n, m = self.sys, self.n, self.m
        # the mass check found A's blocks already; with no damping or stiffness they are W_h's, and
        # A itself is not needed (each SciPy matrix built costs tens of microseconds on a fresh system)
        blocks = sys_.mass_blocks
        A, K, C, Hccs, gap, F0 = _sparse_step_data(sys_, need_mass=blocks is None)
        if blocks is not None and K is None and C is None and _have_numba():
            return self._init_blocks(h, blocks, Hccs, gap, F0)
        Hc, Hrow, Hv = Hccs
        H = sp.csc_matrix((Hv, Hrow, Hc), shape=(self.rows, n))
        H.eliminate_zeros()
        if K is not None or C is not None:
            blocks = None
            if A is None:
                A = sys_.sparse_mass(np.zeros(n))
        Wh = A
        if C is not None:
            Wh = Wh + (h * th) * C
        if K is not None:
            Wh = Wh + (h * th) ** 2 * K
        try:
            Sblk = block_inverse(Wh, blocks)
        except np.linalg.LinAlgError:
            raise FloatingPointError("singular iteration matrix: a block of the mass matrix is singular") from None
        if Sblk is not None:
            # independent bodies: S is block diagonal and sparse, S H' a sparse product (SuperLU's
            # dense-column solves would cost 0.4 ms a column); H' of the CSC H is CSR, no conversion
            self._lu, self.S, self._solve = None, Sblk, Sblk.dot
            SHt = Sblk @ H.T
            SHt.eliminate_zeros()
        else:
            Ht = H.T.tocsc()
            try:
                lu = splu(Wh.tocsc())
            except RuntimeError as exc:
                raise FloatingPointError(f"singular iteration matrix: {exc}") from None
            self._lu, self._solve = lu, lu.solve
            self.S = LinearOperator((n, n), matvec=lu.solve, dtype=float)
            cols = []
            for a in range(0, self.rows, 512):  # column blocks keep the dense intermediate small
                X = lu.solve(Ht[:, a:a + 512].toarray())
                big = np.max(np.abs(X)) if X.size else 0.0
                X[np.abs(X) <= SPARSE_DROP_TOL * big] = 0.0
                cols.append(sp.csc_matrix(X))
            SHt = sp.hstack(cols).tocsr() if cols else sp.csr_matrix((n, 0))
        self.T = np.zeros((n, 0))
        if not np.all(np.isfinite(SHt.data)):
            raise FloatingPointError("singular iteration matrix: the mass matrix is singular")
        Hr = H.tocsr()
        self.SHt, self.H = SHt, _LeadingRows(Hr, m)
        self.W = (Hr @ SHt).tocsr()
        self.gap0 = gap
        self.F0 = F0
        # no stiffness or damping (the common case): one empty matrix for all three
        zero = _empty_csr(n) if K is None or C is None else None
        self.Kq = -K.tocsr() if K is not None else zero
        self.Cv = -C.tocsr() if C is not None else zero
        self._hhK = (h * h * th) * self.Kq if K is not None else zero
        self.G, self.phi_t = np.zeros((0, n)), np.zeros(0)
        self.force_constant = not sys_.force_depends_on_state
        self.dv_const = (self._solve(h * self.F0) if self.constant and self.force_constant and not self.Kq.nnz
                         else None)

    def _init_blocks(self, h, blocks, H, gap, F0):
        """The constant data of independent bodies without springs or dampers (W_h = A, block
        diagonal), computed by :mod:`lcp.numerics.block_products` on compressed arrays: the same numbers as
        :meth:`_init_sparse`'s SciPy route, to the last bit. The SciPy matrices (S, S H', W, H)
        are built on first use only; the compiled loop reads :attr:`arrays` instead."""
        from lcp.numerics.block_diagonal import block_inverse_arrays
        from lcp.numerics.block_products import block_products, csr_matvec

        n, m, rows = self.n, self.m, self.rows
        try:
            Sx, Si, Sp = block_inverse_arrays(blocks, n)
        except np.linalg.LinAlgError:
            raise FloatingPointError("singular iteration matrix: a block of the mass matrix is singular") from None
        Hc, Hrow, Hv = H
        Hcsr, SHt, W, SHt_csc = block_products(n, rows, Sp, Si, Sx, Hc, Hrow, np.asarray(Hv, dtype=float))
        if not np.all(np.isfinite(SHt[2])):
            raise FloatingPointError("singular iteration matrix: the mass matrix is singular")
        #: compressed arrays (pointers, indices, values) of H and W (CSR) and S H' (CSC)
        self.arrays = {"H": Hcsr, "W": W, "SHt_csc": SHt_csc}
        self._lu = None
        self.T = np.zeros((n, 0))
        self.gap0, self.F0 = gap, F0
        zero = _empty_csr(n)
        self.Kq = self.Cv = self._hhK = zero
        self.G, self.phi_t = np.zeros((0, n)), np.zeros(0)
        self.force_constant = not self.sys.force_depends_on_state
        self._solve = lambda x: csr_matvec(Sp, Si, Sx, np.ascontiguousarray(x, dtype=float))
        self.dv_const = self._solve(h * self.F0) if self.constant and self.force_constant else None
        csr = sp.csr_matrix
        self._lazy = {
            "S": lambda: csr((Sx, Si, Sp), shape=(n, n)),
            "SHt": lambda: csr((SHt[2], SHt[1], SHt[0]), shape=(n, rows)),
            "W": lambda: csr((W[2], W[1], W[0]), shape=(rows, rows)),
            "H": lambda: _LeadingRows(csr((Hcsr[2], Hcsr[1], Hcsr[0]), shape=(rows, n)), m),
        }

    def __getattr__(self, name):
        # the SciPy matrices of _init_blocks, built on first use
        lazy = self.__dict__.get("_lazy")
        if lazy is not None and name in lazy:
            value = lazy.pop(name)()
            setattr(self, name, value)
            return value
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def _eval(self, t, q, v):
        """CasADi's one-step data (System.one_step_fn) as NumPy arrays, checked."""
        n, r = self.n, self.rows
        out = one_step_fn(self.sys)(t, q, v, self.h, self.theta)
        vfree, S, T, SHt, W, gap, H = (np.array(x, dtype=float) for x in out)
        if not (np.all(np.isfinite(S)) and np.all(np.isfinite(vfree))):
            raise FloatingPointError(nonfinite_cause(self.sys, self.h, t, q, v, S))
        return (vfree.ravel(), S.reshape(n, n), T.reshape(n, -1), SHt.reshape(n, r),
                W.reshape(r, r), gap.ravel(), H.reshape(r, n))

    def at(self, t, q, v):
        """(v_free - v, SHt, W, gap, H) at the start of a step from (t, q, v)."""
        if self.sparse and self.schedule is None:
            return self._at_sparse(t, q, v)
        if self.dv_const is not None:
            return self.dv_const, self.SHt, self.W, self.gap0 + self.H[: self.m] @ q, self.H
        if self.matrices_constant:
            h, th = self.h, self.theta
            if self.constant or self.control_matrix is not None:  # affine, time-independent (the drift's)
                Fth = self.F0 if self.force_constant else self.F0 + self.Kq @ q + self.Cv @ v
            else:  # an additive F(t): only the forces are evaluated per step
                f = self.sys.force_fn
                Fth = ((1 - th) * np.array(f(t, q, v), dtype=float).ravel()
                       + th * np.array(f(t + h, q, v), dtype=float).ravel())
            # the theta-weighted force, linearized exactly (as in one_step_function)
            dv = self.S @ (h * Fth + h * h * th * self.Kq @ v)
            if self.T.shape[1]:
                dv = dv + self.T @ (-self.phi_t - self.G @ v)
            if self.control_matrix is not None:
                dv = dv + self.S @ self.control_increment(t)
            elif self.schedule is not None:
                dv = dv + self._control_correction(t, q, self.S)
            return dv, self.SHt, self.W, self.gap0 + self.H[: self.m] @ q, self.H
        vfree, S, _, SHt, W, gap, H = self._eval(t, q, v)
        if self.force_check is not None:
            self.force_check(t, q, v)
        dv = vfree - v
        if self.schedule is not None:
            dv = dv + self._control_correction(t, q, S)
        return dv, SHt, W, gap, H

    def _at_sparse(self, t, q, v):
        """:meth:`at` of the sparse assembly: the factors of W_h instead of S, no matrix rebuilt."""
        gap = self.gap0 + self.H[: self.m] @ q
        if self.dv_const is not None:
            return self.dv_const, self.SHt, self.W, gap, self.H
        h, th = self.h, self.theta
        if self.constant:
            Fth = self.F0 if self.force_constant else self.F0 + self.Kq @ q + self.Cv @ v
        else:
            f = self.sys.force_fn
            Fth = ((1 - th) * np.array(f(t, q, v), dtype=float).ravel()
                   + th * np.array(f(t + h, q, v), dtype=float).ravel())
        dv = self._solve(h * Fth + self._hhK @ v)
        return dv, self.SHt, self.W, gap, self.H

    def control_increment(self, t):
        """B int_t^{t+h} u ds of a constant B (``control_matrix``): the control's exact impulse over
        the step, added to the drift's free velocity through S (the compiled loop adds the same)."""
        return self.control_matrix @ self.schedule.impulse(t, t + self.h)

    def _control_correction(self, t, q, S):
        """Replace the theta-weighted control force by the control's exact impulse over the step.

        The theta-method sees h ((1 - theta) B u(t) + theta B u(t + h)); for a piecewise-constant
        control evaluated at a breakpoint t + h that is the next piece's value, which would average
        neighbouring pieces. The step's velocity increment gets instead S B(t, q) int_t^{t+h} u ds:
        u_k h for a constant hold, the trapezoid for a linear hold, exact for any step placement.
        """
        h, th = self.h, self.theta
        cf = self.sys.control_force_fn
        seen = h * ((1 - th) * np.array(cf(t, q), dtype=float).ravel()
                    + th * np.array(cf(t + h, q), dtype=float).ravel())
        B = np.array(self.sys.control_matrix_fn(t, q), dtype=float).reshape(self.n, -1)
        return S @ (B @ self.schedule.impulse(t, t + h) - seen)


def _constant_control(system):
    """B as an (n, nu) array where a scheduled system's drift F0 is constant (constant mass and
    kinematics, affine time-independent forces: ``control_drift.is_constant``) and B(t, q) does not
    depend on t or q; else None."""
    drift = getattr(system, "control_drift", None)
    fn = getattr(system, "control_matrix_fn", None)
    if drift is None or fn is None or not drift.is_constant or fn.sparsity_jac(0, 0).nnz() or fn.sparsity_jac(1, 0).nnz():
        return None
    return np.array(fn(0.0, np.zeros(fn.size1_in(1))), dtype=float).reshape(system.n, -1)


def _sparse_step_data(system, need_mass: bool = True):
    """(A, K, C, H, gap, F) of a system with constant matrices at (0, 0, 0): A, K = -dF/dq and
    C = -dF/dv as SciPy CSC matrices of their nonzeros, H as compressed-column arrays (pointers,
    rows, values; int64, float), the gaps and forces as arrays. K and C are None when all zero (no
    springs, no damping: the usual case), and A is None when not ``need_mass`` (the caller has the
    mass matrix's blocks from the check already).

    Structurally sparse outputs are read straight from :attr:`lcp.model.system.System.step_data_fn`'s
    buffers; a structurally dense one (a mass matrix written as a dense array has n^2 structural
    entries, whose conversion would cost seconds at n = 2000) goes through a Function of the
    symbolically sparsified expressions instead.
    """
    n = system.n
    fn = system.step_data_fn
    parts = (0, 2, 3, 7)
    if sum(fn.nnz_out(i) for i in parts) <= max(4096, (n + system.n_contact_rows) * n // 8):
        sps = [fn.sparsity_out(i) for i in range(8)]
        bufs = [np.empty(x.nnz()) for x in sps]
        z = np.zeros(n)
        evaluate_into(fn, [np.zeros(1), z, z], bufs)
        out = []
        for i in parts:
            if (i == 0 and not need_mass) or (i in (2, 3) and not np.any(bufs[i])):
                out.append(None)  # all zero: no matrix to build (the caller tests for None)
                continue
            colind, row = sps[i].get_ccs()
            if i == 7:
                out.append((np.array(colind, dtype=np.int64), np.array(row, dtype=np.int64), bufs[i]))
                continue
            M = sp.csc_matrix((bufs[i], np.array(row, dtype=np.int32), np.array(colind, dtype=np.int32)),
                              shape=sps[i].shape)
            M.eliminate_zeros()
            out.append(M)
        gap, F = np.zeros(sps[6].numel()), np.zeros(n)
        gap[np.array(sps[6].find(), dtype=np.int64)] = bufs[6]  # structural zeros are zeros
        F[np.array(sps[1].find(), dtype=np.int64)] = bufs[1]
        return (*out, gap, F)
    q_, v_, t_ = system.q_sym, system.v_sym, system.t_sym
    f = ca.Function("sparse_step_data", [t_, q_, v_],
                    [ca.sparsify(system.mass_expr), ca.sparsify(-ca.jacobian(system.force_expr, q_)),
                     ca.sparsify(-ca.jacobian(system.force_expr, v_)), ca.sparsify(system.H_expr), system.gap_expr])
    A, K, C, H, gap = f(0.0, np.zeros(n), np.zeros(n))

    def csc(x):
        r, c = x.sparsity().get_triplet()
        return sp.csc_matrix((np.array(x.nonzeros(), dtype=float), (r, c)), shape=x.shape)

    K, C, H = csc(K), csc(C), csc(H)
    H = (H.indptr.astype(np.int64), H.indices.astype(np.int64), H.data)
    return (csc(A), K if np.any(K.data) else None, C if np.any(C.data) else None, H, np.array(gap, dtype=float).ravel(),
            system.force(np.zeros(n), np.zeros(n)))


def _have_numba() -> bool:
    from lcp.numerics.jit import HAVE_NUMBA

    return HAVE_NUMBA


_EMPTY = {}


def _empty_csr(n):
    """An n x n CSR matrix of no entries, shared by size (read only: it stands for absent springs
    and dampers, and building one costs as much as the rest of a small set-up step)."""
    if n not in _EMPTY:
        if len(_EMPTY) > 64:
            _EMPTY.clear()
        _EMPTY[n] = sp.csr_matrix((n, n))
    return _EMPTY[n]


_LEADING_ROWS = []


def _LeadingRows(A, m):
    """A CSR matrix that keeps its leading row block ``[:m]`` (the normal rows of the contact
    Jacobian, which the stepping loop takes every step) instead of slicing it each time. The class
    derives from scipy.sparse.csr_matrix, so it is defined on first use (SciPy stays unimported
    until a large system needs it)."""
    if not _LEADING_ROWS:
        class LeadingRows(sp.csr_matrix):
            def __init__(self, A, m):
                super().__init__(A)
                self._m = m
                self._lead = None  # sliced on first use (the compiled loop never asks)

            def __getitem__(self, key):
                if (isinstance(key, slice) and key.start in (None, 0) and key.step in (None, 1)
                        and key.stop == self._m):
                    if self._lead is None:
                        self._lead = sp.csr_matrix(sp.csr_matrix(self)[: self._m])
                    return self._lead
                return sp.csr_matrix(self).__getitem__(key)

        _LEADING_ROWS.append(LeadingRows)
    return _LEADING_ROWS[0](A, m)


def kahan_add(s, inc, comp):
    """s + inc by Kahan's compensated sum: returns (new sum, new compensation).

    Works on floats, NumPy arrays and CasADi expressions alike, so that the Python loop, the batch
    path and the compiled step sum positions and velocities the same way (1e6 steps stay at rounding
    level).
    """
    y = inc - comp
    t = s + y
    return t, (t - s) - y


#: the core functions of :func:`_constant_core` by size and numbers of nonzeros, each a list of
#: (sparsity patterns, Function); bounded, so that a sweep over many structures does not grow it
_CORES: dict = {}
_CORES_MAX = 64


def _constant_core(system):
    """The function ``d -> out`` of a system with constant matrices, with the offsets of its
    argument's parts and the layout of its result.

    d stacks the nonzeros of the system's step data (:attr:`lcp.model.system.System.step_data_fn`: A, F,
    K, C, G, phi_t, gap, H), then h and theta (``offsets``: where each part starts, and the end);
    out stacks S, T, S H', W, F, K, C, G, phi_t, gap and H, each dense and column-major (``layout``:
    offset, rows and columns of each). S, T, S H' and W come out of exactly the operations of
    :func:`one_step_function` on inputs of the same sparsity patterns (the linear solve depends on
    them), so that both give the same bits.

    Built once per structure (size and sparsity patterns), not per system: a new system of a known
    structure costs one evaluation, not the construction of a CasADi Function.
    """
    fn = system.step_data_fn
    n, nb = system.n, system.n_bilateral
    # the key narrows the candidates, the patterns decide; each call into CasADi costs a
    # microsecond or two, which a fresh small system pays several times over
    key = (n, nb, system.n_contact_rows, fn.nnz_out())
    sps = [fn.sparsity_out(i) for i in range(8)]
    entries = _CORES.setdefault(key, [])
    for patterns, found in entries:
        if all(a == b for a, b in zip(patterns, sps)):
            return found
    nnz = [x.nnz() for x in sps]
    offsets = np.concatenate([[0], np.cumsum(nnz)]).tolist()
    d = ca.MX.sym("d", offsets[-1] + 2)
    A, F, K, C, G, phi_t, gap, H = (ca.MX(x, d[offsets[i]:offsets[i + 1]]) for i, x in enumerate(sps))
    h, th = d[offsets[-1]], d[offsets[-1] + 1]
    Wh = A + h * th * C + (h * th) ** 2 * K
    KKT = ca.blockcat([[Wh, G.T], [G, ca.MX(nb, nb)]]) if nb else Wh
    X = ca.solve(KKT, ca.MX.eye(n + nb))
    S, T = X[:n, :n], X[:n, n:]
    SHt = ca.mtimes(S, H.T)
    outs = [S, T, SHt, ca.mtimes(H, SHt), F, K, C, G, phi_t, gap, H]
    layout, at = [], 0
    for x in outs:
        layout.append((at, x.shape[0], x.shape[1]))
        at += x.numel()
    core = ca.Function("constant_core", [d], [ca.vertcat(*(ca.vec(ca.densify(x)) for x in outs))])
    if sum(map(len, _CORES.values())) >= _CORES_MAX:
        _CORES.clear()
        entries = _CORES.setdefault(key, [])
    found = (core, offsets, layout)
    entries.append((sps, found))
    return found


def one_step_function(system) -> ca.Function:
    """The data of one Moreau-Jean step of ``system`` as one CasADi Function.

    ``one_step(t, q, v, h, theta) -> (v_free, S, T, SHt, W, gap, H)``, where the theta-method's
    velocity update with bilateral constraints eliminated is

        [W_h G'; G 0] [dv; lambda] = [r; c],   W_h = A + h theta C + (h theta)^2 K,
        r = h ((1 - theta) F(t, q, v) + theta F(t + h, q, v)) - h^2 theta K v,
        c = -phi_t(t + h, q) - G v,

    so that dv = S r + T c; ``v_free = v + dv`` is the velocity without contact impulses,
    ``SHt = S H'`` maps contact impulses to velocity, and ``W = H S H'`` is the Delassus operator
    of the local velocities u = W p + H v_free. :func:`one_step_fn` builds it
    once per system.
    """
    n, nb = system.n, system.n_bilateral
    t, h, th = ca.MX.sym("t"), ca.MX.sym("h"), ca.MX.sym("theta")
    q, v = ca.MX.sym("q", getattr(system, "n_q", n)), ca.MX.sym("v", n)  # n_q != n with kinematics
    A, F, K, C, G, _, gap, H = system.step_data_fn(t, q, v)
    F1 = system.force_fn(t + h, q, v)
    _, _, phi_t1 = system.constraints_fn(t + h, q)
    Wh = A + h * th * C + (h * th) ** 2 * K
    KKT = ca.blockcat([[Wh, G.T], [G, ca.MX(nb, nb)]]) if nb else Wh
    X = ca.solve(KKT, ca.MX.eye(n + nb))
    S, T = X[:n, :n], X[:n, n:]
    r = h * ((1 - th) * F + th * F1) - h * h * th * ca.mtimes(K, v)
    dv = ca.mtimes(S, r)
    if nb:
        dv = dv + ca.mtimes(T, -phi_t1 - ca.mtimes(G, v))
    SHt = ca.mtimes(S, H.T)
    return ca.Function("one_step", [t, q, v, h, th], [v + dv, S, T, SHt, ca.mtimes(H, SHt), gap, H],
                       ["t", "q", "v", "h", "theta"], ["v_free", "S", "T", "SHt", "W", "gap", "H"])


#: system -> its one-step Function (weak keys: the Function lives as long as its System)
ONE_STEP_FUNCTIONS = weakref.WeakKeyDictionary()


def one_step_fn(system) -> ca.Function:
    """:func:`one_step_function` of ``system``, built on first use and then reused.

    The cache lives here, not on the System, so that the model knows nothing of the time stepping.
    """
    fn = ONE_STEP_FUNCTIONS.get(system)
    if fn is None:
        fn = ONE_STEP_FUNCTIONS[system] = one_step_function(system)
    return fn
