"""Event-driven integration with exact mode switches (the ``method="event"`` branch of :func:`lcp.simulate`).

Between events every contact keeps one mode (open, stick, slide+, slide-) and the motion is smooth.
Each smooth phase is integrated

- in **closed form** when the phase dynamics is polynomial in t: constant mass matrix, kinematics
  and forces (``System.is_constant`` and no state dependence of the forces). Each mode then has
  constant accelerations, so positions are quadratic in t and every event is the root of a linear
  or quadratic polynomial, computed without cancellation (a stop at ``dt = -u_T / a_T``);
- otherwise by SciPy's ``solve_ivp`` (DOP853 by default, rtol 1e-12) with event functions
  (``.terminal``, ``.direction``) located by Brent's method on the dense output.

Which integrator ran is recorded per phase (:attr:`EventResult.phases`).

Events
------
- a sliding velocity reaching zero (stop);
- a normal force reaching zero (lift-off);
- a stick force reaching the friction bound (stick -> slip);
- a gap closing (impact).

At each event the next mode comes from the **acceleration-level contact problem**. With the
closed contacts c (gap 0, normal velocity 0), the contact accelerations are affine in the contact
forces,

    a = H_c qdd + Hdot_c v = W lam + b,    qdd = qdd_free + S H_c' lam,

with S the inverse mass matrix with the bilateral constraints eliminated (the first block of
[[A, G'], [G, 0]]^-1), qdd_free the free acceleration and W = H_c S H_c'. The Coulomb law at the
acceleration level is, per closed contact j:

- normal: 0 <= N_j  perp  a_N,j >= 0;
- if u_T,j = 0 (stick candidate): |f_j| <= mu_j N_j and f_j = -mu_j N_j sign(a_T,j) if a_T,j != 0,
  i.e. exactly the complementarity structure of :class:`~lcp.contact_problem.ContactProblem`
  with impulses replaced by forces and velocities by accelerations;
- if u_T,j != 0 (sliding): f_j = -mu_j N_j sign(u_T,j), whatever a_T,j.

The sliding contacts are folded into the same :class:`~lcp.contact_problem.ContactProblem`: their
friction force is carried by the normal force's generalized direction
``d_j = H_N,j' - mu_j sign(u_T,j) H_T,j'`` (the column of W is ``H_c S d_j``, computed by one solve
with d_j so that no W_NN - mu W_NT cancellation is left to rounding), and their friction
coefficient in the problem is 0, which pins their tangential unknown to 0 and leaves only the
normal complementarity. So the Coulomb law itself stays in one place (``solve_branch``,
``admissible``, ``residual``); this module only changes variables.

The problem is solved by enumerating every branch (open / stick / slide+ / slide- for stick
candidates, open / closed for sliding contacts), which finds *all* solutions, or by Lemke's method
for many contacts. Solutions with the same acceleration are one motion (ties at a mode boundary,
broken by looking a short time ahead). When the problem has **no solution or several** (the
Painlevé cases: kappa >= 1 in the Jean-Pratt scene), the integrator applies the **impulsive
fallback**: the velocity-level impact problem, ContactProblem(W, H_c v, mu), the problem
Moreau-Jean solves in the limit h -> 0+. Its trivial solution (no impulse) is excluded by taking the
branch that Moreau-Jean's problem selects for a vanishing step (free velocity H_c v + delta b with
delta -> 0+) and re-solving that branch at delta = 0. The impulse (a tangential impact) is recorded
with its time in :attr:`EventResult.impulses`.

Cost on constant systems
------------------------
With constant mass matrix, kinematics and forces (``System.is_constant`` and no state dependence
of the forces) the acceleration-level problems, the phases' accelerations and forces, the
projection matrices and the check of the mass matrix depend on the System only: they are built
on first use and kept per System object (``_Model``), so that a later call only classifies the
contacts, finds the event times, projects the state at events and evaluates the quadratic phases
at the output times (all at once, with NumPy). The results are those of a fresh System.

Behaviour at the shock limit (Jean-Pratt, v0 > 0): for kappa < 1 the block slides with
N0 = (m+M) g / (1 - kappa) and stops at tau0 = |v0| A (1 - kappa) / (R (m+M) g); as kappa -> 1-,
tau0 -> 0, the stop distance -> 0 and the integral of the contact forces over the slide tends to
(M tan(alpha) v0, -A v0). For kappa >= 1 (kappa = 1 included: its sliding branch has a zero
effective normal mass, detected without letting rounding decide) the block stops by one tangential
impact at t = 0 with exactly those impulses, then sticks. The motion is continuous in kappa.
"""
from __future__ import annotations

from dataclasses import dataclass, field, fields
from enum import Enum
import functools
from itertools import product
import math
import weakref

import casadi as ca
import numpy as np
import scipy.linalg as sla
from scipy.integrate import solve_ivp

from .contact_problem import MODE_NAMES, OPEN, SLIDE_NEG, SLIDE_POS, STICK, ContactProblem
from .result import STATUS_MESSAGES, SimulationResult, SolverStats
from .solvers import make_solver

__all__ = ["EVENT_STATUS_MESSAGES", "SmoothIntegrator", "ModeSolver", "EventOptions", "Event", "Impulse",
           "Phase", "EventResult", "event_driven"]

_EPS = np.finfo(float).eps

#: status codes of the event integrator (the package's one table, :data:`lcp.result.STATUS_MESSAGES`)
EVENT_STATUS_MESSAGES = STATUS_MESSAGES


class SmoothIntegrator(str, Enum):
    """How smooth phases are integrated."""

    AUTO = "auto"  #: closed form when the phase dynamics is polynomial in t, SciPy otherwise
    CLOSED_FORM = "closed-form"  #: closed form only (ValueError if the system does not allow it)
    SCIPY = "scipy"  #: solve_ivp with event functions, always


class ModeSolver(str, Enum):
    """How the acceleration-level contact problem is solved at events."""

    AUTO = "auto"  #: enumeration while the number of branches is <= max_branches, else Lemke
    ENUMERATE = "enumerate"  #: every branch: finds all solutions (detects non-uniqueness)
    LEMKE = "lemke"  #: Lemke's method on the LCP form (one solution; no uniqueness check)


_ODE_METHODS = ("DOP853", "RK45", "RK23", "Radau", "BDF", "LSODA")


def _enum_value(enum, name, value):
    member = _ENUM_MEMBERS[enum].get(value) if isinstance(value, str) else None
    if member is not None:
        return member
    try:
        return enum(value)
    except ValueError:
        raise ValueError(f"{name} must be one of {[e.value for e in enum]}, got {value!r}") from None


#: members by value (a str Enum member is its own value): Enum(value) without the metaclass call
_ENUM_MEMBERS = {enum: {e.value: e for e in enum} for enum in (SmoothIntegrator, ModeSolver)}
_AUTO_SMOOTH, _CLOSED_FORM, _SCIPY = SmoothIntegrator.AUTO, SmoothIntegrator.CLOSED_FORM, SmoothIntegrator.SCIPY
_AUTO_SOLVER, _ENUMERATE = ModeSolver.AUTO, ModeSolver.ENUMERATE


_NO_CONTACTS = np.zeros(0, dtype=int)
_NO_CONTACTS.setflags(write=False)


def _finite(x) -> bool:
    """np.isfinite(x).all() for a 1-D array, without NumPy's per-call overhead when small."""
    if x.size <= 16:
        return all(map(math.isfinite, x.tolist()))
    return bool(np.isfinite(x).all())


def _absmax(x) -> float:
    """float(np.max(np.abs(x))) for a non-empty 1-D array, without NumPy's per-call overhead when small."""
    if x.size <= 16:
        return float(max(map(abs, x.tolist())))
    return float(np.max(np.abs(x)))


@dataclass(frozen=True, eq=False)
class EventOptions:
    """Validated options of the event-driven integrator.

    Parameters
    ----------
    t_eval : array_like, optional
        Output times, increasing, inside [0, t_end]. Default: ``n_eval`` equally spaced times
        from 0 to t_end.
    n_eval : int
        Number of default output times (>= 2).
    smooth : {"auto", "closed-form", "scipy"}
        Integrator of the smooth phases (:class:`SmoothIntegrator`).
    ode_method : str
        ``solve_ivp`` method for non-polynomial phases (DOP853, RK45, RK23, Radau, BDF, LSODA).
    rtol, atol : float
        ``solve_ivp`` tolerances.
    mode_solver : {"auto", "enumerate", "lemke"}
        Solver of the acceleration-level problem (:class:`ModeSolver`).
    impact_solver : str
        One-step solver of the velocity-level impact problem (``"auto"``, ``"enum"``, ``"lemke"``,
        ``"osqp"``; see :func:`lcp.solvers.make_solver`).
    max_branches : int
        Largest number of branches enumerated by ``mode_solver="auto"``.
    max_events : int
        Largest number of events before the integration stops with status -4.
    tol : float
        Relative tolerance of the zero tests (a velocity, a gap or a force "is zero"), relative
        to the scene's velocity, length and force scales.
    """

    t_eval: object = None
    n_eval: int = 1000
    smooth: str = "auto"
    ode_method: str = "DOP853"
    rtol: float = 1e-12
    atol: float = 1e-14
    mode_solver: str = "auto"
    impact_solver: str = "auto"
    max_branches: int = 4096
    max_events: int = 10_000
    tol: float = 1e-10

    def __post_init__(self):
        set_ = object.__setattr__
        set_(self, "smooth", _enum_value(SmoothIntegrator, "smooth", self.smooth))
        set_(self, "mode_solver", _enum_value(ModeSolver, "mode_solver", self.mode_solver))
        if self.ode_method not in _ODE_METHODS:
            raise ValueError(f"ode_method must be one of {list(_ODE_METHODS)}, got {self.ode_method!r}")
        defaults = _OPTION_DEFAULTS
        for name in ("rtol", "atol", "tol"):
            val = getattr(self, name)
            if val is defaults[name]:
                continue  # the default, valid
            if not isinstance(val, (int, float, np.floating)) or not math.isfinite(val) or val <= 0:
                raise ValueError(f"{name} must be finite and > 0, got {val!r}")
        for name, low in (("n_eval", 2), ("max_branches", 1), ("max_events", 1)):
            val = getattr(self, name)
            if val is defaults[name]:
                continue
            if not isinstance(val, (int, np.integer)) or isinstance(val, bool) or val < low:
                raise ValueError(f"{name} must be an integer >= {low}, got {val!r}")
        if not (isinstance(self.impact_solver, str) and self.impact_solver in _VALID_SOLVER_NAMES):
            make_solver(self.impact_solver)  # raises ValueError naming the known solvers
            if isinstance(self.impact_solver, str):
                _VALID_SOLVER_NAMES.add(self.impact_solver)
        if self.t_eval is not None:
            te = np.array(self.t_eval, dtype=float).ravel()
            # strictly increasing with finite ends: all finite (a NaN fails every comparison)
            ok = (te.size and math.isfinite(te[0]) and math.isfinite(te[-1])
                  and (te.size == 1 or (te[1:] > te[:-1]).all()))
            if not ok and (te.size == 0 or not np.isfinite(te).all()):
                raise ValueError("t_eval must be a non-empty array of finite times")
            if not ok or te[0] < 0:
                raise ValueError("t_eval must be strictly increasing and >= 0")
            te.setflags(write=False)
            set_(self, "t_eval", te)

    @classmethod
    def from_kwargs(cls, **options) -> "EventOptions":
        """Build from keyword arguments; unknown names raise ValueError listing the known ones."""
        known = _OPTION_NAMES
        if not known.issuperset(options):
            names = [f.name for f in fields(cls)]
            unknown = sorted(set(options) - known)
            raise ValueError(f"unknown option(s) {unknown} for method 'event'; known options: {names}")
        return cls(**options)

    def output_times(self, t_end: float) -> np.ndarray:
        if self.t_eval is None:
            return np.linspace(0.0, t_end, self.n_eval)
        if self.t_eval[-1] > t_end:
            raise ValueError(f"t_eval must lie inside [0, t_end = {t_end!r}], got a last time {self.t_eval[-1]!r}")
        return np.array(self.t_eval)


_OPTION_NAMES = frozenset(f.name for f in fields(EventOptions))
_OPTION_DEFAULTS = {f.name: f.default for f in fields(EventOptions)}
_VALID_SOLVER_NAMES: set = set()  # impact-solver names make_solver accepted (no need to build one again)


# ---------------------------------------------------------------------------------------- records
@dataclass(frozen=True)
class Event:
    """One event: its time, kind and contact.

    ``kind`` is one of ``"stop"`` (sliding velocity reached zero), ``"lift-off"`` (normal force
    reached zero), ``"slip"`` (stick force reached the friction bound), ``"impact"`` (gap closed),
    ``"tangential impact"`` (impulsive fallback of the Painlevé cases).
    """

    t: float
    kind: str
    contact: int


def _record(cls, *values):
    """``cls(*values)`` for the frozen record dataclasses (Event, Phase), without the per-field
    ``object.__setattr__`` of their generated ``__init__`` (they have no ``__post_init__``)."""
    obj = object.__new__(cls)
    obj.__dict__.update(zip(_RECORD_FIELDS[cls], values))
    return obj


@dataclass(frozen=True)
class Impulse:
    """An impulse applied at time ``t`` to one contact: normal ``P_N`` and tangential ``P_T``.

    ``reason`` says why: an impact (gap closing with approach velocity) or the impulsive fallback
    of an acceleration-level problem with no solution or several (Painlevé).
    """

    t: float
    contact: int
    P_N: float
    P_T: float
    kind: str
    reason: str


@dataclass(frozen=True)
class Phase:
    """One smooth phase [t0, t1): contact modes (names, one per contact) and the integrator used."""

    t0: float
    t1: float
    modes: tuple
    integrator: str
    nfev: int = 0


_RECORD_FIELDS = {cls: tuple(f.name for f in fields(cls)) for cls in (Event, Phase)}


@dataclass(repr=False)
class EventResult(SimulationResult):
    """Result of :func:`event_driven`: a :class:`~lcp.result.SimulationResult` plus the events.

    Attributes (besides those of SimulationResult)
    ----------------------------------------------
    t : ndarray, shape (n_points,)
        The requested output times (``t_eval``); q and v are exact-in-time values there (right
        limits at an impulse).
    p_N, p_T : ndarray, shape (n_points - 1, m)
        Contact impulses over each output interval [t_i, t_{i+1}): the contact forces integrated
        plus the impulses applied in the interval (as Moreau-Jean's p over a step).
    modes : ndarray of int8, shape (n_points - 1, m)
        Mode of each contact at t_i (right limit): 0 open, 1 stick, 2 slide+, 3 slide-.
    force_N, force_T : ndarray, shape (n_points, m)
        Contact forces at the output times (right limits).
    t_events : list of float
        Times of the events (mode switches and impulses), in order.
    events : list of Event
    impulses : list of Impulse
        Every impulse: impacts and the tangential impacts of the impulsive fallback.
    phases : list of Phase
        The smooth phases with their modes and the integrator used.
    """

    force_N: np.ndarray = None
    force_T: np.ndarray = None
    events: list = field(default_factory=list)
    impulses: list = field(default_factory=list)
    phases: list = field(default_factory=list)

    @property
    def mode_sequence(self) -> list:
        """Modes per phase (tuples of mode names, one per contact), repeats at events merged."""
        seq = []
        for ph in self.phases:
            if not seq or seq[-1] != ph.modes:
                seq.append(ph.modes)
        return seq

    @property
    def integrators(self) -> list:
        """The smooth-phase integrators used, without repeats, in order of first use."""
        return list(dict.fromkeys(ph.integrator for ph in self.phases))

    @property
    def N(self) -> np.ndarray:
        """Mean normal force over each output interval, p_N / dt, shape (n_points - 1, m)."""
        return self.p_N / np.diff(self.t)[:, None]

    @property
    def f(self) -> np.ndarray:
        """Mean friction force over each output interval, p_T / dt, shape (n_points - 1, m)."""
        return self.p_T / np.diff(self.t)[:, None]

    def __repr__(self) -> str:
        return (f"EventResult(method='event', phases={len(self.phases)}, events={len(self.events)}, "
                f"impulses={len(self.impulses)}, integrators={self.integrators}, status={self.status}, "
                f"message={self.message!r})")


# ---------------------------------------------------------------------------------------- model
_ACCEL_FUNCTIONS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _accel_function(system) -> ca.Function:
    """CasADi Function (t, q, v) -> (A, F, G, zeta, H, Hdot v, gap), built once per system.

    zeta is the velocity-dependent part of the bilateral constraints' second time derivative:
    d2/dt2 phi(t, q) = G qdd + zeta.
    """
    fn = _ACCEL_FUNCTIONS.get(system)
    if fn is None:
        t, q, v = system.t_sym, system.q_sym, system.v_sym
        c = system.constraints_expr
        G = ca.jacobian(c, q)
        phi_t = ca.jacobian(c, t)
        Gv = ca.mtimes(G, v)
        zeta = (ca.jtimes(Gv, q, v) + ca.jacobian(Gv, t) + ca.jtimes(phi_t, q, v) + ca.jacobian(phi_t, t))
        H = system.H_expr
        Hdv = ca.jtimes(ca.mtimes(H, v), q, v)
        fn = ca.Function("event_accel_data", [t, q, v],
                         [system.mass_expr, system.force_expr, G, zeta, H, Hdv, system.gap_expr])
        _ACCEL_FUNCTIONS[system] = fn
    return fn


class _Data:
    """Everything the contact problems need at one state, with the KKT matrix factorized once."""

    def __init__(self, A, F, G, zeta, H, Hdv, gap, check: bool = False):
        self.A, self.F, self.G, self.zeta, self.H, self.Hdv, self.gap = A, F, G, zeta, H, Hdv, gap
        n, nb = A.shape[0], G.shape[0]
        self.n, self.nb = n, nb
        self.K = K = np.block([[A, G.T], [G, np.zeros((nb, nb))]]) if nb else A
        # LU with partial pivoting per solve (LAPACK gesv): for these tiny systems it is faster than
        # reusing a factorization through scipy.linalg.lu_solve, whose multi-column path is slow
        if check:
            d = np.abs(sla.lu_factor(K, check_finite=False)[0].diagonal())
            if not np.all(np.isfinite(d)) or np.any(d <= 1e-14 * max(1.0, float(np.max(np.abs(K))))):
                raise ValueError("the mass matrix is singular on the constraint manifold")
        self._qdd_free = None

    def solve_dirs(self, D: np.ndarray) -> np.ndarray:
        """S D: accelerations produced by generalized forces D (columns), bilateral constraints held."""
        if self.nb:
            D = np.vstack([D, np.zeros((self.nb, D.shape[1]))])
        return np.linalg.solve(self.K, D)[: self.n]

    @property
    def qdd_free(self) -> np.ndarray:
        """Acceleration with no contact force (bilateral constraints held)."""
        if self._qdd_free is None:
            rhs = np.concatenate([self.F, -self.zeta]) if self.nb else self.F
            self._qdd_free = np.linalg.solve(self.K, rhs)[: self.n]
        return self._qdd_free


class _Model:
    """Evaluates the system; when it is constant, assembles once and never calls CasADi again.

    For a constant system it also keeps what depends on the system only, built on first use and
    reused by every later integration of the same System object:

    - ``state_checked``: the mass matrix was validated (``System.check_state``) once; it is the same
      at every state, so later calls only check the shapes and finiteness of q0 and v0;
    - ``projector(key, J)``: the mass-metric correction matrix A^-1 J' (J A^-1 J')^+ of a set of
      constraint rows (the projections after an event apply it to a rounding-level residual);
    - for polynomial systems (constant forces as well), the contact problems of the mode decision
      do not depend on the state at all: ``mode_memo`` keeps their solutions per (closed contacts,
      slide signs, allowed modes, solver), with the solver statistics to replay, and ``phase_memo``
      the per-mode data of a closed-form phase.
    """

    def __init__(self, system):
        self.sys = system
        self.n, self.m, self.nb = system.n, system.n_contacts, system.n_bilateral
        self.all_contacts = tuple(range(self.m))
        self.constant = system.is_constant
        # polynomial (quadratic) phases: constant mass, kinematics and forces
        self.polynomial = self.constant and not system.force_depends_on_state
        self.state_checked = False
        if self.constant:
            n, m = self.n, self.m
            z = np.zeros(n)
            A, F0, K, C, G, phi_t, gap0, H = (np.array(x, dtype=float) for x in system.step_data_fn(0.0, z, z))
            self.A, self.G = A.reshape(n, n), G.reshape(system.n_bilateral, n)
            self.phi_t = phi_t.ravel()
            self.F0, self.Kq, self.Cv = F0.ravel(), -K.reshape(n, n), -C.reshape(n, n)
            self.H, self.gap0 = H.reshape(2 * m, n), gap0.ravel()
            self.HN = np.ascontiguousarray(self.H[:m])
            self.A_max = float(np.max(np.abs(self.A))) if n else 0.0
            self._const_data = _Data(self.A, self.F0, self.G, np.zeros(system.n_bilateral), self.H,
                                     np.zeros(2 * m), self.gap0, check=True)
            self._proj = {}
            self.mode_memo = {}
            self.phase_memo = {}
            self.impact_memo = {}
            self.free_ready = {}  # closed-form phase data with no closed contact (_ClosedFormPhase.ready)
        else:
            self.fn = _accel_function(system)

    def data(self, t, q, v) -> _Data:
        if self.constant:
            if self.polynomial:
                return self._const_data  # nothing depends on the state (gaps: see gaps())
            d = _Data.__new__(_Data)
            d.__dict__.update(self._const_data.__dict__)  # shares the factorization
            d.gap = self.gap0 + self.HN @ q
            d.F = self.F0 + self.Kq @ q + self.Cv @ v
            d._qdd_free = None
            return d
        n, m, nb = self.n, self.m, self.sys.n_bilateral
        A, F, G, zeta, H, Hdv, gap = (np.array(x, dtype=float) for x in self.fn(t, q, v))
        return _Data(A.reshape(n, n), F.ravel(), G.reshape(nb, n), zeta.ravel(), H.reshape(2 * m, n),
                     Hdv.ravel(), gap.ravel())

    def gaps(self, q) -> np.ndarray:
        if self.constant:
            return self.gap0 + self.HN @ q
        return self.sys.gaps(q)

    def jac(self, q) -> np.ndarray:
        """H(q), rows [H_N; H_T]."""
        if self.constant:
            return self.H
        return self.sys.contact_jacobian(q)

    def projector(self, key, rows) -> np.ndarray:
        """Constant system: the matrix C with _mass_projection(A, J, r) = C r, J = vstack(rows)."""
        C = self._proj.get(("C",) + key)
        if C is None:
            J = np.vstack(rows)
            AJ = np.linalg.solve(self.A, J.T)
            C = self._proj[("C",) + key] = AJ @ np.linalg.lstsq(J @ AJ, np.eye(J.shape[0]), rcond=None)[0]
        return C


# ---------------------------------------------------------------------------- contact problems
class _Accel:
    """The acceleration-level problem of the closed contacts ``idx``, sliding ones folded in.

    ``slide[j]`` is the sign of the sliding velocity of closed contact j (0 for a stick
    candidate). The ContactProblem is (W', b, mu') with W' = H_c S D, D = H_c' except that a
    sliding contact's normal column is d_j = H_N,j' - mu_j slide_j H_T,j', and mu'_j = 0 for
    sliding contacts. Its unknowns are p = (N, f) with f_j = 0 for sliding contacts, whose friction
    force is -mu_j slide_j N_j.
    """

    def __init__(self, data: _Data, idx, slide, mu, flush: bool = False):
        self.idx = idx = np.asarray(idx, dtype=int)
        self.slide = slide = np.asarray(slide, dtype=float)
        self.k = k = idx.size
        m = data.H.shape[0] // 2
        self.mu = mu[idx]
        rows = np.concatenate([idx, m + idx])
        Hc = data.H[rows]
        D = Hc.T.copy()
        sl = np.flatnonzero(slide != 0)
        D[:, sl] = Hc[sl].T - (self.mu[sl] * slide[sl]) * Hc[k + sl].T
        self.SD = data.solve_dirs(D)
        W = Hc @ self.SD
        if flush and sl.size:
            # A folded column is a difference; entries at the rounding level of its two terms are
            # zero (kappa = 1 exactly must not be decided by rounding).
            SH = data.solve_dirs(Hc[np.concatenate([sl, k + sl])].T)
            ref = np.abs(Hc @ SH[:, : sl.size]) + self.mu[sl] * np.abs(Hc @ SH[:, sl.size:])
            Wc = W[:, sl]
            Wc[np.abs(Wc) <= 16 * _EPS * ref] = 0.0
            W[:, sl] = Wc
        self.qdd_free = data.qdd_free
        b = Hc @ self.qdd_free + data.Hdv[rows]
        mu_p = np.where(slide != 0, 0.0, self.mu)
        self.pb = ContactProblem(W, b, mu_p)

    def forces(self, p) -> tuple[np.ndarray, np.ndarray]:
        """Physical (N, f) of the closed contacts from the problem's unknowns p."""
        k = self.k
        N = p[:k]
        f = np.where(self.slide != 0, -self.mu * self.slide * N, p[k:])
        return N, f

    def qdd(self, p) -> np.ndarray:
        return self.qdd_free + self.SD @ p

    def branch_modes(self, modes) -> list:
        """Modes for ``solve_branch``: a closed sliding contact solves with p_T = 0 (its mu' is 0)."""
        return [SLIDE_POS if (s != 0 and md != OPEN) else md for md, s in zip(modes, self.slide)]

    def check_modes(self, modes) -> list:
        """Modes for ``admissible``: a closed sliding contact is checked as 'stick' with mu' = 0,
        i.e. p_T = 0 and p_N >= 0, with no condition on a_T (the slide direction is the velocity's)."""
        return [STICK if (s != 0 and md != OPEN) else md for md, s in zip(modes, self.slide)]


@dataclass(eq=False)
class _Solution:
    modes: tuple  # per closed contact: OPEN / STICK / SLIDE_POS / SLIDE_NEG (sliding: SLIDE_*)
    p: np.ndarray
    qdd: np.ndarray
    #: closed-form phase data of this solution (_ClosedFormPhase.ready), per closed set
    ready: dict = field(default_factory=dict, repr=False)


def _enumerate(acc: _Accel, allowed=None) -> tuple[list, int]:
    """Every branch of the acceleration problem that satisfies the Coulomb law; (solutions, tried)."""
    pb = acc.pb
    choices = []
    for j in range(acc.k):
        if acc.slide[j] != 0:
            s = SLIDE_POS if acc.slide[j] > 0 else SLIDE_NEG
            choices.append((OPEN, s))
        else:
            choices.append((OPEN, STICK, SLIDE_POS, SLIDE_NEG))
    sols, tried = [], 0
    for modes in product(*choices):
        if allowed is not None and modes not in allowed:
            continue
        tried += 1
        p = pb.solve_branch(acc.branch_modes(modes))
        if p is None or not pb.admissible(p, acc.check_modes(modes)):
            continue
        sols.append(_Solution(modes, p, acc.qdd(p)))
    return sols, tried


def _boundary_alternatives(acc: _Accel, modes, p, rtol: float = 1e-9) -> list:
    """Per closed contact, the modes that describe the same solution p when p is on a boundary
    between modes (stick force on the friction bound, zero tangential or normal acceleration,
    zero normal force)."""
    pb, k = acc.pb, acc.k
    a = pb.velocity(p)
    tol = rtol * max(pb.scale, float(np.max(np.abs(p))) if k else 0.0)
    alts = []
    for j, md in enumerate(modes):
        alt = {md}
        sliding = acc.slide[j] != 0
        closed_mode = (SLIDE_POS if acc.slide[j] > 0 else SLIDE_NEG) if sliding else STICK
        if md == OPEN:
            if abs(a[j]) * pb.rho[j] <= tol:
                alt.add(closed_mode)
        else:
            if p[j] <= tol:
                alt.add(OPEN)
            if not sliding:
                aT = a[k + j] * pb.rho[k + j]
                if md == STICK and acc.mu[j] * p[j] - abs(p[k + j]) <= tol:
                    alt.add(SLIDE_POS if p[k + j] < 0 else SLIDE_NEG)
                if md in (SLIDE_POS, SLIDE_NEG) and abs(aT) <= tol:
                    alt.add(STICK)
        alts.append(tuple(sorted(alt)))
    return alts


def _group(sols: list, qdd_scale: float) -> list:
    """Group solutions by motion: equal accelerations are one motion (ties at a mode boundary)."""
    if len(sols) <= 1:
        return [list(sols)] if sols else []
    groups = []
    for s in sols:
        for g in groups:
            if np.max(np.abs(g[0].qdd - s.qdd)) <= 1e-9 * qdd_scale:
                g.append(s)
                break
        else:
            groups.append([s])
    return groups


# ---------------------------------------------------------------------------------- phases
@functools.lru_cache(maxsize=4096)
def _phase_static(m: int, idx: tuple, modes: tuple) -> tuple:
    """What a phase needs from its closed contacts and modes alone (shared, read-only arrays):
    (modes, idx, slide signs, open contacts, modes of all contacts, mode names, sliding (j, sign, row of
    H_T,j) triples, idx as a tuple)."""
    idx_a = np.array(idx, dtype=int)
    slide = np.array([1.0 if md == SLIDE_POS else (-1.0 if md == SLIDE_NEG else 0.0) for md in modes])
    closed = set(idx)
    open_idx = np.array([j for j in range(m) if j not in closed], dtype=int)
    full = np.full(m, OPEN, dtype=np.int8)
    full[idx_a] = modes
    names = tuple(MODE_NAMES[int(c)] for c in full)
    sliding = tuple((j, s, m + j) for j, s in zip(idx, slide.tolist()) if s != 0)
    for arr in (idx_a, slide, open_idx, full):
        arr.setflags(write=False)
    return modes, idx_a, slide, open_idx, full, names, sliding, idx


class _Phase:
    """Common part of a smooth phase: fixed closed set, slide signs and stick set."""

    def __init__(self, model, t0, q0, v0, P0, idx, modes, mu, static=None):
        self.model = model
        self.t0, self.q0, self.v0, self.P0 = t0, q0, v0, P0
        self.mu = mu
        if static is None:  # modes: per closed contact, never OPEN
            static = _phase_static(model.m, tuple(np.asarray(idx, dtype=int).tolist()), tuple(map(int, modes)))
        self.static = static
        (self.modes, self.idx, self.slide, self.open_idx, self.full_modes, self._names, self._sliding,
         self.idx_t) = static

    def names(self) -> tuple:
        return self._names

    def accel(self, data):
        acc = _Accel(data, self.idx, self.slide, self.mu)
        p = acc.pb.solve_branch(acc.branch_modes(self.modes))
        if p is None:
            raise FloatingPointError("singular contact branch in a smooth phase")
        N, f = acc.forces(p)
        return acc.qdd(p), N, f


class _ClosedFormPhase(_Phase):
    """Constant accelerations: q = q0 + v0 dt + qdd dt^2/2; events are polynomial roots."""

    integrator = "closed-form"
    nfev = 0

    def __init__(self, *args, start=None):
        super().__init__(*args)
        self.H = self.model.H
        if start is None:
            data = self.model.data(self.t0, self.q0, self.v0)
            self.qdd, N, f = self.accel(data)
        else:  # the accelerations and forces the mode decision already solved for
            self.qdd, N, f = start
        # The constraints of this mode hold at the acceleration level up to rounding (1e-16 |qdd|),
        # which dt^2/2 amplifies over long phases; one mass-metric projection makes it eps^2.
        rows = [self.model.G, self.model.H[self.idx], self.model.H[self.model.m + self.idx[self.slide == 0]]]
        J = np.vstack(rows)
        if J.shape[0]:
            self.qdd = self.qdd - _mass_projection(self.model.A, J, J @ self.qdd)
        m = self.model.m
        self.N = np.zeros(m)
        self.f = np.zeros(m)
        self.N[self.idx], self.f[self.idx] = N, f
        self.NF = np.concatenate([self.N, self.f])
        # per sliding contact: (j, sign, H_T,j, tangential acceleration H_T,j qdd)
        self._slide_rows = tuple((j, s, self.H[row], self.H[row] @ self.qdd) for j, s, row in self._sliding)

    def ready(self) -> tuple:
        """What a later phase of the same modes and accelerations reuses (:meth:`from_ready`)."""
        for arr in (self.qdd, self.N, self.f, self.NF):
            arr.setflags(write=False)
        return self.static, (self.H, self.qdd, self.N, self.f, self.NF, self._slide_rows)

    @classmethod
    def from_ready(cls, model, t0, q0, v0, P0, mu, ready):
        """The phase of the same modes and accelerations as the one ``ready`` came from."""
        ph = cls.__new__(cls)
        ph.model, ph.t0, ph.q0, ph.v0, ph.P0, ph.mu = model, t0, q0, v0, P0, mu
        ph.static, (ph.H, ph.qdd, ph.N, ph.f, ph.NF, ph._slide_rows) = ready
        (ph.modes, ph.idx, ph.slide, ph.open_idx, ph.full_modes, ph._names, ph._sliding, ph.idx_t) = ph.static
        return ph

    def run(self, t_stop):
        """First event before t_stop: (t_event, kind, contact) or None."""
        H = self.H
        best = (math.inf, None, -1)
        for j, s, Hrow, a in self._slide_rows:
            u0 = Hrow @ self.v0
            if s * a < 0 and s * u0 > 0:
                dt = -u0 / a  # cancellation-free: one division
                if dt < best[0]:
                    best = (dt, "stop", int(j))
        if len(self.open_idx):
            gap = self.model.gaps(self.q0)
            for j in self.open_idx:
                dt = _first_landing(gap[j], H[j] @ self.v0, H[j] @ self.qdd)
                if dt < best[0]:
                    best = (dt, "impact", int(j))
        dt, kind, j = best
        if not self.t0 + dt < t_stop:
            self.t1 = t_stop
            return None
        self.t1 = self.t0 + dt
        return self.t1, kind, j

    def end_state(self):
        dt = self.t1 - self.t0
        v1 = self.v0 + dt * self.qdd
        q1 = self.q0 + dt * 0.5 * (self.v0 + v1)  # exact for constant acceleration, no cancellation
        return q1, v1, self.P0 + dt * self.NF

    def output(self, t, out):
        """Write (q, v, cumulative impulses) at the times t into the columns of ``out``
        (shape (2n + 2m, t.size)); return the forces (N, f), the same at every time."""
        _closed_form_output([self], t, [t.size], out)
        return self.N, self.f


def _closed_form_output(phases, t, counts, out):
    """Closed-form phases, consecutive, on consecutive output times t (``counts[i]`` of them in
    phase i): write the rows (q, v, cumulative impulses) of ``out`` (shape (2n + 2m, t.size)).

    Elementwise q0 + dt v0 + dt^2/2 qdd, v0 + dt qdd and P0 + dt (N, f), evaluated in that order
    (dt = t - t0), with each phase's constants repeated over its columns: long contiguous rows
    for every phase at once, rather than NumPy's slow broadcasting of short ones.
    """
    n, r = phases[0].q0.size, out.shape[0]
    Y0 = np.concatenate([x for ph in phases for x in (ph.q0, ph.v0, ph.P0)]).reshape(len(phases), r).T
    Y1 = np.concatenate([x for ph in phases for x in (ph.v0, ph.qdd, ph.NF)]).reshape(len(phases), r).T
    if len(phases) == 1:
        dt = t - phases[0].t0
    else:
        dt = t - np.array([ph.t0 for ph in phases]).repeat(counts)
        Y0, Y1 = Y0.repeat(counts, axis=1), Y1.repeat(counts, axis=1)
    h = 0.5 * dt
    h *= dt
    quad = h * Y1[n:2 * n]  # dt^2/2 qdd
    np.multiply(dt, Y1, out=out)
    np.add(Y0, out, out=out)
    np.add(out[:n], quad, out=out[:n])


def _first_landing(g0: float, u: float, a: float) -> float:
    """Smallest dt > 0 with g0 + u dt + a dt^2/2 = 0 and the gap decreasing; inf if none.

    Roots by the cancellation-free pair q/(a/2) and g0/q with q = -(u + sign(u) sqrt(disc))/2.
    """
    h = 0.5 * a
    if h == 0.0:
        return -g0 / u if u < 0 and g0 >= 0 else math.inf
    disc = u * u - 4.0 * h * g0
    if disc < 0:
        return math.inf
    qq = -0.5 * (u + math.copysign(math.sqrt(disc), u))
    roots = [qq / h]
    if qq != 0.0:
        roots.append(g0 / qq)
    good = [r for r in roots if r > 0 and u + a * r <= 0]
    return min(good) if good else math.inf


class _OdePhase(_Phase):
    """solve_ivp on y = (q, v, cumulative contact impulses), with terminal event functions."""

    def __init__(self, *args, options: EventOptions, scales):
        super().__init__(*args)
        self.options = options
        self.integrator = options.ode_method
        self.scales = scales
        self._cache_key = None
        self.linear = self.model.constant  # affine forces: the whole phase is a linear ODE y' = L y + c
        if self.linear:
            self._build_linear()

    # --- dynamics
    def _build_linear(self):
        """For a constant system with affine forces: y' = L y + c, built once per phase.

        The branch solution is linear in the free contact acceleration b; its matrix comes from
        ``solve_branch`` on unit right-hand sides (the Coulomb law is not rewritten here).
        """
        model, n, m = self.model, self.model.n, self.model.m
        data = model.data(self.t0, np.zeros(n), np.zeros(n))
        acc = _Accel(data, self.idx, self.slide, self.mu)
        k = acc.k
        modes = acc.branch_modes(self.modes)
        Pi = np.zeros((2 * k, 2 * k))
        for i in range(2 * k):
            e = np.zeros(2 * k)
            e[i] = 1.0
            p = ContactProblem(acc.pb.W, e, acc.pb.mu).solve_branch(modes)
            if p is None:
                raise FloatingPointError("singular contact branch in a smooth phase")
            Pi[:, i] = p
        rows = np.concatenate([self.idx, m + self.idx])
        Hc = model.H[rows]
        # qdd_free = S (F0 + Kq q + Cv v): columns by solves
        Sfree = data.solve_dirs(np.column_stack([model.F0, model.Kq, model.Cv]))
        s0, Sq, Sv = Sfree[:, 0], Sfree[:, 1:n + 1], Sfree[:, n + 1:]
        # p = Pi b, b = Hc qdd_free
        Pq, Pv, p0 = Pi @ Hc @ Sq, Pi @ Hc @ Sv, Pi @ Hc @ s0
        Qq, Qv, q0 = Sq + acc.SD @ Pq, Sv + acc.SD @ Pv, s0 + acc.SD @ p0
        # physical forces of all contacts: N = p[:k]; f = p[k:] or -mu s N
        fold = np.zeros((2 * m, 2 * k))
        fold[self.idx, np.arange(k)] = 1.0
        for jj, j in enumerate(self.idx):
            if self.slide[jj] != 0:
                fold[m + j, jj] = -self.mu[j] * self.slide[jj]
            else:
                fold[m + j, k + jj] = 1.0
        L = np.zeros((2 * n + 2 * m, 2 * n + 2 * m))
        c = np.zeros(2 * n + 2 * m)
        L[:n, n:2 * n] = np.eye(n)
        L[n:2 * n, :n], L[n:2 * n, n:2 * n], c[n:2 * n] = Qq, Qv, q0
        L[2 * n:, :n], L[2 * n:, n:2 * n], c[2 * n:] = fold @ Pq, fold @ Pv, fold @ p0
        self.L, self.c = L, c

    def _eval(self, t, y):
        """(ydot, N (m), f (m)) at (t, y), cached for the event functions at the same point."""
        key = (t, y.tobytes())
        if key == self._cache_key:
            return self._cache
        n, m = self.model.n, self.model.m
        if self.linear:
            yd = self.L @ y + self.c
            out = (yd, yd[2 * n:2 * n + m], yd[2 * n + m:])
        else:
            q, v = y[:n], y[n:2 * n]
            data = self.model.data(t, q, v)
            qdd, N, f = self.accel(data)
            Nm, fm = np.zeros(m), np.zeros(m)
            Nm[self.idx], fm[self.idx] = N, f
            out = (np.concatenate([v, qdd, Nm, fm]), Nm, fm)
        self._cache_key, self._cache = key, out
        return out

    def _rhs(self, t, y):
        return self._eval(t, y)[0]

    # --- events
    def _event_functions(self):
        n, m = self.model.n, self.model.m
        model = self.model
        evs, meta = [], []

        def make(fun, kind, j):
            fun.terminal, fun.direction = True, -1
            evs.append(fun)
            meta.append((kind, int(j)))

        for jj, j in enumerate(self.idx):
            s = self.slide[jj]
            if s != 0:
                make(lambda t, y, j=j, s=s: s * float(model.jac(y[:n])[m + j] @ y[n:2 * n]), "stop", j)
            make(lambda t, y, j=j: float(self._eval(t, y)[1][j]), "lift-off", j)
            if s == 0:
                mu = self.mu[j]
                make(lambda t, y, j=j, mu=mu: float(mu * self._eval(t, y)[1][j] - self._eval(t, y)[2][j]), "slip", j)
                make(lambda t, y, j=j, mu=mu: float(mu * self._eval(t, y)[1][j] + self._eval(t, y)[2][j]), "slip", j)
        for j in self.open_idx:
            make(lambda t, y, j=j: float(model.gaps(y[:n])[j]), "impact", j)
        return evs, meta

    def run(self, t_stop):
        n = self.model.n
        y0 = np.concatenate([self.q0, self.v0, self.P0])
        evs, meta = self._event_functions()
        o = self.options
        atol = np.concatenate([np.full(n, o.atol * self.scales["L"]), np.full(n, o.atol * self.scales["V"]),
                               np.full(self.P0.size, o.atol * self.scales["P"])])
        sol = solve_ivp(self._rhs, (self.t0, t_stop), y0, method=o.ode_method, rtol=o.rtol, atol=atol,
                        events=evs, dense_output=True)
        self.nfev = sol.nfev
        self.sol = sol
        if sol.status < 0:
            raise FloatingPointError(f"solve_ivp ({o.ode_method}) failed at t = {sol.t[-1]:.10g}: {sol.message}")
        self.y1 = sol.y[:, -1]
        if sol.status == 1:
            first = min((float(te[0]), i) for i, te in enumerate(sol.t_events) if te.size)
            self.t1 = first[0]
            self.y1 = sol.y_events[first[1]][0]
            kind, j = meta[first[1]]
            return self.t1, kind, j
        self.t1 = t_stop
        return None

    def end_state(self):
        n = self.model.n
        y = self.y1
        return y[:n].copy(), y[n:2 * n].copy(), y[2 * n:].copy()

    def output(self, t, out):
        """Write (q, v, cumulative impulses) at the times t into the columns of ``out``; return (N, f)."""
        m = self.model.m
        Y = self.sol.sol(t) if t.size else np.zeros((out.shape[0], 0))
        out[:] = Y
        N = np.zeros((t.size, m))
        f = np.zeros((t.size, m))
        for i in range(t.size):
            _, N[i], f[i] = self._eval(float(t[i]), Y[:, i])
        return N, f


# --------------------------------------------------------------------------------- integrator
_MODELS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _model(system) -> _Model:
    """The evaluator of a system, built once (a constant system is then assembled only once)."""
    model = _MODELS.get(system)
    if model is None:
        model = _MODELS[system] = _Model(system)
    return model


class _Integrator:
    def __init__(self, system, q0, v0, t_end, options: EventOptions):
        self.sys = system
        self.model = _model(system)
        self.o = options
        self.t_end = t_end
        self.mu, self.e = system.mu, system.e
        n, m = system.n, system.n_contacts
        self.n, self.m = n, m
        if options.smooth is _CLOSED_FORM and not self.model.polynomial:
            raise ValueError("smooth='closed-form' needs constant mass, kinematics and forces "
                             "(System.is_constant and forces independent of q and v)")
        self.closed_form = self.model.polynomial and options.smooth is not _SCIPY
        self._impact_solver = None
        self.stats = SolverStats()
        self.events, self.impulses, self.phases = [], [], []
        self.mode_solver_used = set()
        # scales for the zero tests
        model = self.model
        if model.polynomial:
            acc_scale = model.__dict__.get("acc_scale")
            if acc_scale is None:
                d = model.data(0.0, q0, v0)
                acc_scale = model.acc_scale = float(np.max(np.abs(d.qdd_free))) if n else 0.0
            A_max = model.A_max
        else:
            d = model.data(0.0, q0, v0)
            acc_scale = float(np.max(np.abs(d.qdd_free))) if n else 0.0
            A_max = float(np.max(np.abs(d.A)))
        V = max(_absmax(v0) if n else 0.0, acc_scale * t_end, 1e-300)
        self.scales = {"V": V, "L": max(V * t_end, _absmax(q0) if n else 0.0, 1e-300),
                       "A": max(acc_scale, V / t_end),
                       "P": max(A_max * V, 1e-300)}
        self.vel_tol = options.tol * V
        self.gap_tol = options.tol * self.scales["L"]

    @property
    def impact_solver(self):
        """The one-step solver of the velocity-level impact problems (built on first use)."""
        if self._impact_solver is None:
            self._impact_solver = make_solver(self.o.impact_solver)
        return self._impact_solver

    # --- consistency of the initial state
    def check_initial(self, q0, v0):
        sys = self.sys
        if sys.n_bilateral:
            phi, G, phi_t = (np.array(x, dtype=float) for x in sys.constraints_fn(0.0, q0))
            G = G.reshape(sys.n_bilateral, self.n)
            if np.max(np.abs(phi)) > 1e-9 * self.scales["L"]:
                raise ValueError(f"q0 violates the bilateral constraints (residual {np.max(np.abs(phi)):.3g})")
            if np.max(np.abs(G @ v0 + phi_t.ravel())) > 1e-9 * self.scales["V"]:
                raise ValueError("v0 violates the velocity form of the bilateral constraints")
        if self.m:
            gap = self.model.gaps(q0)
            bad = np.flatnonzero(gap < -self.gap_tol) if min(gap.tolist()) < -self.gap_tol else ()
            if len(bad):
                raise ValueError(f"q0 penetrates contact {bad[0]} (gap {gap[bad[0]]:.3g} < 0)")

    # --- projection onto the constraints after a phase (removes integration drift and rounding)
    def project(self, t, q, v, gap_rows, normal_rows, tangent_rows):
        """Snap q onto g_j = 0 (j in gap_rows) and the bilateral constraints, and v onto
        u_N,j = 0 (normal_rows), u_T,j = 0 (tangent_rows) and the bilateral velocity constraints,
        each by the smallest correction in the mass metric (it removes drift and rounding only).
        The rows are tuples of contact indices."""
        if self.model.constant:
            return self._project_constant(t, q, v, gap_rows, normal_rows, tangent_rows)
        n, m = self.n, self.m
        nb = self.sys.n_bilateral
        gap_rows = np.array(gap_rows, dtype=int)
        A = self.sys.mass(q, t)
        if gap_rows.size or nb:
            for _ in range(3):
                rows, res = [], []
                if nb:
                    phi, G, _ = (np.array(x, dtype=float) for x in self.sys.constraints_fn(t, q))
                    rows.append(G.reshape(nb, n))
                    res.append(phi.ravel())
                if gap_rows.size:
                    rows.append(self.model.jac(q)[gap_rows])
                    res.append(self.model.gaps(q)[gap_rows])
                J, r = np.vstack(rows), np.concatenate(res)
                if not np.any(r):
                    break
                q = q - _mass_projection(A, J, r)
        rows, res = [], []
        if nb:
            _, G, phi_t = (np.array(x, dtype=float) for x in self.sys.constraints_fn(t, q))
            G = G.reshape(nb, n)
            rows.append(G)
            res.append(G @ v + phi_t.ravel())
        vr = np.array(normal_rows + tuple(m + j for j in tangent_rows), dtype=int)
        if vr.size:
            H = self.model.jac(q)
            rows.append(H[vr])
            res.append(H[vr] @ v)
        if rows:
            J, r = np.vstack(rows), np.concatenate(res)
            if np.any(r):
                v = v - _mass_projection(A, J, r)
        return q, v

    def _project_constant(self, t, q, v, gap_rows, normal_rows, tangent_rows):
        """:meth:`project` for a constant system: one correction each (the constraints are
        affine), with the rows and correction matrices of each row set built once per system."""
        model, m = self.model, self.m
        nb = model.nb
        if gap_rows or nb:
            key = ("q", gap_rows)
            entry = model._proj.get(key)
            if entry is None:
                rows = np.array(gap_rows, dtype=int)
                entry = model._proj[key] = (rows, model.projector(key, [model.G, model.H[rows]]))
            rows, C = entry
            res = []
            if nb:
                res.append(np.array(self.sys.constraints_fn(t, q)[0], dtype=float).ravel())
            if gap_rows:
                g = model.gaps(q)
                res.append(g if len(gap_rows) == g.size and gap_rows == model.all_contacts else g[rows])
            r = np.concatenate(res) if len(res) > 1 else res[0]
            if r.any():
                q = q - C @ r
        vr = normal_rows + tuple(m + j for j in tangent_rows)
        if nb or vr:
            key = ("v", vr)
            entry = model._proj.get(key)
            if entry is None:
                Hv = model.H[np.array(vr, dtype=int)]
                entry = model._proj[key] = (Hv, model.projector(key, [model.G, Hv]))
            Hv, C = entry
            if nb:
                r = np.concatenate([model.G @ v + model.phi_t, Hv @ v])
            else:
                r = Hv @ v
            if r.any():
                v = v - C @ r
        return q, v

    # --- the acceleration-level problem and the next mode
    def classify(self, q, v):
        """Contacts at the surface: (closed candidates, approaching ones) as tuples of contact
        indices, and the local velocities H v (a list)."""
        m = self.m
        if not m:
            return (), (), []
        gap = self.model.gaps(q).tolist()
        ul = (self.model.jac(q) @ v).tolist()
        gtol, vtol = self.gap_tol, self.vel_tol
        closed, approaching = [], []
        for j in range(m):
            if gap[j] <= gtol:
                if abs(ul[j]) <= vtol:
                    closed.append(j)
                elif ul[j] < -vtol:
                    approaching.append(j)
        return tuple(closed), tuple(approaching), ul

    def solve_modes(self, data, closed, slide, allowed=None):
        """Distinct motions of the acceleration problem: list of groups of _Solution.

        ``closed`` (contact indices) and ``slide`` (signs) are tuples. For a polynomial system
        the problem depends on them only: its solutions are kept per system
        (``_Model.mode_memo``) and the solver statistics replayed.
        """
        n_branches = 1
        for s in slide:
            n_branches *= 2 if s != 0 else 4
        use_enum = (self.o.mode_solver is _ENUMERATE
                    or (self.o.mode_solver is _AUTO_SOLVER and n_branches <= self.o.max_branches))
        if self.model.polynomial:
            key = (closed, slide, None if allowed is None else frozenset(allowed), use_enum)
            memo = self.model.mode_memo
            entry = memo.get(key)
            if entry is None:
                entry = memo[key] = self._solve_modes(data, closed, slide, allowed, use_enum)
        else:
            entry = self._solve_modes(data, closed, slide, allowed, use_enum)
        sols, acc, used, iterations, max_iterations, max_residual = entry
        st = self.stats
        st.solver_calls += 1
        self.mode_solver_used.add(used)
        st.iterations += iterations
        st.max_iterations = max(st.max_iterations, max_iterations)
        if max_residual is not None:
            st.max_residual = max(st.max_residual, max_residual)
        return _group(sols, self.scales["A"]), acc

    def _solve_modes(self, data, closed, slide, allowed, use_enum):
        """(solutions, problem, solver name, iterations, max iterations candidate, max residual)."""
        closed, slide = np.array(closed, dtype=int), np.array(slide, dtype=float)
        acc = _Accel(data, closed, slide, self.mu, flush=True)
        if use_enum or allowed is not None:
            used = "enumerate"
            sols, tried = _enumerate(acc, allowed)
            iterations = max_iterations = tried
        else:
            used = "lemke"
            res = make_solver("lemke").solve(acc.pb)
            iterations = max_iterations = res.iterations
            sols = []
            if res.success:
                md = acc.pb.modes(res.p)
                modes = tuple(OPEN if md[j] == OPEN else (md[j] if slide[j] == 0 else
                                                          (SLIDE_POS if slide[j] > 0 else SLIDE_NEG))
                              for j in range(acc.k))
                sols = [_Solution(modes, res.p, acc.qdd(res.p))]
                alts = _boundary_alternatives(acc, modes, res.p)
                if any(len(a) > 1 for a in alts):
                    # Lemke returns one solution; at a mode boundary its neighbours are the same
                    # motion, and the tie must be seen to be broken (else the phase chatters)
                    sols, tried = _enumerate(acc, set(product(*alts)))
                    iterations += tried
        max_residual = None
        for s in sols:
            r = acc.pb.residual(s.p)
            max_residual = r if max_residual is None else max(max_residual, r)
            s.p.setflags(write=False)
            s.qdd.setflags(write=False)
        return sols, acc, used, iterations, max_iterations, max_residual

    def slide_signs(self, closed, ul) -> tuple:
        """Sign of the sliding velocity of each closed contact (0.0 for a stick candidate)."""
        m, vtol = self.m, self.vel_tol
        return tuple(0.0 if abs(x) <= vtol else (1.0 if x > 0 else -1.0) for x in (ul[m + j] for j in closed))

    def lookahead(self, t, q, v, closed, slide, group):
        """Break a tie (one motion, several mode sets) by the problem a short time later."""
        qdd = group[0].qdd
        dt = 1e-6 * self.t_end
        if self.model.polynomial:
            d1 = self.model.data(t + dt, q, v)  # the same at every state
        else:
            q1 = q + dt * v + 0.5 * dt * dt * qdd
            v1 = v + dt * qdd
            d1 = self.model.data(t + dt, q1, v1)
        groups, _ = self.solve_modes(d1, closed, slide, allowed={s.modes for s in group})
        if len(groups) == 1 and len(groups[0]) >= 1:
            return groups[0][0]
        return group[0]

    def impact(self, t, q, v, contacts, data):
        """Velocity-level impact problem on ``contacts``; returns (dv, p, modes) or None."""
        m = self.m
        idx = np.asarray(contacts, dtype=int)
        k = idx.size
        key = idx.tobytes()
        cached = self.model.impact_memo.get(key) if self.model.polynomial else None
        if cached is None:
            rows = np.concatenate([idx, m + idx])
            Hc = data.H[rows]
            SH = data.solve_dirs(Hc.T)
            W = Hc @ SH
            b = Hc @ data.qdd_free + data.Hdv[rows]
            cached = (Hc, SH, W, b)
            if self.model.polynomial:  # nothing here depends on the state
                for arr in cached:
                    arr.setflags(write=False)
                self.model.impact_memo[key] = cached
        Hc, SH, W, b = cached
        u = Hc @ v
        qv = u.copy()
        qv[:k] += self.e[idx] * u[:k]  # Newton restitution, as in the Moreau-Jean step
        # Moreau-Jean's problem for a vanishing step h = delta: free velocity u + delta b
        umax, bmax = float(np.max(np.abs(qv))), float(np.max(np.abs(b)))
        delta = 1e-8 * (umax / bmax if umax > 0 and bmax > 0 else self.t_end)
        pb_d = ContactProblem(W, qv + delta * b, self.mu[idx])
        sol = self.impact_solver.solve(pb_d)
        self.stats.solver_calls += 1
        self.stats.iterations += sol.iterations
        self.stats.qp_solves += sol.qp_solves
        if not sol.success:
            return None
        modes = pb_d.modes(sol.p)
        pb0 = ContactProblem(W, qv, self.mu[idx])
        p = pb0.solve_branch(modes)
        if p is None or not pb0.admissible(p, modes):
            p = sol.p  # the branch is singular at delta = 0: keep the vanishing-step solution
        self.stats.max_residual = max(self.stats.max_residual, pb0.residual(p))
        return SH @ p, p, modes

    def record_impulse(self, t, contacts, p, kind, reason):
        k = len(contacts)
        for jj, j in enumerate(contacts):
            if p[jj] != 0.0 or p[k + jj] != 0.0:
                self.impulses.append(Impulse(float(t), int(j), float(p[jj]), float(p[k + jj]), kind, reason))
        if not (self.events and self.events[-1].t == t and self.events[-1].kind == kind):
            self.events.append(Event(float(t), kind, int(contacts[0]) if k == 1 else -1))

    def decide(self, t, q, v):
        """Apply impulses where needed, then find the modes of the next phase.

        Returns (q, v, closed, solution, problem): the contacts at the surface (a tuple), the chosen
        solution of their acceleration-level problem (None if there are none) and that problem;
        raises _Inconsistent when no motion can be continued.
        """
        if self.model.polynomial:
            out = self._decide_memo(q, v)
            if out is not None:
                return out
        for _ in range(8):
            data = self.model.data(t, q, v)
            closed, approaching, ul = self.classify(q, v)
            if approaching:
                at = np.union1d(np.array(closed, dtype=int), np.array(approaching, dtype=int))
                out = self.impact(t, q, v, at, data)
                if out is None:
                    raise _Inconsistent(f"the impact problem at t = {t:.17g} has no solution")
                dv, p, _ = out
                v = v + dv
                self.record_impulse(t, at, p, "impact", "gap closed with approach velocity")
                continue
            if not closed:
                return q, v, closed, None, None
            m, vtol = self.m, self.vel_tol  # slide_signs, inline
            slide = tuple([0.0 if abs(x) <= vtol else (1.0 if x > 0 else -1.0) for x in [ul[m + j] for j in closed]])
            groups, acc = self.solve_modes(data, closed, slide)
            if len(groups) == 1:
                group = groups[0]
                sol = group[0] if len(group) == 1 else self.lookahead(t, q, v, closed, slide, group)
                return q, v, closed, sol, acc
            self.stats.ambiguous_steps += int(len(groups) > 1)
            why = ("no consistent contact mode (Painleve: no solution)" if not groups else
                   f"{len(groups)} consistent contact modes (Painleve: non-uniqueness)")
            out = self.impact(t, q, v, closed, data)
            if out is None:
                raise _Inconsistent(f"at t = {t:.17g}: {why}, and the impact problem has no solution")
            dv, p, imodes = out
            if np.max(np.abs(p)) > 1e-12 * self.scales["P"]:
                self.stats.fallbacks += 1
                v = v + dv
                self.record_impulse(t, closed, p, "tangential impact", why)
                continue
            if groups:
                # several motions and no impulse: follow the one Moreau-Jean's vanishing step picks
                for g in groups:
                    for s in g:
                        if all((im == OPEN) == (sm == OPEN) for im, sm in zip(imodes, s.modes)):
                            return q, v, closed, s, acc
                return q, v, closed, groups[0][0], acc
            raise _Inconsistent(f"at t = {t:.17g}: {why}; the impulsive fallback gives no impulse")
        raise _Inconsistent(f"at t = {t:.17g}: impulses did not lead to a consistent contact mode")

    def _decide_memo(self, q, v):
        """:meth:`decide` of a polynomial system in its common case: no contact approaching and
        an acceleration problem already solved (``_Model.mode_memo``) with a unique solution.
        The same steps as classify, slide_signs and solve_modes, inlined; None otherwise
        (nothing done: decide then takes its general path)."""
        model, m = self.model, self.m
        gtol, vtol = self.gap_tol, self.vel_tol
        gap = (model.gap0 + model.HN @ q).tolist()  # model.gaps(q)
        ul = (model.H @ v).tolist()
        closed = []
        for j in range(m):
            if gap[j] <= gtol:
                if abs(ul[j]) <= vtol:
                    closed.append(j)
                elif ul[j] < -vtol:
                    return None  # an impact first
        closed = tuple(closed)
        if not closed:
            return q, v, closed, None, None
        slide = tuple([0.0 if abs(x) <= vtol else (1.0 if x > 0 else -1.0) for x in [ul[m + j] for j in closed]])
        n_branches = 1
        for s in slide:
            n_branches *= 2 if s != 0 else 4
        o = self.o
        use_enum = (o.mode_solver is _ENUMERATE or (o.mode_solver is _AUTO_SOLVER and n_branches <= o.max_branches))
        entry = model.mode_memo.get((closed, slide, None, use_enum))
        if entry is None or len(entry[0]) != 1:
            return None
        sols, acc, used, iterations, max_iterations, max_residual = entry
        st = self.stats  # as solve_modes
        st.solver_calls += 1
        self.mode_solver_used.add(used)
        st.iterations += iterations
        st.max_iterations = max(st.max_iterations, max_iterations)
        st.max_residual = max(st.max_residual, max_residual)
        return q, v, closed, sols[0], acc

    # --- main loop
    def run(self, q0, v0):
        o, m = self.o, self.m
        t, q, v = 0.0, q0.copy(), v0.copy()
        P = np.zeros(2 * m)
        status, message = 0, EVENT_STATUS_MESSAGES[0]
        run_phases = []
        short = 0
        while True:
            try:
                q, v, closed, sol, acc = self.decide(t, q, v)
            except _Inconsistent as exc:
                status, message = -3, f"{EVENT_STATUS_MESSAGES[-3]} {exc}"
                break
            if self.closed_form:
                # The phase's modes, accelerations and forces depend on the solution only (a
                # polynomial system's mode problems are the same at every state): kept with it.
                cache = sol.ready if sol is not None else self.model.free_ready
                ready = cache.get(closed)
                if ready is None:
                    closed_a = np.array(closed, dtype=int)
                    modes = sol.modes if sol is not None else ()
                    keep = [i for i, md in enumerate(modes) if md != OPEN]
                    args = (self.model, t, q, v, P, closed_a[keep], tuple(modes[i] for i in keep), self.mu)
                    Nm, fm = np.zeros(m), np.zeros(m)
                    if sol is not None:
                        Nm[closed_a], fm[closed_a] = acc.forces(sol.p)  # zero for the contacts that open
                        start = (sol.qdd, Nm[closed_a[keep]], fm[closed_a[keep]])
                    else:
                        start = (self.model.data(t, q, v).qdd_free, Nm[:0], fm[:0])
                    ph = _ClosedFormPhase(*args, start=start)
                    cache[closed] = ph.ready()
                else:
                    ph = _ClosedFormPhase.from_ready(self.model, t, q, v, P, self.mu, ready)
            else:
                closed_a = np.array(closed, dtype=int)
                modes = sol.modes if sol is not None else ()
                keep = [i for i, md in enumerate(modes) if md != OPEN]
                args = (self.model, t, q, v, P, closed_a[keep], tuple(modes[i] for i in keep), self.mu)
                ph = _OdePhase(*args, options=o, scales=self.scales)
            closed, modes = ph.idx_t, ph.modes
            try:
                ev = ph.run(self.t_end)
            except FloatingPointError as exc:
                status, message = -2, f"{EVENT_STATUS_MESSAGES[-2]} Phase from t = {t:.10g}: {exc}"
                break
            run_phases.append(ph)
            self.phases.append(_record(Phase, float(ph.t0), float(ph.t1), ph.names(), ph.integrator, int(ph.nfev)))
            counts = self.stats.mode_counts
            for name in ph.names():
                counts[name] += 1
            if ev is None:
                break
            te, kind, j = ev
            q, v, P = ph.end_state()
            stick = tuple(c for c, md in zip(closed, modes) if md == STICK)
            if kind == "stop":
                stick += (j,)
            gap_rows = closed if kind != "impact" else closed + (j,)
            q, v = self.project(te, q, v, gap_rows, closed, stick)
            if not (_finite(q) and _finite(v)):
                status, message = -2, f"{EVENT_STATUS_MESSAGES[-2]} At t = {te:.10g}."
                break
            self.events.append(_record(Event, float(te), kind, int(j)))
            short = short + 1 if te - t <= 64 * _EPS * max(1.0, abs(te)) else 0
            t = te
            if len(self.events) > o.max_events or short > 50:
                status = -4
                message = (f"{EVENT_STATUS_MESSAGES[-4]} {len(self.events)} events by t = {t:.10g}"
                           + (f" ({short} consecutive phases of zero length)" if short > 50 else ""))
                break
        self.stats.steps = len(run_phases)
        self.stats.free_steps = sum(1 for ph in run_phases if not ph.idx_t)
        return run_phases, status, message, t


class _Inconsistent(Exception):
    pass


def _transposed(rows):
    """C-contiguous copy of rows.T (column by column when there are few: faster than NumPy's)."""
    k, N = rows.shape
    if k > 8:
        return np.ascontiguousarray(rows.T)
    out = np.empty((N, k))
    for i in range(k):
        out[:, i] = rows[i]
    return out


def _check_state(system, q0, v0):
    """``System.check_state``; for a constant system whose mass matrix was already validated,
    only the shapes and finiteness of q0 and v0 (anything else: the full check, and its message)."""
    model = _MODELS.get(system)
    if model is not None and model.state_checked:
        q, v = np.asarray(q0, dtype=float), np.asarray(v0, dtype=float)
        if q.shape == v.shape == (model.n,) and _finite(q) and _finite(v):
            return q, v
    return system.check_state(q0, v0)


def _mass_projection(A, J, r):
    """Smallest correction dx in the mass metric with J dx = r: A^-1 J' (J A^-1 J')^-1 r."""
    AJ = np.linalg.solve(A, J.T)
    return AJ @ np.linalg.lstsq(J @ AJ, r, rcond=None)[0]


def event_driven(system, q0, v0, t_end: float, scene=None, **options) -> EventResult:
    """Integrate a :class:`~lcp.system.System` event by event, with exact mode switches.

    Usually called as ``lcp.simulate(scene, t_end, method="event", **options)``.

    Parameters
    ----------
    system : System
    q0, v0 : array_like, shape (n,)
        Initial state (consistent with the bilateral constraints, no penetration).
    t_end : float
        Horizon, > 0.
    scene : Scene, optional
        Only used to name the scene in messages.
    **options
        See :class:`EventOptions` (``t_eval``, ``n_eval``, ``smooth``, ``ode_method``, ``rtol``,
        ``atol``, ``mode_solver``, ``impact_solver``, ``max_branches``, ``max_events``, ``tol``).

    Returns
    -------
    EventResult
        ``t`` (n_points,), ``q`` and ``v`` (n_points, n) at the output times, impulses ``p_N``,
        ``p_T`` and ``modes`` (n_points - 1, m) per output interval, ``force_N`` and ``force_T``
        (n_points, m), ``t_events``, ``events``, ``impulses``, ``phases`` (with the integrator of
        each), ``mode_sequence``, ``status``, ``message``, ``success`` and ``stats``.

    Examples
    --------
    The Jean-Pratt block slides and sticks at tau0 = 0.152905... s (physics.md section 2):

    >>> import lcp
    >>> sc = lcp.scenes.jean_pratt()
    >>> res = lcp.simulate(sc, 0.3, method="event")
    >>> res.success, res.mode_sequence, res.integrators
    (True, [('slide+',), ('stick',)], ['closed-form'])
    >>> abs(res.t_events[0] - sc.tau0) < 1e-15
    True

    Past the shock limit (kappa = 1.25) the block stops by a tangential impact at t = 0:

    >>> res = lcp.simulate(lcp.scenes.jean_pratt(R=2.5), 0.3, method="event")
    >>> imp = res.impulses[0]
    >>> imp.t, round(imp.P_N, 12), round(imp.P_T, 12), res.mode_sequence
    (0.0, 1.0, -2.0, [('stick',)])
    """
    opts = EventOptions.from_kwargs(**options)
    if not (isinstance(t_end, (int, float, np.floating)) and math.isfinite(t_end) and t_end > 0):
        raise ValueError(f"t_end must be finite and > 0, got {t_end!r}")
    t_end = float(t_end)
    q0, v0 = _check_state(system, q0, v0)
    t_out = opts.output_times(t_end)
    integ = _Integrator(system, q0, v0, t_end, opts)
    integ.model.state_checked = integ.model.constant  # the mass matrix is the same at every state
    integ.check_initial(q0, v0)
    phases, status, message, t_fail = integ.run(q0, v0)
    n, m = system.n, system.n_contacts
    if status < 0:
        t_out = t_out[t_out <= t_fail]
        if scene is not None:
            message = f"{message} (scene '{scene.name}')"
    N_out = t_out.size
    # rows q (n), v (n), cumulative impulses (2m); one column per output time
    Y = np.empty((2 * n + 2 * m, N_out))
    FN = np.empty((N_out, m))
    FT = np.empty((N_out, m))
    MD = np.empty((N_out, m), dtype=np.int8)

    def blank(a, b):  # output times no phase covers: no state, no force, no mode
        Y[:2 * n, a:b] = np.nan
        Y[2 * n:, a:b] = 0.0
        FN[a:b] = FT[a:b] = 0.0
        MD[a:b] = -1

    # output times in [t0, t1) of each phase, [t0, t1] for the last (t_out is increasing)
    bounds = np.searchsorted(t_out, [ph.t0 for ph in phases] + [ph.t1 for ph in phases]).tolist()
    n_ph = len(phases)
    if n_ph and bounds[-1] < N_out and t_out[bounds[-1]] == phases[-1].t1:
        bounds[-1] += 1
    # the phases are consecutive in time: their output times are the columns [start, stop)
    start = bounds[0] if n_ph else 0
    stop = max(start, bounds[-1]) if n_ph else 0
    if start > 0:
        blank(0, start)
    if stop < N_out:
        blank(stop, N_out)
    spans = [(ph, a, b) for ph, a, b in zip(phases, bounds[:n_ph], bounds[n_ph:]) if a < b]
    if spans and integ.closed_form:
        ph_s = [ph for ph, _, _ in spans]
        _closed_form_output(ph_s, t_out[start:stop], [b - a for _, a, b in spans], Y[:, start:stop])
        for ph, a, b in spans:
            FN[a:b], FT[a:b] = ph.N, ph.f
            MD[a:b] = ph.full_modes
    else:
        for ph, a, b in spans:
            FN[a:b], FT[a:b] = ph.output(t_out[a:b], Y[:, a:b])
            MD[a:b] = ph.full_modes
    # impulses over [t_i, t_{i+1}): the left-limit cumulative impulse, shocks at t_s < t included
    for imp in integ.impulses:
        after = int(np.searchsorted(t_out, imp.t, "right"))  # t_out > imp.t
        Y[2 * n + imp.contact, after:] += imp.P_N
        Y[2 * n + m + imp.contact, after:] += imp.P_T
    Q, V = _transposed(Y[:n]), _transposed(Y[n:2 * n])
    Pc = Y[2 * n:]
    dP = (Pc[:, 1:] - Pc[:, :-1]).T  # np.diff
    integ.stats.steps = len(phases)
    used = sorted(integ.mode_solver_used)
    return EventResult(t=t_out, q=Q, v=V, p_N=dP[:, :m], p_T=dP[:, m:], modes=MD[:-1] if t_out.size else MD,
                       status=status, message=message, stats=integ.stats, method="event",
                       solver="+".join(used) if used else "none",
                       t_events=[ev.t for ev in integ.events], force_N=FN, force_T=FT,
                       events=integ.events, impulses=integ.impulses,
                       phases=integ.phases)
