"""Chains of blocks on a frictional floor joined by springs: scenes with many coupled contacts.

Holds :func:`block_chain`. Imports the model and the scene type only.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from lcp.model.system import Contact, System
from lcp.scenes.scene import Scene, check_params as _check_params

__all__ = ["block_chain"]


def block_chain(K: int = 3, m=1.0, k_spring: float = 50.0, mu=0.3, g: float = 9.81, v0=None,
                spacing: float = 1.0, damping: float = 0.0, t_end: float = 1.0) -> Scene:
    """K blocks on a frictional floor joined by linear springs: a scene with K contacts.

    Block i has coordinates (x_i, y_i), gap y_i and tangent x_i; springs of stiffness ``k_spring``
    (and optional dashpots ``damping``) join neighbours at rest length ``spacing``.

    Parameters
    ----------
    K : int
        Number of blocks, >= 1.
    m, mu : float or sequence of K floats
        Masses (> 0) and friction coefficients (>= 0), per block or shared.
    k_spring, damping : float
        Spring stiffness and dashpot coefficient (>= 0).
    v0 : sequence of K floats, optional
        Initial horizontal velocities; by default the first block is launched at 2 m/s and the
        others are at rest, so the chain sticks and slips.
    t_end : float
        Default horizon.

    Examples
    --------
    >>> from lcp.scenes import block_chain
    >>> sc = block_chain(4)
    >>> sc.system.n, sc.system.n_contacts
    (8, 4)
    """
    if not isinstance(K, (int, np.integer)) or K < 1:
        raise ValueError(f"K must be an integer >= 1, got {K!r}")
    masses = np.broadcast_to(np.asarray(m, dtype=float), (K,)).copy()
    mus = np.broadcast_to(np.asarray(mu, dtype=float), (K,)).copy()
    if np.any(~np.isfinite(masses)) or np.any(masses <= 0):
        raise ValueError(f"m must be finite and > 0, got {m!r}")
    if np.any(~np.isfinite(mus)) or np.any(mus < 0):
        raise ValueError(f"mu must be finite and >= 0, got {mu!r}")
    _check_params(k_spring=k_spring, g=g, spacing=spacing, damping=damping, t_end=t_end)
    if k_spring < 0 or damping < 0:
        raise ValueError("k_spring and damping must be >= 0")
    if t_end <= 0:
        raise ValueError(f"t_end must be > 0, got {t_end!r}")
    n = 2 * K
    q, v = ca.SX.sym("q", n), ca.SX.sym("v", n)
    x, y = q[0::2], q[1::2]
    vx = v[0::2]
    F = [ca.SX(0)] * n
    for i in range(K):
        F[2 * i + 1] = -masses[i] * g
    for i in range(K - 1):
        stretch = x[i + 1] - x[i] - spacing
        rate = vx[i + 1] - vx[i]
        tension = k_spring * stretch + damping * rate
        F[2 * i] = F[2 * i] + tension
        F[2 * i + 2] = F[2 * i + 2] - tension
    # structurally diagonal (not a dense array with zeros): the n^2 structural entries of a dense
    # mass matrix would dominate every evaluation, check and assembly of a long chain
    mass = ca.diag(ca.SX(np.repeat(masses, 2)))
    contacts = [Contact(gap=y[i], tangent=x[i], mu=float(mus[i]), name=f"block{i}") for i in range(K)]
    names = [nm for i in range(K) for nm in (f"x{i}", f"y{i}")]
    system = System(q, v, mass, ca.vertcat(*F), contacts=contacts, names=names)
    q0 = np.zeros(n)
    q0[0::2] = spacing * np.arange(K)
    if v0 is None:
        v0 = np.zeros(K)
        v0[0] = 2.0
    v0 = np.asarray(v0, dtype=float)
    if v0.shape != (K,) or not np.all(np.isfinite(v0)):
        raise ValueError(f"v0 must be {K} finite numbers, got {v0!r}")
    vv = np.zeros(n)
    vv[0::2] = v0
    params = dict(K=K, m=masses, k_spring=k_spring, mu=mus, g=g, spacing=spacing, damping=damping)
    return Scene(system, q0, vv, float(t_end), f"block_chain_{K}", params, None)
