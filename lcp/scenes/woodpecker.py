"""The woodpecker toy (Glocker and Pfeiffer): a sleeve on a rod, a bird attached to it by a spring.

Holds :func:`woodpecker` (the scene, re-exported by :mod:`lcp.scenes.classical`),
:data:`WOODPECKER` (the published data) and :func:`woodpecker_energy`. Imports the model
(:mod:`lcp.model`) and :class:`~lcp.scenes.scene.Scene`; never the simulation, the time stepping or
the event method.

The model is the one of Glocker's thesis as written in Siconos's tutorial (examples/Mechanics/
Woodpecker: WoodPecker.cpp, WoodPeckerConsts.h): three coordinates q = (y, phi_M, phi_S), the
height of the sleeve on the rod, the sleeve's angle and the bird's angle; constant mass matrix,
a torsion spring c_phi between the two angles, gravity; three contacts, each with Coulomb friction
mu = 0.3:

- 1, the beak hits the rod: gap l_M + l_G - l_S - r_O - h_S phi_S, restitution 0.5;
- 2 and 3, the sleeve's lower and upper edges touch the rod:
  gap r_M - r_O +- h_M phi_M, restitution 0.

The published start has contact 2 closed to four digits: its gap is -8.8e-7 (0.0058 x -0.1036 +
0.0006), 4.6e-4 of the row's size. :func:`lcp.simulate` projects it onto g >= 0 at the start (the
common start check, :mod:`lcp.model.start`) and says so in the result's message; the scene keeps the
published numbers so that a comparison with Siconos starts from the same data.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from lcp.model.system import Contact, System
from lcp.scenes.scene import Scene, check_params

__all__ = ["WOODPECKER", "woodpecker", "woodpecker_energy"]

#: the data of Siconos's tutorial (WoodPeckerConsts.h), SI units
WOODPECKER = dict(
    r_O=0.0025, r_M=0.0031, h_M=0.0058, l_M=0.010, l_G=0.015, h_S=0.02, l_S=0.0201,  # geometry
    m_M=0.0003, m_S=0.0045, J_M=5.0e-9, J_S=7.0e-7,  # inertias
    c_phi=0.0056, g=9.81,  # spring, gravity
    e_1=0.5, e_23=0.0, mu=0.3,  # contacts
    y0=0.0, phi_M0=-0.1036, phi_S0=-0.2788, v0=-0.3411, omega_M0=4.8572e-15, omega_S0=-7.4583,  # start
)


def _matrices(p: dict):
    """Mass matrix, stiffness and constant force of the linear model (Siconos's M, K, FExt)."""
    mS, mM, lM, lG = p["m_S"], p["m_M"], p["l_M"], p["l_G"]
    M = np.array([[mS + mM, mS * lM, mS * lG],
                  [mS * lM, p["J_M"] + mS * lM * lM, mS * lM * lG],
                  [mS * lG, mS * lM * lG, p["J_S"] + mS * lG * lG]])
    c = p["c_phi"]
    K = np.array([[0.0, 0.0, 0.0], [0.0, c, -c], [0.0, -c, c]])
    f = -p["g"] * np.array([mS + mM, mS * lM, mS * lG])
    return M, K, f


def woodpecker_energy(params: dict, q, v) -> np.ndarray:
    """Total energy 1/2 v'Mv + 1/2 q'Kq - f'q along rows of q and v (the gravity of the linear model
    is the constant force f, so its potential is -f'q)."""
    M, K, f = _matrices(params)
    q, v = np.atleast_2d(q), np.atleast_2d(v)
    return 0.5 * np.einsum("ij,jk,ik->i", v, M, v) + 0.5 * np.einsum("ij,jk,ik->i", q, K, q) - q @ f


def woodpecker(t_end: float = 0.3, mu: float | None = None, e_1: float | None = None,
               e_23: float | None = None, **overrides) -> Scene:
    """The woodpecker toy with the data of Siconos's tutorial (:data:`WOODPECKER`).

    Parameters
    ----------
    t_end : float
        Default horizon (0.3 s, the tutorial's: about three and a half cycles of the limit cycle).
    mu, e_1, e_23 : float, optional
        Friction coefficient of the three contacts and the restitution coefficients of the beak
        (contact 1) and of the sleeve (contacts 2 and 3); the published values by default.
    **overrides
        Any other entry of :data:`WOODPECKER` (geometry, inertias, start).

    Examples
    --------
    >>> from lcp.scenes.woodpecker import woodpecker
    >>> sc = woodpecker()
    >>> sc.system.n, sc.system.n_contacts, sc.system.is_constant
    (3, 3, True)
    >>> round(float(sc.system.gaps(sc.q0)[1]), 12)  # the published start penetrates the sleeve's contact
    -8.8e-07
    """
    p = dict(WOODPECKER)
    for k, val in dict(mu=mu, e_1=e_1, e_23=e_23).items():
        if val is not None:
            overrides[k] = val
    unknown = set(overrides) - set(p)
    if unknown:
        raise ValueError(f"unknown woodpecker parameter(s) {sorted(unknown)}; known: {sorted(p)}")
    p.update(overrides)
    check_params(t_end=t_end, **p)
    for k in ("r_O", "r_M", "h_M", "h_S", "m_M", "m_S", "J_M", "J_S", "t_end"):
        if (t_end if k == "t_end" else p[k]) <= 0:
            raise ValueError(f"{k} must be > 0, got {t_end if k == 't_end' else p[k]!r}")
    for k in ("e_1", "e_23"):
        if not 0 <= p[k] <= 1:
            raise ValueError(f"{k} must lie in [0, 1], got {p[k]!r}")
    if p["mu"] < 0 or p["c_phi"] < 0:
        raise ValueError(f"mu and c_phi must be >= 0, got mu = {p['mu']!r}, c_phi = {p['c_phi']!r}")
    M, K, f = _matrices(p)
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    y, phM, phS = q[0], q[1], q[2]
    force = ca.DM(f) - ca.mtimes(ca.DM(K), q)
    contacts = [
        Contact(gap=p["l_M"] + p["l_G"] - p["l_S"] - p["r_O"] - p["h_S"] * phS,
                tangent=y + p["l_M"] * phM + (p["l_G"] - p["l_S"]) * phS, mu=p["mu"], e=p["e_1"], name="beak"),
        Contact(gap=p["r_M"] - p["r_O"] + p["h_M"] * phM, tangent=y + p["r_M"] * phM, mu=p["mu"], e=p["e_23"],
                name="sleeve lower"),
        Contact(gap=p["r_M"] - p["r_O"] - p["h_M"] * phM, tangent=y + p["r_M"] * phM, mu=p["mu"], e=p["e_23"],
                name="sleeve upper"),
    ]
    system = System(q, v, ca.DM(M), force, contacts=contacts, names=("y", "phi_M", "phi_S"))
    q0 = np.array([p["y0"], p["phi_M0"], p["phi_S0"]])
    v0 = np.array([p["v0"], p["omega_M0"], p["omega_S0"]])
    return Scene(system, q0, v0, float(t_end), "woodpecker", p, None,
                 no_exact_reason="no closed form: the reference is Moreau-Jean's limit h -> 0 and Siconos's run")
