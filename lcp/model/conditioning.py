"""How many digits of a system's motion double precision can resolve: the mass matrix's conditioning.

A light body coupled to a heavy one (the Jean-Pratt block at m/M = 1e-12) has a mass matrix whose
entries m + M keep few of m's digits: its condition number kappa says that a solve with it loses
log10(kappa) of the 16 digits, and past a point no method can resolve the light body's motion.
Independent bodies are separate diagonal blocks of the mass matrix and are judged block by block,
so a 1 kg bar beside a 1e12 kg block is fine (each block is well conditioned).

:func:`mass_condition` gives the largest condition number over the blocks at a state (cached per
system where the mass matrix is constant); :func:`resolvable` compares it with a method's limit
(:data:`MOREAU_JEAN_LIMIT`, :data:`EVENT_LIMIT`, measured on the Jean-Pratt scene, see their notes).
Imports :mod:`lcp.numerics` and :mod:`lcp.model.state_checks` only.
"""
from __future__ import annotations

import math
import weakref

import numpy as np

from lcp.model.state_checks import dense_mass, mass_ccs_values, null_space
from lcp.numerics.block_diagonal import compressed_diagonal_blocks

__all__ = ["EVENT_LIMIT", "MOREAU_JEAN_LIMIT", "block_condition", "mass_condition", "reduced_condition",
           "resolvable"]

_EPS = np.finfo(float).eps

#: kappa * eps above which Moreau-Jean's impulses lose the light body's motion. Measured on the
#: Jean-Pratt scene (h = 1e-3, 1 s; kappa = 2 M / m): at kappa eps = 4.4e-8 the stop position is
#: exact to the scheme's O(h^2) (2.9e-7); at 4.4e-7 the Python loop is 30 times further off
#: (8.9e-6) and the compiled step creeps at 1e-8 m/s; at 4.4e-5 the error is 1.4e-2 m.
MOREAU_JEAN_LIMIT = 1e-7

#: the same for the event method, whose phases use accelerations, not impulses of size 1/m:
#: at kappa eps = 4.4e-4 (m/M = 1e-12) its stop position is still within 4e-5 of x_stop.
EVENT_LIMIT = 1e-4

#: system -> condition number, for systems whose mass matrix does not depend on the state
_CACHE: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def block_condition(A: np.ndarray) -> float:
    """The largest 2-norm condition number over the diagonal blocks of a symmetric positive
    definite matrix (its connected components; the whole matrix when it does not split).

    Examples
    --------
    >>> import numpy as np
    >>> from lcp.model.conditioning import block_condition
    >>> float(block_condition(np.diag([1.0, 1e12])))  # two independent bodies
    1.0
    >>> round(float(block_condition(np.array([[2.0, -1.0], [-1.0, 2.0]]))), 12)
    3.0
    """
    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    if n == 0:
        return 1.0
    cols, rows = np.nonzero(A.T != 0)  # column-major order, as CasADi's compressed arrays
    colind = np.searchsorted(cols, np.arange(n + 1)).astype(np.int32)
    blocks = compressed_diagonal_blocks(n, colind, rows.astype(np.int32), A.T[A.T != 0], True)
    parts = [A] if blocks is None else [B for _, B in blocks]
    return _worst(parts)


def _worst(parts) -> float:
    kappa = 1.0
    for B in parts:
        e = np.linalg.eigvalsh(0.5 * (B + np.swapaxes(B, -1, -2)))  # ascending along the last axis
        low, high = e[..., 0], np.maximum(np.abs(e[..., 0]), e[..., -1])
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(low > 0, high / np.where(low > 0, low, 1.0), np.inf)
        kappa = max(kappa, float(np.max(ratio)))
    return kappa


def mass_condition(system, q, t: float = 0.0) -> float:
    """The largest condition number over the diagonal blocks of the mass matrix A(t, q), on the
    constraint manifold when the system has bilateral constraints (then the reduced matrix as one
    block). NaN where the matrix is too large to judge cheaply (over 200 coordinates in a block)."""
    constant = system.mass_is_constant and system.kinematics_is_constant
    if constant and system in _CACHE:
        return _CACHE[system]
    if constant and "_mass_kappa" in system.__dict__:  # found by the state check (a diagonal A)
        return system._mass_kappa
    n = system.n
    if system.n_bilateral:
        if n > 200:
            kappa = float("nan")
        else:
            A = dense_mass(system, q, t)
            _, G, _ = (np.array(x, dtype=float) for x in system.constraints_fn(t, q))
            Z = null_space(G.reshape(system.n_bilateral, n))
            kappa = _worst([Z.T @ A @ Z]) if Z.size else 1.0
    else:
        data, row, colind = mass_ccs_values(system, q, t)
        blocks = compressed_diagonal_blocks(n, colind, row, data, True)
        if blocks is not None:
            kappa = _worst([B for _, B in blocks])
        elif n <= 200:
            kappa = _worst([dense_mass(system, q, t)])
        else:
            kappa = float("nan")
    if constant:
        _CACHE[system] = kappa
    return kappa


def reduced_condition(A: np.ndarray, G: np.ndarray | None = None) -> float:
    """:func:`block_condition` of a mass matrix given as numbers, on the null space of the
    constraint Jacobian G when there is one (a constant model's A and G)."""
    if G is not None and np.size(G):
        Z = null_space(np.atleast_2d(G))
        return _worst([Z.T @ A @ Z]) if Z.size else 1.0
    return block_condition(A)


def resolvable(kappa: float, limit: float) -> str:
    """An empty string when kappa * eps <= limit (or kappa is not known), else the reason."""
    if not math.isfinite(kappa) and not math.isinf(kappa) or kappa * _EPS <= limit:
        return ""
    digits = max(0.0, -math.log10(kappa * _EPS))
    return (f"The mass matrix's condition number is {kappa:.3g} (a block of coupled bodies with very "
            f"different masses): a solve keeps about {digits:.0f} of 16 digits, too few to resolve the "
            f"lightest body's motion (limit {limit:g} / eps); the trajectory is not reliable. Rescale "
            "the masses or model the light body apart.")
