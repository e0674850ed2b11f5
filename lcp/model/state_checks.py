"""The checks of a system and its start: the mass matrix (symmetric positive definite), the contact rows
(independent), and the symbols its expressions use (the System's own).

:meth:`System.check_state <lcp.model.system.System.check_state>` runs these tests on a start;
they work on the nonzeros CasADi gives (a sparse mass matrix of independent bodies is tested
block by block, never formed dense). Imports :mod:`lcp.numerics` only (the System is passed in).
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from lcp.numerics.casadi_eval import evaluate_into

__all__ = ["check_state", "check_contact_rows", "check_free_symbols", "contact_rows_degenerate", "check_dense_mass", "check_diagonal_mass", "check_sparse_mass", "check_definite", "dense_mass", "mass_ccs_pattern", "mass_ccs_values",
           "null_space", "sparse_mass"]


def check_state(system, q0, v0, t0, mass_nonzeros=None):
    """The body of :meth:`System.check_state <lcp.model.system.System.check_state>` on float arrays
    (``mass_nonzeros``: A's nonzeros in CasADi's order where the mass matrix is constant and the
    caller has them)."""
    for name, x, size in (("q0", q0, getattr(system, "n_q", system.n)), ("v0", v0, system.n)):
        if x.shape != (size,):
            raise ValueError(f"{name} must have shape ({size},), got {x.shape}")
        if not np.isfinite(x).all():
            raise ValueError(f"{name} must be finite, got {x}")
    if system.__dict__.get("_mass_checked_constant"):
        return q0, v0
    if getattr(system, "has_kinematics", False):
        from lcp.model.kinematics import check_kinematics_at

        check_kinematics_at(system, q0, t0)
    if system.n_contacts and not system.contact_rows_checked:
        check_contact_rows(system, q0, t0)  # a constant mass matrix (and constraints) passed the check below once
    if not system.n_bilateral and _structurally_diagonal(system):
        check_diagonal_mass(system, q0, t0, mass_nonzeros if system.mass_is_constant else None)
    elif not system.n_bilateral and system.n > 32 and system.mass_expr.nnz() <= system.n * system.n // 8:
        check_sparse_mass(system, q0, t0)
    else:
        check_dense_mass(system, q0, t0)
    # the check does not depend on the state when nothing in it does: done once (it costs a
    # dense factorization or eigenvalue decomposition)
    system._mass_checked_constant = system.mass_is_constant and system.kinematics_is_constant
    return q0, v0


def check_dense_mass(system, q0, t0) -> None:
    """The test of :meth:`System.check_state <lcp.model.system.System.check_state>` on the dense mass matrix (on the constraint manifold)."""
    A = dense_mass(system, q0, t0)
    if not np.all(np.isfinite(A)):
        raise ValueError("mass matrix is not finite at q0")
    if np.max(np.abs(A - A.T)) > 1e-12 * max(1.0, np.max(np.abs(A))):
        raise ValueError("mass matrix must be symmetric")
    if system.n_bilateral:
        _, G, _ = (np.array(x, dtype=float) for x in system.constraints_fn(t0, q0))
        Z = null_space(G.reshape(system.n_bilateral, system.n))
        A = Z.T @ A @ Z
    As = 0.5 * (A + A.T)
    check_definite([As] if A.size else [], As.shape[0],
                    1e-14 * max(1.0, float(np.max(np.sum(np.abs(As), axis=1), initial=0.0))))

def _structurally_diagonal(system) -> bool:
    """Whether the mass matrix's pattern is its diagonal, every entry present (point masses,
    independent sliders): then the mass check needs no matrix at all."""
    sparsity = system.mass_fn.sparsity_out(0)
    return system.n > 0 and sparsity.nnz() == system.n and sparsity.is_diag()


def check_diagonal_mass(system, q0, t0, data=None) -> None:
    """The test of :meth:`System.check_state <lcp.model.system.System.check_state>` for a mass matrix
    whose pattern is its diagonal, without bilateral constraints: the eigenvalues are the diagonal
    entries themselves, so the dense test's verdict (symmetric by structure, every eigenvalue above
    1e-14 of the largest) is read off them. Each 1 x 1 block has condition number 1, which is kept
    for :func:`lcp.model.conditioning.mass_condition` where the matrix is constant (its blocks,
    too, where the sparse check would keep them), so that no later step analyses A again.
    ``data``: the diagonal already evaluated (a constant A), else it is evaluated at (t0, q0)."""
    if data is None:
        data, _, _ = mass_ccs_values(system, q0, t0)
    if not np.all(np.isfinite(data)):
        raise ValueError("mass matrix is not finite at q0")
    low, top = float(data.min()), float(data.max())
    if low <= 1e-14 * max(1.0, max(-low, top)):
        raise ValueError("mass matrix is singular or not positive definite (on the constraint manifold) "
                         f"at q0: eigenvalues {np.sort(data)}")
    if system.mass_is_constant and system.kinematics_is_constant:
        system._mass_kappa = 1.0
        if system.n > 32:  # as check_sparse_mass: the sparse assembly inverts the blocks
            system.mass_blocks = [(np.arange(system.n).reshape(-1, 1), data.reshape(-1, 1, 1).copy())]


def check_sparse_mass(system, q0, t0) -> None:
    """The test of :meth:`System.check_state <lcp.model.system.System.check_state>` for a sparse mass matrix without bilateral constraints,
    on its nonzeros: where A is block diagonal (up to a permutation) with small blocks, its
    eigenvalues (n <= 200) are those of the blocks and the Cholesky factorization of A - s I
    (larger n) is that of each block (batched), so the dense matrix is never formed and the
    verdicts are the dense test's; otherwise the dense test. A constant mass matrix keeps its
    blocks (``System.mass_blocks``): the sparse assembly inverts them instead of finding them again.
    Everything is read from CasADi's compressed arrays (no SciPy matrix unless the blocks are
    large): on a fresh system the conversions would cost more than the test."""
    from lcp.numerics.block_diagonal import compressed_diagonal_blocks

    n = system.n
    data, row, colind = mass_ccs_values(system, q0, t0)
    if not np.all(np.isfinite(data)):
        raise ValueError("mass matrix is not finite at q0")
    scale = max(1.0, float(np.max(np.abs(data), initial=0.0)))
    # symmetry on the nonzeros: CCS order sorts the keys col * n + row, so each entry's mirror
    # (row * n + col) is found by bisection; a missing mirror is a zero
    col = np.repeat(np.arange(n), np.diff(colind))
    row64 = row.astype(np.int64)  # row * n in int32 would overflow past 46340 coordinates
    keys = col * n + row64
    mkeys = row64 * n + col
    at = np.minimum(np.searchsorted(keys, mkeys), keys.size - 1)
    mirror = np.where(keys[at] == mkeys, data[at], 0.0)
    if np.max(np.abs(data - mirror), initial=0.0) > 1e-12 * scale:
        raise ValueError("mass matrix must be symmetric")
    shift = 1e-14 * max(1.0, float(np.max(np.bincount(row, np.abs(data), minlength=n), initial=0.0)))
    blocks = compressed_diagonal_blocks(n, colind, row, data, True)
    if blocks is None:
        from scipy.sparse import csc_matrix

        A = csc_matrix((data, row, colind), shape=(n, n))
        As = 0.5 * (A + A.T)
        check_definite([As.toarray()], n, shift)
        return
    check_definite([0.5 * (B + B.transpose(0, 2, 1)) for _, B in blocks], n, shift)
    if system.mass_is_constant:
        system.mass_blocks = blocks

def dense_mass(system, q, t) -> np.ndarray:
    """:meth:`System.mass <lcp.model.system.System.mass>` for a validated q, evaluated into NumPy buffers (the check of a fresh small
    system pays CasADi's matrix conversion otherwise)."""
    n = system.n
    sparsity = system.mass_fn.sparsity_out(0)
    data = np.empty(sparsity.nnz())
    evaluate_into(system.mass_fn, [np.array([float(t)]), np.asarray(q, dtype=float)], [data])
    flat = np.zeros(n * n)
    flat[np.array(sparsity.find(), dtype=np.int64)] = data  # column-major positions
    return np.ascontiguousarray(flat.reshape(n, n).T)

def sparse_mass(system, q, t: float = 0.0):
    """The mass matrix A(t, q) as a SciPy CSC matrix of its structural nonzeros (never dense)."""
    from scipy.sparse import csc_matrix

    data, row, colind = mass_ccs_values(system, q, t)
    return csc_matrix((data, row, colind), shape=(system.n, system.n))


def mass_ccs_pattern(system):
    """(CasADi's sparsity of A, row indices, column pointers) of the mass matrix (int32 indices),
    read once per system."""
    sparsity = system.mass_fn.sparsity_out(0)
    if "_mass_ccs" not in system.__dict__:
        colind, row = sparsity.get_ccs()
        system._mass_ccs = (np.array(row, dtype=np.int32), np.array(colind, dtype=np.int32))
    row, colind = system._mass_ccs
    return sparsity, row, colind


def mass_ccs_values(system, q, t):
    """(nonzeros, row indices, column pointers) of A(t, q), CasADi's CCS arrays (int32 indices)."""
    sparsity, row, colind = mass_ccs_pattern(system)
    data = np.empty(sparsity.nnz())
    evaluate_into(system.mass_fn, [np.array([float(t)]), np.asarray(q, dtype=float)], [data])
    return data, row, colind


def check_definite(blocks, size: int, shift: float) -> None:
    """The positive-definiteness test of a symmetric mass matrix of ``size`` rows given as diagonal
    ``blocks`` (arrays (..., k, k); the whole matrix as one block, or none when it is empty), or
    ValueError. Up to 200 rows: the eigenvalues, all above 1e-14 of the largest. Larger: a Cholesky
    factorization of each block minus ``shift`` I, which succeeds iff every eigenvalue exceeds the
    shift; with the shift above 1e-14 of the largest eigenvalue (the infinity norm bounds it) that
    is the same test at a tenth of the cost (seconds for thousands of coordinates)."""
    if size <= 200:
        eigs = [np.linalg.eigvalsh(B) for B in blocks]  # ascending along the last axis
        low = min((float(e[..., 0].min()) for e in eigs if e.size), default=1.0)
        high = max((max(-float(e[..., 0].min()), float(e[..., -1].max())) for e in eigs if e.size), default=1.0)
        if low <= 1e-14 * max(1.0, high):
            eig = np.sort(np.concatenate([e.ravel() for e in eigs]))
            raise ValueError("mass matrix is singular or not positive definite (on the constraint manifold) "
                             f"at q0: eigenvalues {eig}")
        return
    for B in blocks:
        try:
            np.linalg.cholesky(B - shift * np.eye(B.shape[-1]))
        except np.linalg.LinAlgError:
            raise ValueError("mass matrix is singular or not positive definite (on the constraint manifold) "
                             f"at q0: an eigenvalue is below {shift:.3g}") from None


def null_space(G: np.ndarray) -> np.ndarray:
    """Orthonormal basis of the null space of G (for the bilateral constraints)."""
    if G.shape[0] == 0:
        return np.eye(G.shape[1])
    u, s, vt = np.linalg.svd(G)
    rank = int(np.sum(s > 1e-12 * max(1.0, s.max())))
    if rank < G.shape[0]:
        raise ValueError("bilateral constraints are redundant (their Jacobian G is rank deficient)")
    return vt[rank:].T


def contact_rows_degenerate(system, q, j, t: float = 0.0, H=None):
    """(rows [H_N; H_T] of contact j at (t, q), their singular values) if they are dependent there, else None.

    ``H``: the contact Jacobian at (t, q) where the caller has it already (one evaluation for all
    contacts, not one per contact: K contacts of 3K coordinates would cost K dense evaluations)."""
    if H is None:
        H = system.contact_jacobian(q, t)
    m, off = system.n_contacts, system.tangent_offsets
    rows = H[np.r_[j, m + off[j]:m + off[j + 1]]]
    s = np.linalg.svd(rows, compute_uv=False)
    if not np.all(np.isfinite(s)):
        raise ValueError(f"contact {system.contacts[j].name!r}: its Jacobian rows are not finite at q0 = {q}")
    return (rows, s) if s[-1] <= 1e-10 * max(s[0], 1e-300) else None


def check_contact_rows(system, q, t: float = 0.0) -> None:
    """The tangent rows of each contact must be independent of each other and of its normal.

    Checked once, at q0 (anywhere when the kinematics are constant). Where the rows depend on q,
    a configuration can be singular for a contact (a double pendulum hanging straight down has
    a zero normal row for a floor under its tip) while the contact is sound elsewhere; the
    message then says that it is this configuration, by checking one nearby.
    """
    q = np.asarray(q, dtype=float)
    H = system.contact_jacobian(q, t) if system.n_contacts else None
    for j, c in enumerate(system.contacts):
        bad = contact_rows_degenerate(system, q, j, t, H)
        if bad is None:
            continue
        rows, s = bad
        if s[0] == 0:
            what = "its normal and tangent rows are all zero"
        elif np.linalg.norm(rows[0]) <= 1e-10 * s[0]:
            what = "its normal row H_N (the gradient of its gap) is zero"
        else:
            what = (f"its {'tangent rows are' if rows.shape[0] > 2 else 'tangent row is'} not independent "
                    f"of {'each other and of ' if rows.shape[0] > 2 else ''}the normal")
        detail = f"(rows [H_N; H_T] rank deficient, singular values {s})"
        if system.kinematics_is_constant:
            raise ValueError(f"contact {c.name!r}: {what} {detail}; the kinematics are constant, so "
                             "this holds in every configuration")
        # a deterministic nearby configuration: is it q0, or the contact?
        near = q + 1e-3 * (1.0 + np.abs(q)) * np.sin(1.0 + np.arange(q.size))
        if contact_rows_degenerate(system, near, j, t) is None:
            raise ValueError(f"contact {c.name!r}: at q0 = {q} (where the contact rows are checked) "
                             f"{what} {detail}. Only this configuration is singular for the contact: "
                             "at a nearby one the rows are independent. Start from a q0 off it")
        raise ValueError(f"contact {c.name!r}: {what} {detail}, at q0 = {q} (where the contact rows are "
                         "checked) and at a nearby configuration too")
    system.contact_rows_checked = True


def check_free_symbols(system, no_t_given, gap, H, phi_t) -> None:
    """A ValueError naming a symbol that an expression uses but the System does not know (CasADi
    would only say "variables [t] are free ... set option 'allow_free'"), typically a time
    symbol not passed as ``t=``."""
    known = [system.t_sym, system.q_sym, system.v_sym]
    if system.control_sym is not None:
        known.append(system.control_sym)
    known = ca.vertcat(*known)
    parts = [("mass", system.mass_expr), ("force", getattr(system, "controlled_force_expr", system.force_expr)),
             ("constraints", system.constraints_expr), ("constraints' time derivative", phi_t),
             ("contact gaps", gap), ("contact Jacobian", H)]
    for label, expr in parts:
        free = [str(x) for x in ca.symvar(expr) if not ca.depends_on(x, known)]
        if not free:
            continue
        one = len(free) == 1
        names = ", ".join(repr(f) for f in free)
        cand = next((f for f in free if f.lower() in ("t", "time")), free[0])
        if no_t_given:
            time = (f"if {cand!r} is the time, pass it to System as t={cand} (no t= was given, so "
                    f"the System's time is a symbol of its own); ")
        else:
            time = (f"the System's time is the symbol given as t= ({str(system.t_sym)!r}), and a symbol "
                    "of the same name made by another SX.sym call is a different one; ")
        raise ValueError(f"the {label} uses the symbol{'' if one else 's'} {names}, which "
                         f"{'is' if one else 'are'} not the System's q, v, t"
                         f"{' or control' if system.control_sym is not None else ''}: {time}otherwise "
                         f"give {'it a number' if one else 'them numbers'} or make "
                         f"{'it a coordinate' if one else 'them coordinates'}")
