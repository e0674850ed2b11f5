"""The consistency of a start (q0, v0) with the constraints and contacts, one check for every method.

Holds :func:`consistent_start` (a :class:`~lcp.model.system.System`), :func:`consistent_affine_start`
(the numbers of a constant model with contacts only), :func:`system_length` and the tolerances
:data:`START_TOL`, :data:`ROUND_ULPS`. Imports NumPy (SciPy and :mod:`lcp.numerics.casadi_eval` for large constant rows) only (the System is passed in); never the
contact problem, time stepping or events: both methods call it from their entry.

What a start must satisfy
-------------------------
- every bilateral constraint at the position level, phi(t0, q0) = 0, and at the velocity level,
  G(t0, q0) v0 + phi_t(t0, q0) = 0;
- every contact is not penetrated, g_j(q0) >= 0. A closed contact may approach (u_N < 0): it just
  impacts at t0; nothing is asked of the contacts' velocities.

Each row i (a constraint or a gap) is measured against its own size, in its own units,

    s_i = |J_i| (|q0| + l) + |r_i(t0, 0)|        (velocities: |G_i| |v0| + |phi_t,i|),

where J_i is the row's Jacobian, |.| taken entry by entry, r_i(t0, 0) the row's constant (a floor at
height 5, a rod's length squared) and l the system's length (:func:`system_length`: its largest
geometric constant in coordinate units, or one unit of the coordinates where the rows have none).
Then:

- a violation within rounding (|r_i| <= ROUND_ULPS eps s_i) is left as it is, silently;
- a violation within the start tolerance (|r_i| <= START_TOL s_i: data rounded to four significant
  digits, such as published parameters, are consistent to about this) is projected away, by the
  smallest correction in the mass metric: positions onto the constraints and out of the penetrated
  contacts (held at g_j = 0; others enter when the correction pushes them in), then velocities onto
  the constraints' tangent space. The result's message says so (``note``);
- a larger violation raises a ValueError naming the contact or constraint and its violation.

A system with Newton-Euler kinematics (``System(..., kinematics=T)``: n_q coordinates, n_v
velocities) is checked the same way, its Jacobians in v-space (J = dr/dq T, corrections
dx = T A^-1 J' (...)); its declared unit quaternions first
(:func:`lcp.model.kinematics.quaternion_start`): normalised silently within rounding, with a note
within START_TOL of norm 1, a ValueError naming the coordinate beyond.
"""
from __future__ import annotations

import math
import weakref

import numpy as np

__all__ = ["ROUND_ULPS", "START_TOL", "consistent_affine_start", "consistent_start", "system_length"]

#: a start violating a constraint or penetrating a contact by at most this fraction of the row's size
#: (module docstring) is projected onto the constraints; beyond it, ValueError
START_TOL = 1e-3
#: violations within this many units of rounding (eps times the row's size) are left untouched
ROUND_ULPS = 64.0
_EPS = float(np.finfo(float).eps)


def _length(J, c) -> float:
    """The system's length from the rows' constants c and Jacobians J (1.0 where there is none)."""
    if J.size == 0:
        return 1.0
    norms = _row_absmax(J) if hasattr(J, "indptr") else np.abs(J).max(axis=1)
    ok = (norms > 0) & np.isfinite(norms) & np.isfinite(c)
    ell = float((np.abs(c[ok]) / norms[ok]).max(initial=0.0))
    return ell if ell > 0 and math.isfinite(ell) else 1.0


def system_length(system, q, t: float = 0.0) -> float:
    """The length ``l`` of the start's scales (module docstring): the largest of the constraints' and
    gaps' constants r_i(t, 0) divided by their Jacobian row's largest entry at q; 1.0 where every
    constant is zero (a system without a length of its own is measured in its coordinates' unit)."""
    _, _, J, c = _rows(system, np.asarray(q, dtype=float), t)
    return _length(J, c)


#: the largest m x n gap Jacobian of constant rows kept dense (beyond it CSR: see _affine_rows)
_DENSE_ROWS_MAX = 40_000

#: (Jacobian, constants, names) of a system whose constraints and gaps are affine and constant
_AFFINE = weakref.WeakKeyDictionary()


def _rows(system, q, t):
    """(residuals r, names, Jacobian J, constants r(t, 0)) of the bilateral rows, then the gaps."""
    if not system.n_bilateral and system.kinematics_is_constant:
        # g(q) = g(0) + H_N q: the rows once per system, the residuals by one product (a CasADi
        # evaluation of each costs more than the whole check)
        known = _AFFINE.get(system)
        if known is None:
            known = _AFFINE[system] = _affine_rows(system, t)
        names, J, c = known
        return c + J @ q, names, J, c
    return _general_rows(system, q, t)


def _affine_rows(system, t):
    """(names, J, c) of constant contact rows without bilateral constraints, from the nonzeros of
    CasADi's H and g at q = 0 (its own conversions to NumPy cost more than the check). J is CSR
    where the dense gap Jacobian would be large (K contacts of 3K coordinates: CasADi's dense
    conversion of H alone took a second at K = 1000), else dense."""
    n, m = system.n, system.n_contacts
    if system.gap_tq_fn is not None or system.H_tq_fn is not None:  # (constant kinematics never move)
        return _general_rows(system, np.zeros(n), t)[1:]
    z = np.zeros(n)
    vals, row, col, _ = _nonzeros(system.H_fn, z)
    keep = row < m
    if n * m <= _DENSE_ROWS_MAX:
        J = np.zeros((m, n))
        J[row[keep], col[keep]] = vals[keep]
    else:
        import scipy.sparse as sp

        J = sp.csr_matrix((vals[keep], (row[keep], col[keep])), shape=(m, n))
    gv, grow, _, _ = _nonzeros(system.gap_fn, z)
    c = np.zeros(m)
    c[grow] = gv
    names = [f"contact {ct.name!r}" for ct in system.contacts]
    return names, J, c


def _nonzeros(fn, q):
    """(values, rows, columns, shape) of the nonzeros of fn(q)'s first output."""
    from lcp.numerics.casadi_eval import evaluate_into

    pattern = fn.sparsity_out(0)
    vals = np.empty(pattern.nnz())
    evaluate_into(fn, [q], [vals])
    colind = np.array(pattern.colind(), dtype=np.int64)
    col = np.repeat(np.arange(colind.size - 1), np.diff(colind))
    return vals, np.array(pattern.row(), dtype=np.int64), col, pattern.shape


def _row_absmax(J):
    """max_j |J_ij| of each row of a CSR matrix (SciPy's max(axis=1) costs milliseconds here)."""
    out = np.zeros(J.shape[0])
    nz = np.diff(J.indptr) > 0
    if nz.any():
        out[nz] = np.maximum.reduceat(np.abs(J.data), J.indptr[:-1][nz])
    return out


def _dense(J):
    return J.toarray() if hasattr(J, "toarray") else J


def _general_rows(system, q, t):
    n, nb, m = system.n, system.n_bilateral, system.n_contacts
    r, J, c = [], [], []
    if nb:
        phi, G, _ = system.constraints_fn(t, q)
        r.append(np.array(phi, dtype=float).ravel())
        J.append(np.array(G, dtype=float).reshape(nb, n))
        c.append(np.array(system.constraints_fn(t, np.zeros(_n_q(system)))[0], dtype=float).ravel())
    if m:
        r.append(system.gaps(q, t))
        J.append(system.contact_jacobian(q, t)[:m])
        c.append(system.gaps(np.zeros(_n_q(system)), t))
    names = [f"bilateral constraint {i}" for i in range(nb)] + [f"contact {ct.name!r}" for ct in system.contacts]
    if not r:
        return np.zeros(0), names, np.zeros((0, n)), np.zeros(0)
    return np.concatenate(r), names, np.vstack(J), np.concatenate(c)


def _n_q(system) -> int:
    """The number of coordinates (n_q; the number of velocities n where the System has no kinematics)."""
    return getattr(system, "n_q", system.n)


def _reach(system, q, ell, t):
    """|q| + l, the coordinates' reach in the row scales; with kinematics (J in v-space) mapped to
    v-space by |T(t, q)|', so that |J| times it has the size of |dg/dq| (|q| + l)."""
    x = np.abs(q) + ell
    if getattr(system, "has_kinematics", False):
        return np.abs(np.array(system.kinematics_fn(t, q), dtype=float)).T @ x
    return x


def _violations(r, nb):
    """Each row's violation: |phi_i| for the bilateral rows, max(0, -g_j) for the gaps."""
    out = np.abs(r)
    out[nb:] = np.maximum(-r[nb:], 0.0)
    return out


def _raise_beyond(viol, s, names, what):
    bad = viol > START_TOL * s
    if bad.any():
        i = int(np.argmax(np.where(bad, viol / np.maximum(s, 1e-300), -1.0)))
        kind = "penetrates" if names[i].startswith("contact") else "violates"
        raise ValueError(f"{what} {kind} {names[i]} by {viol[i]:.3g} (its size {s[i]:.3g}; starts are projected "
                         f"onto the constraints within {START_TOL:g} of the size only, lcp.model.start)")


def _mass_correction(A, J, r):
    """The smallest correction dx in the mass metric A with J dx = r."""
    AJ = np.linalg.solve(A, J.T)
    return AJ @ np.linalg.lstsq(J @ AJ, r, rcond=None)[0]


def consistent_start(system, q0, v0, t0: float = 0.0, rows=None):
    """The start (q0, v0) checked, and projected within the tolerance (module docstring).

    Parameters
    ----------
    rows : (ndarray, ndarray), optional
        The contact rows (H_N, g(0)) of a system without bilateral constraints whose contacts do not
        move, where the caller has them already (the Moreau-Jean assembly of a constant system):
        they are those of the gaps g(q) = g(0) + H_N q, so no CasADi evaluation is repeated.

    Returns
    -------
    q0, v0 : ndarray
        The start itself where it is consistent to rounding, else the projected start.
    note : str or None
        Where the start was projected: a sentence for the result's message.

    Raises
    ------
    ValueError
        A constraint violated or a contact penetrated beyond :data:`START_TOL` of its size.
    """
    nb, m = system.n_bilateral, system.n_contacts
    qnote = None
    if getattr(system, "unit_quaternions", ()):
        from lcp.model.kinematics import quaternion_start

        q0, qnote = quaternion_start(system, q0, START_TOL)
    if nb + m == 0:
        return q0, v0, qnote
    t0 = float(t0)
    if (rows is not None and not nb and system.kinematics_is_constant and system.n * m <= _DENSE_ROWS_MAX
            and system.gap_tq_fn is None and system.H_tq_fn is None and system not in _AFFINE):
        _AFFINE[system] = ([f"contact {ct.name!r}" for ct in system.contacts], *rows)
    r, names, J, c = _rows(system, q0, t0)
    if not nb and min(r.tolist()) >= 0.0:
        # no constraint and no gap penetrated: every violation is zero, nothing to measure (a NaN
        # gap, which fails this test, is never a violation either)
        return q0, v0, qnote
    ell = _length(J, c)
    lim = np.abs(J) @ _reach(system, q0, ell, t0) + np.abs(c)
    viol = _violations(r, nb)
    moved = []
    q, v = q0, v0
    if np.any(viol > ROUND_ULPS * _EPS * lim):
        _raise_beyond(viol, lim, names, "q0")
        moved = [(names[i], float(viol[i])) for i in np.flatnonzero(viol > ROUND_ULPS * _EPS * lim)]
        q = _project_positions(system, q0, t0, r, J, c, ell, nb)
    vnote = None
    if nb:
        _, G, phi_t = system.constraints_fn(t0, q)
        G = np.array(G, dtype=float).reshape(nb, system.n)
        phi_t = np.array(phi_t, dtype=float).ravel()
        rv = G @ v0 + phi_t
        limv = np.abs(G) @ np.abs(v0) + np.abs(phi_t)
        if np.any(np.abs(rv) > ROUND_ULPS * _EPS * limv):
            _raise_beyond(np.abs(rv), limv, [f"the velocity form of {nm}" for nm in names[:nb]], "v0")
            v = v0 - _mass_correction(system.mass(q, t0), G, rv)
            vnote = float(np.max(np.abs(rv)))
    if not moved and vnote is None:
        return q0, v0, qnote
    parts = []
    if moved:
        parts.append(f"q0 moved by {float(np.max(np.abs(q - q0))):.3g} ("
                     + ", ".join(f"{nm} off by {x:.3g}" for nm, x in moved[:3]) + (", ..." if len(moved) > 3 else "")
                     + ")")
    if vnote is not None:
        parts.append(f"v0 moved by {float(np.max(np.abs(v - v0))):.3g} (velocity constraints off by {vnote:.3g})")
    note = (f"The start was projected onto the constraints (within {START_TOL:g} of their size, "
            f"lcp.model.start): {'; '.join(parts)}.")
    return q, v, note if qnote is None else f"{qnote} {note}"


def _project_positions(system, q0, t0, r, J, c, ell, nb):
    """Newton's method on the bilateral rows and the penetrated contacts held at g = 0, each step the
    smallest correction in the mass metric; contacts pushed in on the way join the held set."""
    A = system.mass(q0, t0)
    held = np.ones(r.size, dtype=bool)
    held[nb:] = r[nb:] < 0
    q = q0.copy()
    J = _dense(J)
    for _ in range(30):
        lim = np.abs(J) @ _reach(system, q, ell, t0) + np.abs(c)
        viol = _violations(r, nb)
        held[nb:] |= r[nb:] < 0
        res = np.where(held, r, 0.0)
        if not np.any(np.where(held, np.abs(r), viol) > ROUND_ULPS * _EPS * lim):
            return q
        rows = np.flatnonzero(held)
        dx = _mass_correction(A, J[rows], res[rows])
        if getattr(system, "has_kinematics", False):  # dx is in v-space: q moves by T(q) dx
            from lcp.model.kinematics import normalize_quaternions

            q = normalize_quaternions(system, q - np.array(system.kinematics_fn(t0, q), dtype=float) @ dx)
        else:
            q = q - dx
        r, _, J, _ = _rows(system, q, t0)
        J = _dense(J)
        A = system.mass(q, t0)
    raise ValueError(f"q0 could not be projected onto the constraints: residual {float(np.max(np.abs(r))):.3g} "
                     "after 30 Newton steps")


def consistent_affine_start(H_N, gap0, A, q0, v0, contact_names):
    """:func:`consistent_start` for constant contact rows (g = gap0 + H_N q) without bilateral
    constraints, from the numbers alone (a scene's constant model)."""
    g = gap0 + H_N @ q0
    if min(g.tolist(), default=0.0) >= 0.0:
        return q0, v0, None
    ell = _length(H_N, gap0)
    lim = np.abs(H_N) @ (np.abs(q0) + ell) + np.abs(gap0)
    viol = np.maximum(-g, 0.0)
    if not np.any(viol > ROUND_ULPS * _EPS * lim):
        return q0, v0, None
    names = [f"contact {nm!r}" for nm in contact_names]
    _raise_beyond(viol, lim, names, "q0")
    held = g < 0
    q = q0.copy()
    for _ in range(len(g) + 1):  # affine rows: one correction per change of the held set
        q = q - _mass_correction(A, H_N[held], g[held])
        g = gap0 + H_N @ q
        if not np.any(~held & (g < -ROUND_ULPS * _EPS * lim)):
            break
        held |= g < 0
    moved = [(names[i], float(viol[i])) for i in np.flatnonzero(viol > ROUND_ULPS * _EPS * lim)]
    note = (f"The start was projected onto the constraints (within {START_TOL:g} of their size, "
            f"lcp.model.start): q0 moved by {float(np.max(np.abs(q - q0))):.3g} ("
            + ", ".join(f"{nm} off by {x:.3g}" for nm, x in moved[:3]) + ").")
    return q, v0, note
