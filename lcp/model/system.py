"""The mechanical system: generalized coordinates, mass matrix, forces, bilateral constraints and contacts.

Everything is written with CasADi symbols, so that every Jacobian (contact normals and tangents,
bilateral constraints, force derivatives for the implicit step) comes from automatic
differentiation. The model follows docs/models.md:

    A(t, q) qdd = F(t, q, v) + G(t, q)' lambda + H_N(q)' N + H_T(q)' f,
    phi(t, q) = 0 (bilateral, frictionless),
    0 <= N_j  perp  g_j(q) >= 0,   |f_j| <= mu_j N_j,  f_j = -mu_j N_j sign(u_T,j) if u_T,j != 0.

A contact is planar (one tangent direction: the 2D Coulomb law, exactly a linear complementarity
problem) or spatial (two tangent directions: the sliding velocity U_j and the friction force f_j are
vectors of the tangent plane, |f_j| <= mu_j N_j, f_j = -mu_j N_j U_j/|U_j| while U_j != 0: the
Coulomb disk). Both kinds can be mixed in one system. The contact Jacobian H stacks the normal rows
of all contacts first, then the tangent rows contact by contact (one or two each):
``[H_N,1..H_N,m, H_T,1 (d_1 rows), .., H_T,m (d_m rows)]``; for planar contacts only this is
``[H_N; H_T]`` with m rows each.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from lcp.model import state_checks
from lcp.model.control import check_schedule, split_control
from lcp.model.kinematics import attach_kinematics, kinematics_functions, kinematics_options

__all__ = ["Contact", "System", "moving_contact"]


def _finite_nonneg(name: str, value) -> float:
    if isinstance(value, (str, bytes)) or np.ndim(value) != 0:  # float("0.3") would pass a typo'd string through
        raise ValueError(f"{name} must be a number, got {value!r}")
    try:
        value = float(value)
    except (TypeError, ValueError):  # None, objects
        raise ValueError(f"{name} must be a number, got {value!r}") from None
    if not np.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value!r}")
    if value < 0:
        raise ValueError(f"{name} must be >= 0, got {value!r}")
    return value


@dataclass(frozen=True)
class Contact:
    """A point contact with Coulomb friction, planar (one tangent) or spatial (two tangents).

    Parameters
    ----------
    gap : casadi.SX
        Scalar expression g(q) >= 0 of the system's coordinates; its gradient is the normal
        Jacobian row H_N.
    tangent : casadi.SX, optional
        Tangent coordinate s(q) whose rate is the sliding velocity (H_T = ds/dq): a scalar for a
        planar contact, or two coordinates ``ca.vertcat(s1, s2)`` for a spatial contact, whose
        rates are the two components of the sliding velocity U in the tangent plane.
    tangent_jacobian : casadi.SX, optional
        Or the tangent Jacobian itself, possibly depending on q: one row (1 x n, or an n-vector)
        for a planar contact, two rows (2 x n) for a spatial one. Give exactly one of ``tangent``
        and ``tangent_jacobian``. The tangent rows must be independent of each other and of the
        normal row (checked where the system is built, or at the initial state when they depend
        on q). For a system with Newton-Euler ``kinematics`` its columns are those of v (n_v):
        the tangent velocities per unit of v, as every Jacobian of such a system.
    mu : float
        Coulomb friction coefficient (the paper's R), >= 0.
    e : float
        Newton restitution coefficient in [0, 1].
    name : str
        Label used in messages.
    """

    gap: ca.SX
    tangent: ca.SX | None = None
    tangent_jacobian: ca.SX | None = None
    mu: float = 0.0
    e: float = 0.0
    name: str = "contact"

    def __post_init__(self):
        object.__setattr__(self, "mu", _finite_nonneg(f"mu of {self.name}", self.mu))
        object.__setattr__(self, "e", _finite_nonneg(f"e of {self.name}", self.e))
        if self.e > 1:
            raise ValueError(f"e of {self.name} must lie in [0, 1], got {self.e!r}")
        if (self.tangent is None) == (self.tangent_jacobian is None):
            raise ValueError(f"{self.name}: give exactly one of 'tangent' and 'tangent_jacobian'")
        if ca.SX(self.gap).numel() != 1:
            raise ValueError(f"gap of {self.name} must be a scalar expression")


def _float_array(name: str, x) -> np.ndarray:
    try:
        return np.asarray(x, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be an array of numbers, got {x!r}") from exc


def _sx(expr, shape_name: str, shape: tuple[int, int]) -> ca.SX:
    """Turn numbers or expressions into an SX of the expected shape, or raise naming it."""
    try:
        x = ca.SX(expr) if not isinstance(expr, ca.SX) else expr
    except Exception as exc:  # noqa: BLE001 - CasADi raises NotImplementedError/RuntimeError variously
        raise ValueError(f"{shape_name} must be a CasADi SX expression or numeric array") from exc
    if x.shape != shape:
        if x.numel() == shape[0] * shape[1]:
            x = ca.reshape(x, *shape)
        else:
            raise ValueError(f"{shape_name} must have shape {shape}, got {x.shape}")
    if not x.is_symbolic() and x.is_constant():
        vals = np.array(ca.DM(x), dtype=float)
        if not np.all(np.isfinite(vals)):
            raise ValueError(f"{shape_name} must be finite")
    return x


class System:
    """A rigid-body system with bilateral constraints and frictional point contacts (planar or spatial).

    Parameters
    ----------
    q, v : casadi.SX
        Column symbols (n x 1) for the coordinates and the velocities.
    mass : casadi.SX or array_like
        Mass matrix A(t, q), n x n, symmetric positive definite (on the constraint manifold).
    force : casadi.SX or array_like
        Generalized forces F(t, q, v), n x 1.
    contacts : sequence of Contact
        The unilateral contacts (may be empty).
    constraints : casadi.SX, optional
        Bilateral holonomic constraints phi(t, q) = 0, n_b x 1.
    t : casadi.SX, optional
        Time symbol, if any expression depends on time.
    names : sequence of str, optional
        Names of the coordinates.
    breakpoints : array_like, optional
        Times at which a time-dependent force is discontinuous (e.g. the switches of a
        piecewise-constant control); stored sorted and unique as :attr:`breakpoints` (empty by
        default), so that an event integrator can end its phases exactly there.
    control : casadi.SX, optional
        Column of control symbols u (nu x 1). The force must be affine in u,
        F(t, q, v, u) = F0(t, q, v) + B(t, q) u (checked: B may not depend on u or v), and the
        mass, constraints and contacts may not depend on u. A controlled system is simulated
        with a control schedule (:meth:`with_control`, or ``lcp.simulate(..., control=...)``) and
        optimised by :class:`lcp.ocp.OptimalControlProblem`. Its ``force_expr``, ``force_fn`` and
        the step functions are those of the drift F0 (u = 0); ``control_matrix_expr`` is B.
    control_bounds : (array_like, array_like), optional
        Lower and upper bounds of u (broadcast to (nu,); +-inf allowed; -inf..inf by default).
    kinematics, unit_quaternions, velocity_names : optional
        Newton-Euler kinematics qdot = T(t, q) v (T: n_q x n_v SX; v of its own length n = n_v;
        A, F and every Jacobian in v-space), the start indices in q of unit quaternions, the
        velocities' names: :mod:`lcp.model.kinematics`. Default: T = I, the system without it.

    Notes
    -----
    On construction the system compiles CasADi Functions for everything a time stepper needs, and
    finds out which parts are constant (mass matrix, Jacobians, forces), so that a stepper can
    assemble them once and never call CasADi inside its loop when nothing varies.

    Examples
    --------
    A block of mass 2 on a frictional floor (coordinates x, y; gap y):

    >>> import casadi as ca
    >>> from lcp.model.system import System, Contact
    >>> q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    >>> s = System(q, v, mass=2 * ca.SX.eye(2), force=ca.vertcat(0, -2 * 9.81),
    ...            contacts=[Contact(gap=q[1], tangent=q[0], mu=0.3)])
    >>> s.n, s.n_contacts, s.is_constant
    (2, 1, True)
    """

    def __init__(self, q: ca.SX, v: ca.SX, mass: ca.SX | ArrayLike, force: ca.SX | ArrayLike,
                 contacts: Sequence[Contact] = (), constraints: ca.SX | None = None,
                 t: ca.SX | None = None, names: Sequence[str] | None = None, breakpoints: ArrayLike | None = None,
                 control: ca.SX | None = None, control_bounds: ArrayLike | None = None,
                 kinematics: ca.SX | None = None, unit_quaternions: Sequence[int] = (),
                 velocity_names: Sequence[str] | None = None) -> None:
        self.breakpoints = _breakpoints(breakpoints)
        self.control_schedule = None  # set by with_control
        if not isinstance(q, ca.SX) or not q.is_symbolic() or q.shape[1] != 1:
            raise ValueError("q must be a column of CasADi SX symbols (casadi.SX.sym('q', n))")
        if kinematics is None and (not isinstance(v, ca.SX) or not v.is_symbolic() or v.shape != q.shape):
            raise ValueError("v must be a column of CasADi SX symbols with the shape of q")
        self.t_sym = t if t is not None else ca.SX.sym("t")
        if not isinstance(self.t_sym, ca.SX) or not self.t_sym.is_symbolic() or self.t_sym.numel() != 1:
            raise ValueError("t must be a scalar CasADi SX symbol")
        self.q_sym, self.v_sym = q, v
        # n velocities (the size of A, F and H's columns), n_q coordinates, qdot = T(t, q) v
        # (lcp.model.kinematics; T None for the identity: then nothing below changes)
        self._T, n = attach_kinematics(self, kinematics, unit_quaternions, velocity_names, names)
        vs = (lambda J: J) if self._T is None else (lambda J: ca.mtimes(J, self._T))  # d/dq to v-space
        self.mass_expr = _sx(mass, "mass", (n, n))
        self.force_expr = _sx(force, "force", (n, 1))
        self._init_control(control, control_bounds, q, v, t)
        if isinstance(contacts, Contact):
            raise ValueError("contacts must be a list of Contact objects, got a single Contact")
        self.contacts = tuple(contacts)
        for c in self.contacts:
            if not isinstance(c, Contact):
                raise ValueError(f"contacts must be Contact objects, got {type(c).__name__}")
        tq = ca.vertcat(self.t_sym, q)
        if ca.depends_on(self.mass_expr, v):
            raise ValueError("mass may depend on t and q only, not on v")

        # bilateral constraints phi(t, q) = 0
        if constraints is None:
            self.constraints_expr = ca.SX.zeros(0, 1)
        else:
            # a list of scalar expressions is accepted as well as a column
            c = ca.vertcat(*constraints) if isinstance(constraints, (list, tuple)) else ca.SX(constraints)
            self.constraints_expr = ca.reshape(c, c.numel(), 1)
            if ca.depends_on(self.constraints_expr, v):
                raise ValueError("constraints must depend on t and q only")
        self.n_bilateral = self.constraints_expr.shape[0]
        G = vs(ca.jacobian(self.constraints_expr, q))
        phi_t = ca.jacobian(self.constraints_expr, self.t_sym)

        # contact kinematics: normal and tangent Jacobian rows
        m = len(self.contacts)
        self.n_contacts = m
        gap, HN, HT, rate = _contact_kinematics(self.contacts, q, v, self.t_sym, n, vs)
        self.mu = np.array([c.mu for c in self.contacts], dtype=float)
        self.e = np.array([c.e for c in self.contacts], dtype=float)
        #: tangent dimension of each contact: 1 (planar) or 2 (spatial, the Coulomb disk)
        self.tangent_dims = np.array([r.shape[0] for r in HT], dtype=np.int64)
        #: contact j's tangent rows of H are m + tangent_offsets[j] .. m + tangent_offsets[j + 1]
        self.tangent_offsets = np.concatenate([[0], np.cumsum(self.tangent_dims)]).astype(np.int64)
        self.n_tangent = int(self.tangent_offsets[-1])
        #: rows of H (and of the Delassus operator): m normals, then the tangent rows
        self.n_contact_rows = m + self.n_tangent
        self.is_spatial = bool(np.any(self.tangent_dims == 2))
        H = ca.vertcat(*(HN + HT)) if m else ca.SX.zeros(0, n)
        # b(t, q) = (dg/dt, ds/dt): the local velocities are u = H(t, q) v + b; contacts_depend_on_t:
        # whether any gap, tangent or contact Jacobian moves with t (a moving table, a cam, a belt)
        self.gap_expr, self.H_expr, self.contact_rate_expr = gap, H, rate
        self.contacts_depend_on_t = bool(m) and _moves(ca.vertcat(gap, ca.vec(H)), rate, self.t_sym)
        self.contact_rows_checked = False
        #: diagonal blocks of a constant sparse mass matrix, found by its check (lcp.numerics.block_diagonal)
        self.mass_blocks = None

        # -dF/dq and -dF/dv: the implicit (theta) step linearizes the forces with them
        K = -vs(ca.jacobian(self.force_expr, q))  # dF/dq T: the rate of F per unit of v
        C = -ca.jacobian(self.force_expr, v)
        self.force_is_affine = not ca.depends_on(ca.vertcat(ca.vec(K), ca.vec(C)), ca.vertcat(self.t_sym, q, v))
        self.force_depends_on_t = ca.depends_on(self.force_expr, self.t_sym)
        self.force_depends_on_state = ca.depends_on(self.force_expr, ca.vertcat(q, v))

        # constancy: decides whether a stepper may assemble once and skip CasADi in its loop
        self.mass_is_constant = not ca.depends_on(self.mass_expr, tq)
        self.kinematics_is_constant = (not ca.depends_on(ca.vertcat(ca.vec(H), ca.vec(G), ca.vec(phi_t)), tq)
                                       and not self.contacts_depend_on_t
                                       and self._T is None)  # with T: g(q) is not g(0) + H q
        self.gap_is_affine = self.kinematics_is_constant
        self.is_constant = (self.mass_is_constant and self.kinematics_is_constant
                            and self.force_is_affine and not self.force_depends_on_t)

        args = [self.t_sym, q, v]
        try:
            self.mass_fn = ca.Function("mass", [self.t_sym, q], [self.mass_expr])
            self.force_fn = ca.Function("force", args, [self.force_expr])
            self.force_jac_fn = ca.Function("force_jac", args, [K, C])
            self.constraints_fn = ca.Function("constraints", [self.t_sym, q], [self.constraints_expr, G, phi_t])
            (self.gap_fn, self.H_fn, self.gap_tq_fn, self.H_tq_fn,
             self.contact_rate_fn) = _contact_functions(self, q, gap, H)
        except RuntimeError:
            state_checks.check_free_symbols(self, t is None, gap, H, phi_t)  # names a symbol the System lacks
            raise
        if m and not ca.depends_on(ca.vec(H), q):
            state_checks.check_contact_rows(self, np.zeros(self.n_q))  # constant kinematics: checked once, here
        # everything one Moreau-Jean step needs at (t, q, v), in one call
        self.step_data_fn = ca.Function(
            "step_data", [self.t_sym, q, v],
            [self.mass_expr, self.force_expr, K, C, G, phi_t, gap, H])
        # energy bookkeeping needs a potential only when the user gives one; kinetic energy is general
        self.kinetic_fn = ca.Function("kinetic", [self.t_sym, q, v], [0.5 * ca.mtimes([v.T, self.mass_expr, v])])
        kinematics_functions(self)  # kinematics_expr, kinematics_fn, qdot_fn (for compiled engines too)

    def _init_control(self, control, control_bounds, q, v, t):
        """Split F = F0 + B u for a control u (:func:`lcp.model.control.split_control`)."""
        split = split_control(self.force_expr, self.mass_expr, control, control_bounds, q, v, self.t_sym)
        self.control_sym, self.nu, self.control_bounds = split.symbol, split.nu, split.bounds
        self.control_matrix_expr = split.matrix
        if split.nu:
            self.controlled_force_expr = self.force_expr
            self.force_expr = split.free_force
            self.control_matrix_fn = ca.Function("control_matrix", [self.t_sym, q], [split.matrix])

    @property
    def is_controlled(self) -> bool:
        """True when the system has a control input that no schedule fixes yet."""
        return self.nu > 0

    def with_control(self, schedule) -> "System":
        """This system with its control fixed to a schedule: F(t) = F0(t, q, v) + B(t, q) u(t).

        Parameters
        ----------
        schedule : lcp.model.control.ControlSchedule
            With ``nu`` components, within ``control_bounds`` (checked).

        Returns
        -------
        System
            Uncontrolled, its force a known function of time; ``breakpoints`` are the schedule's
            discontinuities (merged with this system's), and ``control_schedule`` is the schedule,
            so that a Moreau-Jean step integrates the control's impulse over the step exactly
            (:class:`lcp.timestepping.assembly.StepAssembly`).

        Examples
        --------
        >>> import casadi as ca, lcp
        >>> from lcp.model.control import ControlSchedule
        >>> q, v, u = ca.SX.sym("q", 1), ca.SX.sym("v", 1), ca.SX.sym("u", 1)
        >>> s = System(q, v, mass=1.0, force=u, control=u, control_bounds=(-1, 1))
        >>> r = lcp.simulate(s, 1.0, h=0.25, q0=[0.0], v0=[0.0],
        ...                  control=ControlSchedule([0, 0.5, 1.0], [1.0, -1.0]))
        >>> float(r.v[2, 0]), float(r.v[-1, 0]), float(r.q[-1, 0])
        (0.5, 0.0, 0.25)
        """
        check_schedule(schedule, self.nu, self.control_bounds)
        t = self.t_sym
        force = self.force_expr + ca.mtimes(self.control_matrix_expr, schedule.expression(t))
        out = System(self.q_sym, self.v_sym, self.mass_expr, force, contacts=self.contacts,
                     constraints=self.constraints_expr if self.n_bilateral else None, t=t, names=self.names,
                     breakpoints=np.concatenate([self.breakpoints, schedule.breakpoints]), **kinematics_options(self))
        out.control_schedule = schedule
        # the uncontrolled part F0 (u = 0): where it is constant and B too, the constant paths step
        # it as a constant system and add the control's impulse (lcp.timestepping.assembly)
        out.control_drift = self
        out.control_matrix_fn = self.control_matrix_fn
        out.control_force_fn = ca.Function("control_force", [t, self.q_sym],
                                           [ca.mtimes(self.control_matrix_expr, schedule.expression(t))])
        return out

    # ------------------------------------------------------------------ numeric helpers
    def mass(self, q, t: float = 0.0) -> np.ndarray:
        """Mass matrix A(t, q) as an n x n array."""
        return np.array(self.mass_fn(t, q), dtype=float)

    def force(self, q, v, t: float = 0.0) -> np.ndarray:
        """Generalized forces F(t, q, v) as an n-vector."""
        return np.array(self.force_fn(t, q, v), dtype=float).ravel()

    def gaps(self, q, t: float | None = None) -> np.ndarray:
        """Contact gaps g(t, q), one per contact (t is needed only where a gap depends on time)."""
        return _kinematics(self, self.gap_fn, self.gap_tq_fn, q, t, "gaps").ravel()

    def contact_rates(self, q, t: float) -> np.ndarray:
        """b(t, q) = (dg/dt, ds/dt): the local velocities are u = H(t, q) v + b, rows as in H."""
        fn = self.contact_rate_fn
        return np.zeros(self.n_contact_rows) if fn is None else np.array(fn(t, q), dtype=float).ravel()

    def contact_jacobian(self, q, t: float | None = None) -> np.ndarray:
        """H(t, q): rows [H_N,1..H_N,m, then the tangent rows contact by contact], shape (m + n_tangent, n)
        (t is needed only where a contact moves)."""
        return _kinematics(self, self.H_fn, self.H_tq_fn, q, t, "contact_jacobian").reshape(self.n_contact_rows, -1)

    def contact_rows(self, active) -> np.ndarray:
        """Rows of H (and of the Delassus operator) of the contacts ``active``: their normal rows,
        then their tangent rows contact by contact (the layout of the one-step problem).

        Examples
        --------
        >>> import casadi as ca
        >>> q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
        >>> s = System(q, v, mass=ca.SX.eye(3), force=ca.vertcat(0, 0, -9.81),
        ...            contacts=[Contact(gap=q[2], tangent=q[0], mu=0.3, name="edge"),
        ...                      Contact(gap=q[2] + 1, tangent=ca.vertcat(q[0], q[1]), mu=0.3, name="foot")])
        >>> s.tangent_dims.tolist(), s.contact_rows([1]).tolist()
        ([1, 2], [1, 3, 4])
        """
        active = np.asarray(active, dtype=np.int64)
        m, off = self.n_contacts, self.tangent_offsets
        if not self.is_spatial:
            return np.concatenate([active, m + active])
        tang = [np.arange(m + off[j], m + off[j + 1]) for j in active.tolist()]
        return np.concatenate([active] + tang).astype(np.int64)

    def require_planar(self, what: str) -> None:
        """Raise a ValueError naming the first spatial contact when ``what`` handles planar contacts only."""
        if self.is_spatial:
            name = self.contacts[int(np.flatnonzero(self.tangent_dims == 2)[0])].name
            raise ValueError(f"{what} handles planar contacts only; contact {name!r} is spatial "
                             "(two tangent directions)")

    def constraint_residual(self, q, t: float = 0.0) -> np.ndarray:
        """phi(t, q), the bilateral constraint values (zero on the manifold)."""
        return np.array(self.constraints_fn(t, q)[0], dtype=float).ravel()

    def kinetic_energy(self, q, v, t: float = 0.0) -> float:
        """1/2 v' A(t, q) v."""
        return float(self.kinetic_fn(t, q, v))

    def check_state(self, q0, v0, t0: float = 0.0, mass_nonzeros=None) -> tuple[np.ndarray, np.ndarray]:
        """Validate an initial state: finite, right shape, mass matrix positive definite there.

        ``mass_nonzeros``: the nonzeros of a constant mass matrix where the caller has evaluated them
        already (the Moreau-Jean assembly), so that the check does not evaluate A again."""
        return state_checks.check_state(self, _float_array("q0", q0), _float_array("v0", v0), t0, mass_nonzeros)

    def sparse_mass(self, q, t: float = 0.0):
        """The mass matrix A(t, q) as a SciPy CSC matrix of its structural nonzeros (never dense).

        Examples
        --------
        >>> import lcp
        >>> A = lcp.scenes.block_chain(3).system.sparse_mass([0.0] * 6)
        >>> A.shape, A.nnz
        ((6, 6), 6)
        """
        return state_checks.sparse_mass(self, q, t)


def _tangent_rows(c: Contact, q, v, t, n: int, v_space) -> tuple[ca.SX, ca.SX]:
    """The tangent Jacobian rows of contact c: one (planar) or two (spatial), n columns each (n
    velocities: ds/dq T for a ``tangent``, a ``tangent_jacobian`` as given), and the tangent's time
    derivative ds/dt (zero for a given ``tangent_jacobian``)."""
    if c.tangent is not None:
        s = _sx_any(c.tangent, f"tangent of {c.name}")
        if s.numel() not in (1, 2):
            raise ValueError(f"tangent of {c.name} must be a scalar (planar contact) or two coordinates "
                             f"(spatial contact), got {s.numel()} entries")
        s = ca.reshape(s, s.numel(), 1)
        if ca.depends_on(s, v):
            raise ValueError(f"tangent of {c.name} must depend on t and q only")
        return v_space(ca.jacobian(s, q)), ca.jacobian(s, t)
    J = _sx_any(c.tangent_jacobian, f"tangent_jacobian of {c.name}")
    if J.numel() == n:  # a row or a column: one tangent
        return _sx(J, f"tangent_jacobian of {c.name}", (1, n)), ca.SX.zeros(1, 1)
    if J.shape == (2, n):
        return _sx(J, f"tangent_jacobian of {c.name}", (2, n)), ca.SX.zeros(2, 1)
    raise ValueError(f"tangent_jacobian of {c.name} must have one row (1, {n}) or two rows (2, {n}), "
                     f"got {J.shape}")


def _contact_kinematics(contacts, q, v, t, n: int, v_space) -> tuple:
    """(gaps g(t, q), normal rows H_N, tangent rows H_T, b = (dg/dt, ds/dt)) of the contacts."""
    gaps, HN, HT, gap_rates, tangent_rates = [], [], [], [], []
    for c in contacts:
        g = _sx(c.gap, f"gap of {c.name}", (1, 1))
        if ca.depends_on(g, v):
            raise ValueError(f"gap of {c.name} must depend on t and q only")
        gaps.append(g)
        HN.append(v_space(ca.jacobian(g, q)))
        rows, rate = _tangent_rows(c, q, v, t, n, v_space)
        HT.append(rows)
        gap_rates.append(ca.jacobian(g, t))
        tangent_rates.append(rate)
    if not contacts:
        return ca.SX.zeros(0, 1), HN, HT, ca.SX.zeros(0, 1)
    return ca.vertcat(*gaps), HN, HT, ca.vertcat(*(gap_rates + tangent_rates))


def _contact_functions(system, q, gap, H) -> tuple:
    """(g(q), H(q), g(t, q), H(t, q), b(t, q)) as CasADi Functions: the first two where no contact
    moves, the last three where one does (None for the others)."""
    t = system.t_sym
    if not system.contacts_depend_on_t:
        return ca.Function("gap", [q], [gap]), ca.Function("H", [q], [H]), None, None, None
    return (_NeedsTime(system, "gap_fn"), _NeedsTime(system, "H_fn"), ca.Function("gap_tq", [t, q], [gap]),
            ca.Function("H_tq", [t, q], [H]), ca.Function("contact_rate", [t, q], [system.contact_rate_expr]))


class _NeedsTime:
    """Stands for g(q) or H(q) of a system whose contacts move: calling it is a ValueError naming the
    contact (a caller written for fixed contacts would otherwise drop b = (dg/dt, ds/dt) silently)."""

    def __init__(self, system, what: str):
        self.system, self.what = system, what

    def __call__(self, *args):
        raise ValueError(f"{self.what}: contact {moving_contact(self.system)!r} has a time-dependent gap or "
                         "tangent, which this computation does not support (Moreau-Jean and the event "
                         "method do: lcp.simulate)")


def _kinematics(system, fn_q, fn_tq, q, t, what: str) -> np.ndarray:
    """fn_q(q), or fn_tq(t, q) for moving contacts (ValueError naming the contact without t)."""
    if fn_tq is None:
        return np.array(fn_q(q), dtype=float)  # fixed contacts: g(q), H(q)
    if t is None:
        raise ValueError(f"{what}: contact {moving_contact(system)!r} has a time-dependent gap or tangent: give t")
    return np.array(fn_tq(t, q), dtype=float)


def moving_contact(system) -> str | None:
    """The name of the first contact of ``system`` whose gap, tangent or Jacobian depends on t, or None."""
    if not getattr(system, "contacts_depend_on_t", False):
        return None
    m, off = system.n_contacts, system.tangent_offsets
    for j, c in enumerate(system.contacts):
        rows = [j] + [m + r for r in range(off[j], off[j + 1])]
        if _moves(ca.vertcat(system.gap_expr[j], ca.vec(system.H_expr[rows, :])), system.contact_rate_expr[rows],
                  system.t_sym):
            return c.name
    return system.contacts[0].name


def _moves(kinematics: ca.SX, rate: ca.SX, t: ca.SX) -> bool:
    """Whether contact kinematics move with time: g or H depends on t, or b = (dg/dt, ds/dt) is not
    identically zero (a belt's tangent s = x - V t has a constant H but b = -V)."""
    return bool(ca.depends_on(kinematics, t)) or not all(rate[i].is_zero() for i in range(rate.numel()))


def _sx_any(expr, name: str) -> ca.SX:
    try:
        return ca.SX(expr) if not isinstance(expr, ca.SX) else expr
    except Exception as exc:  # noqa: BLE001 - CasADi raises NotImplementedError/RuntimeError variously
        raise ValueError(f"{name} must be a CasADi SX expression or numeric array") from exc


def _breakpoints(values) -> np.ndarray:
    """Sorted, unique, finite 1-D array of times (empty for None), or ValueError naming it."""
    if values is None:
        return np.zeros(0)
    b = np.asarray(values, dtype=float).ravel()
    if not np.all(np.isfinite(b)):
        raise ValueError(f"breakpoints must be finite, got {b}")
    return np.unique(b)
