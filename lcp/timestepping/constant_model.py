"""A constant system as numbers: what the fast paths need, without any CasADi work.

A system whose mass matrix, contact kinematics and bilateral constraints are constant and whose
forces are affine in the state (``System.is_constant``) is described completely by a few arrays:

    A qdd = F0 + Kq q + Cv v + G' lambda + H' (p_N, p_T),   G v + phi_t = 0,   g(q) = gap0 + H_N q.

A scene builder that knows these numbers in closed form (the Jean-Pratt scene does) attaches a
:class:`ConstantModel` to its Scene; the compiled Moreau-Jean step and the closed-form event path
then run from it directly, and the CasADi System is built only if some other path asks for it. A
parameter sweep therefore pays no symbolic work per parameter set: the compiled kernels are keyed
by the structure (the number of coordinates), the numbers are their inputs.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ConstantModel", "NumericAssembly"]


@dataclass(frozen=True, eq=False)
class ConstantModel:
    """The numbers of a constant system (see the module docstring for the equations).

    Parameters
    ----------
    A : ndarray (n, n)
        Mass matrix, symmetric positive definite (checked).
    F0, Kq, Cv : ndarray (n,), (n, n), (n, n)
        Forces F = F0 + Kq q + Cv v.
    H : ndarray (2m, n)
        Contact Jacobian, rows [H_N; H_T].
    gap0 : ndarray (m,)
        Gaps at q = 0 (the gaps are affine: g = gap0 + H_N q).
    mu, e : ndarray (m,)
        Friction and restitution coefficients.
    names : tuple of str
        Coordinate names; ``contact_names`` the contacts' names.
    G, phi_t : ndarray (nb, n), (nb,), optional
        Bilateral constraints (none by default).

    Examples
    --------
    A unit block on a floor (x, y), friction 0.5:

    >>> import numpy as np
    >>> from lcp.timestepping.constant_model import ConstantModel
    >>> cm = ConstantModel(A=np.eye(2), F0=np.array([0.0, -9.81]), H=np.array([[0.0, 1.0], [1.0, 0.0]]),
    ...                    gap0=np.zeros(1), mu=np.array([0.5]), e=np.zeros(1), names=("x", "y"),
    ...                    contact_names=("floor",))
    >>> cm.n, cm.m, cm.nb, cm.constant_forces
    (2, 1, 0, True)
    """

    A: np.ndarray
    F0: np.ndarray
    H: np.ndarray
    gap0: np.ndarray
    mu: np.ndarray
    e: np.ndarray
    names: tuple
    contact_names: tuple
    Kq: np.ndarray | None = None
    Cv: np.ndarray | None = None
    G: np.ndarray | None = None
    phi_t: np.ndarray | None = None

    def __post_init__(self):
        A = np.asarray(self.A, dtype=float)
        n = A.shape[0]
        fix = object.__setattr__
        fix(self, "A", A)
        fix(self, "F0", np.asarray(self.F0, dtype=float).reshape(n))
        m = np.asarray(self.mu, dtype=float).size
        fix(self, "H", np.asarray(self.H, dtype=float).reshape(2 * m, n))
        for name in ("gap0", "mu", "e"):
            fix(self, name, np.asarray(getattr(self, name), dtype=float).reshape(m))
        fix(self, "Kq", np.zeros((n, n)) if self.Kq is None else np.asarray(self.Kq, dtype=float).reshape(n, n))
        fix(self, "Cv", np.zeros((n, n)) if self.Cv is None else np.asarray(self.Cv, dtype=float).reshape(n, n))
        fix(self, "G", np.zeros((0, n)) if self.G is None else np.asarray(self.G, dtype=float).reshape(-1, n))
        nb = self.G.shape[0]
        fix(self, "phi_t", np.zeros(nb) if self.phi_t is None else np.asarray(self.phi_t, dtype=float).reshape(nb))
        if len(self.names) != n or len(self.contact_names) != m:
            raise ValueError(f"names must have {n} entries and contact_names {m}")
        names = ("A", "F0", "H", "gap0", "mu", "e", "Kq", "Cv", "G", "phi_t")
        arrays = [getattr(self, name) for name in names]
        if not np.isfinite(np.concatenate([a.ravel() for a in arrays])).all():
            bad = next(name for name, a in zip(names, arrays) if not np.isfinite(a).all())
            raise ValueError(f"{bad} must be finite")
        if (self.mu < 0).any() or (self.e < 0).any() or (self.e > 1).any():
            raise ValueError("mu must be >= 0 and e in [0, 1]")
        scale = max(1.0, float(np.abs(A).max(initial=0.0)))
        if np.abs(A - A.T).max(initial=0.0) > 1e-12 * scale:
            raise ValueError("mass matrix A must be symmetric")
        fix(self, "_constant_forces", not (self.Kq.any() or self.Cv.any()))
        # positive definite, with the check System.check_state makes (smallest eigenvalue > 1e-14 scale)
        eig = np.linalg.eigvalsh(A) if n else np.ones(1)
        if not eig[0] > 1e-14 * max(1.0, float(np.abs(eig).max())):
            raise ValueError(f"mass matrix A is singular or not positive definite: eigenvalues {eig}")

    @classmethod
    def trusted(cls, A, F0, H, gap0, mu, e, names, contact_names) -> "ConstantModel":
        """A model of float64 arrays of the right shapes, without the checks: for scene builders
        whose numbers are valid by construction (they validated the physical parameters they
        come from: positive masses give a positive definite A). No springs, dampers or
        bilateral constraints. The checks cost more than the rest of a scene."""
        obj = object.__new__(cls)
        n, m = A.shape[0], mu.size
        zn, z0n, z0 = _zeros(n)
        obj.__dict__.update(A=A, F0=F0, H=H, gap0=gap0, mu=mu, e=e, names=names, contact_names=contact_names,
                            Kq=zn, Cv=zn, G=z0n, phi_t=z0, _constant_forces=True)
        assert H.shape == (2 * m, n) and F0.shape == (n,)  # builder bugs, not user input
        return obj

    @property
    def n(self) -> int:
        return self.A.shape[0]

    @property
    def m(self) -> int:
        return self.mu.size

    @property
    def nb(self) -> int:
        return self.G.shape[0]

    @property
    def constant_forces(self) -> bool:
        """Forces independent of the state (the phases of the event method are then quadratic in t)."""
        return self._constant_forces

    @classmethod
    def from_system(cls, system) -> "ConstantModel":
        """The numbers of a constant :class:`~lcp.model.system.System` (one CasADi evaluation)."""
        if not system.is_constant:
            raise ValueError("only a constant system (System.is_constant) has a ConstantModel")
        n, m, nb = system.n, system.n_contacts, system.n_bilateral
        z = np.zeros(n)
        A, F0, K, C, G, phi_t, gap0, H = (np.array(x, dtype=float) for x in system.step_data_fn(0.0, z, z))
        return cls(A=A.reshape(n, n), F0=F0.ravel(), H=H.reshape(2 * m, n), gap0=gap0.ravel(), mu=system.mu,
                   e=system.e, names=tuple(system.names), contact_names=tuple(c.name for c in system.contacts),
                   Kq=-K.reshape(n, n), Cv=-C.reshape(n, n), G=G.reshape(nb, n), phi_t=phi_t.ravel())

    def gaps(self, q) -> np.ndarray:
        return self.gap0 + self.H[: self.m] @ q

    def violation(self, Q: np.ndarray) -> float:
        """Largest constraint violation along a trajectory (rows of Q): penetration max(0, -g)."""
        if not self.m or not Q.size:
            return 0.0
        return float(max(0.0, -np.min(self.gap0[None, :] + Q @ self.H[: self.m].T)))


_ZEROS: dict = {}


def _zeros(n: int) -> tuple:
    """Read-only zeros (n, n), (0, n) and (0,), shared by the trusted models of n coordinates (the
    absent springs, dampers and constraints: nothing writes into a model's arrays)."""
    z = _ZEROS.get(n)
    if z is None:
        z = _ZEROS[n] = (np.zeros((n, n)), np.zeros((0, n)), np.zeros(0))
        for a in z:
            a.setflags(write=False)
    return z


class NumericAssembly:
    """The constant data of one Moreau-Jean step, from a :class:`ConstantModel` (no bilateral
    constraints): the same attributes as :class:`lcp.timestepping.assembly.StepAssembly` has for a constant
    system, which is what the compiled step packs (:func:`lcp.timestepping.compiled_step.pack`).

    W_h = A + h theta C + (h theta)^2 K with C = -Cv, K = -Kq; S = W_h^-1; W = H S H'.
    """

    def __init__(self, model: ConstantModel, h: float, theta: float):
        if model.nb:
            raise ValueError("NumericAssembly handles systems without bilateral constraints")
        self.model = self.sys = model  # pack() reads sys.mu and sys.e
        self.h, self.theta = h, theta
        self.n, self.m = model.n, model.m
        self.matrices_constant = self.constant = True
        Wh = model.A - (h * theta) * model.Cv - (h * theta) ** 2 * model.Kq
        self.S = np.linalg.inv(Wh)
        self.T = np.zeros((self.n, 0))
        self.H = model.H
        self.SHt = self.S @ model.H.T
        self.W = model.H @ self.SHt
        self.gap0, self.F0, self.Kq, self.Cv = model.gap0, model.F0, model.Kq, model.Cv
        self.G, self.phi_t = model.G, model.phi_t
        self.force_constant = model.constant_forces
        self.schedule = None

    def at(self, t, q, v):
        """(v_free - v, S H', W, gaps, H) at the start of a step, as StepAssembly.at returns them."""
        m = self.model
        h, th = self.h, self.theta
        dv = self.S @ (h * m.F0 + h * (m.Kq @ q) + (h * (m.Cv @ v) + (h * h * th) * (m.Kq @ v)))
        return dv, self.SHt, self.W, m.gaps(q), self.H
