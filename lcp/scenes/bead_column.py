"""A column of beads falling onto a floor: impact cascades through many contacts at once.

Holds :func:`bead_column` (re-exported by :mod:`lcp.scenes.classical`). Imports the model
(:mod:`lcp.model`) and :class:`~lcp.scenes.scene.Scene`; never the simulation, the time stepping or
the event method.

K point masses (q = (x_1, y_1, ..., x_K, y_K), unit masses) stacked in a vertical column of beads
of radius r, spaced ``spacing`` apart and dropped from ``drop`` above the floor. The floor touches
the lowest bead, each bead the one below it: K frictionless contacts, Newton restitution e. When
the lowest bead lands, the impulse cascades up the column, and every later landing of a bead on
the one below closes and opens several contacts at the same instant. There is no closed form; the
references are the invariants (energy never increases, the gaps stay closed or open) and, at the
end, the column at rest bead on bead (y_i = r + 2 r (i - 1)). Moreau-Jean converges to the event
method's run as h -> 0 (a test measures it).
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from lcp.model.system import Contact, System
from lcp.scenes.scene import Scene, check_params

__all__ = ["bead_column"]


def bead_column(K: int = 10, e: float = 0.5, r: float = 0.1, spacing: float = 0.05, drop: float = 0.5,
                g: float = 9.81, t_end: float = 3.0) -> Scene:
    """K frictionless beads in a column above a floor (module docstring).

    The scene carries ``energy(q, v)`` (kinetic + potential, per saved state when given arrays)
    and ``rest`` (the beads' heights at rest, bead on bead).

    Examples
    --------
    >>> sc = bead_column(3, e=0.0)
    >>> sc.system.n_contacts, [round(float(y), 3) for y in sc.rest]
    (3, [0.1, 0.3, 0.5])
    """
    if not isinstance(K, (int, np.integer)) or isinstance(K, bool) or K < 1:
        raise ValueError(f"K must be an integer >= 1, got {K!r}")
    check_params(r=r, drop=drop, g=g, t_end=t_end)
    if not (np.isfinite(spacing) and spacing >= 0):
        raise ValueError(f"spacing must be finite and >= 0, got {spacing!r}")
    if not 0 <= e <= 1:
        raise ValueError(f"e must lie in [0, 1], got {e!r}")
    q, v = ca.SX.sym("q", 2 * K), ca.SX.sym("v", 2 * K)
    x, y = q[0::2], q[1::2]
    force = ca.vertcat(*[ca.vertcat(0, -g) for _ in range(K)])
    contacts = [Contact(gap=y[0] - r, tangent=x[0], mu=0.0, e=e, name="floor")]
    contacts += [Contact(gap=y[i] - y[i - 1] - 2 * r, tangent=x[i] - x[i - 1], mu=0.0, e=e, name=f"bead{i}")
                 for i in range(1, K)]
    names = [f"{c}{i}" for i in range(1, K + 1) for c in ("x", "y")]
    system = System(q, v, ca.SX.eye(2 * K), force, contacts=contacts, names=names)
    q0 = np.zeros(2 * K)
    q0[1::2] = r + drop + np.arange(K) * (2 * r + spacing)
    sc = Scene(system, q0, np.zeros(2 * K), float(t_end), "bead_column",
               {"K": int(K), "e": e, "r": r, "spacing": spacing, "drop": drop, "g": g},
               no_exact_reason="no closed form: invariants, the rest state, and the event method's run")
    sc.rest = r + 2 * r * np.arange(K)

    def energy(qs, vs):
        qs, vs = np.atleast_2d(qs), np.atleast_2d(vs)
        return 0.5 * np.sum(vs * vs, axis=1) + g * np.sum(qs[:, 1::2], axis=1)

    sc.energy = energy
    return sc
