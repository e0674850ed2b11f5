"""The system as the event integrator evaluates it: state data, the per-system cache, projections.

A constant system (``System.is_constant``) is assembled once; for a polynomial one (constant forces
as well) everything the mode decisions need depends on the System only and is kept per System
object (:class:`SystemModel`), so a later integration only classifies contacts, finds event times
and projects states.
"""
from __future__ import annotations

import math
import weakref

import casadi as ca
import numpy as np

from lcp.events.forcing import time_forcing
from lcp.model.kinematics import normalize_quaternions, normalized_expr
from lcp.numerics.casadi_eval import evaluate_kept

__all__ = [
    "EPS",
    "ContactKinematics",
    "StateData",
    "SystemModel",
    "absmax",
    "accel_arrays",
    "accel_function",
    "all_finite",
    "check_state",
    "coordinate_rows",
    "mass_projection",
    "system_model",
    "zero_test_scales",
]

EPS = np.finfo(float).eps


def all_finite(x) -> bool:
    """np.isfinite(x).all() for a 1-D array, without NumPy's per-call overhead when small."""
    if x.size <= 16:
        return all(map(math.isfinite, x.tolist()))
    return bool(np.isfinite(x).all())


def absmax(x) -> float:
    """float(np.max(np.abs(x))) for a non-empty 1-D array, without NumPy's per-call overhead when small."""
    if x.size <= 16:
        return float(max(map(abs, x.tolist())))
    return float(np.max(np.abs(x)))


ACCEL_FUNCTIONS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def accel_function(system) -> ca.Function:
    """CasADi Function (t, q, v) -> (A, F, G, zeta, H, Hdot v, gap), built once per system.

    zeta is the velocity-dependent part of the bilateral constraints' second time derivative:
    d2/dt2 phi(t, q) = G qdd + zeta. Likewise Hdot v is the part of the contacts' local acceleration
    du/dt = H qdd + Hdot v that does not hold qdd: (d/dt H) v, plus, for a moving contact
    (u = H(t, q) v + b(t, q), b = (dg/dt, ds/dt)), the derivative of b along the motion.
    """
    fn = ACCEL_FUNCTIONS.get(system)
    if fn is None and getattr(system, "has_kinematics", False):
        fn = ACCEL_FUNCTIONS[system] = _kinematic_accel_function(system)
    if fn is None and _scheduled(system):
        # a controlled system with its control fixed to a schedule (System.with_control): the
        # controlled system's function, its free force plus B(t, q) u(t). The derivatives are
        # taken once for the controlled system, not again for each schedule (an optimal control's
        # replay restarted at every node fixes a schedule per interval: 2.8 ms each on the cart-pole)
        drift, t, q, v = system.control_drift, system.t_sym, system.q_sym, system.v_sym
        outs = list(accel_function(drift)(t, q, v))
        outs[1] = outs[1] + ca.mtimes(drift.control_matrix_expr, system.control_schedule.expression(t))
        fn = ACCEL_FUNCTIONS[system] = ca.Function("event_accel_data", [t, q, v], outs)
    if fn is None:
        t, q, v = system.t_sym, system.q_sym, system.v_sym
        c = system.constraints_expr
        G = ca.jacobian(c, q)
        phi_t = ca.jacobian(c, t)
        Gv = ca.mtimes(G, v)
        zeta = (ca.jtimes(Gv, q, v) + ca.jacobian(Gv, t) + ca.jtimes(phi_t, q, v) + ca.jacobian(phi_t, t))
        H = system.H_expr
        if system.contacts_depend_on_t:
            # a moving contact: u = H(t, q) v + b(t, q), and du/dt = H qdd + Hdv with everything else
            # (d/dt H) v + db/dt, by AD on u as an expression of (t, q, v) with qdot = v
            u = ca.mtimes(H, v) + system.contact_rate_expr
            Hdv = ca.jtimes(u, q, v) + ca.jacobian(u, t)
        else:
            Hdv = ca.jtimes(ca.mtimes(H, v), q, v)
        fn = ca.Function("event_accel_data", [t, q, v],
                         [system.mass_expr, system.force_expr, G, zeta, H, Hdv, system.gap_expr])
        ACCEL_FUNCTIONS[system] = fn
    return fn


def _scheduled(system) -> bool:
    """Whether ``system`` is a controlled system's ``with_control`` (its symbols, contacts and
    constraints, its force the free force plus the control's), without kinematics."""
    drift = getattr(system, "control_drift", None)
    return (drift is not None and getattr(system, "control_schedule", None) is not None
            and drift.q_sym is system.q_sym and drift.v_sym is system.v_sym and drift.t_sym is system.t_sym
            and not getattr(drift, "has_kinematics", False))


DENSE_ACCEL: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def accel_arrays(system, t, q, v) -> tuple:
    """The outputs of :func:`accel_function` at (t, q, v) as C-ordered NumPy arrays of their shapes
    (A, F, G, zeta, H, Hdot v, gap; the vectors as columns), evaluated into NumPy buffers: the
    event integrator's ODE phases evaluate them at every stage of every step, and converting to and
    from CasADi matrices cost three times the evaluation (the cart-pole: 100 of 170 us). The
    Function's outputs are densified and transposed, so that CasADi's column-major writes fill
    row-major arrays: the same numbers as ``accel_function(system)(t, q, v)``, bit for bit."""
    entry = DENSE_ACCEL.get(system)
    if entry is None:
        fn = accel_function(system)
        args = [ca.SX.sym(fn.name_in(i), fn.sparsity_in(i)) for i in range(fn.n_in())]
        outs = fn(*args)
        dense = ca.Function("event_accel_dense", args, [ca.densify(o).T for o in outs])
        entry = DENSE_ACCEL[system] = (dense, [(fn.size1_out(i), fn.size2_out(i)) for i in range(fn.n_out())])
    dense, shapes = entry
    outs = [np.empty(shape) for shape in shapes]
    evaluate_kept(dense, (np.array([t], dtype=float), np.ascontiguousarray(q, dtype=float),
                          np.ascontiguousarray(v, dtype=float)), outs)
    return tuple(outs)


def _kinematic_accel_function(system) -> ca.Function:
    """:func:`accel_function` for a System with Newton-Euler kinematics qdot = T(t, q) v
    (:mod:`lcp.model.kinematics`): G and H map v (dphi/dq T, dg/dq T, as the System gives them),
    and the drift terms differentiate along the motion with qdot = T v (jtimes in the direction
    T v, not v). Every output is evaluated at q with its unit quaternions normalised (the formulas
    of R(p) hold on the sphere only; the integrators also renormalise the state itself)."""
    t, q, v = system.t_sym, system.q_sym, system.v_sym
    T = system.kinematics_expr
    qdot = ca.mtimes(T, v)
    c = system.constraints_expr
    G = ca.mtimes(ca.jacobian(c, q), T)
    phi_t = ca.jacobian(c, t)
    Gv = ca.mtimes(G, v)
    zeta = ca.jtimes(Gv, q, qdot) + ca.jacobian(Gv, t) + ca.jtimes(phi_t, q, qdot) + ca.jacobian(phi_t, t)
    H = system.H_expr
    u = ca.mtimes(H, v)
    if system.contacts_depend_on_t:
        u = u + system.contact_rate_expr
        Hdv = ca.jtimes(u, q, qdot) + ca.jacobian(u, t)
    else:
        Hdv = ca.jtimes(u, q, qdot)
    qn = normalized_expr(system, q)
    outs = [ca.substitute(x, q, qn) for x in (system.mass_expr, system.force_expr, G, zeta, H, Hdv,
                                              system.gap_expr)]
    return ca.Function("event_accel_data_kinematic", [t, q, v], outs)


def qdot_function(system) -> ca.Function:
    """(t, q, v) -> T(t, q^) v, q^ with the unit quaternions normalised; None without kinematics."""
    if not getattr(system, "has_kinematics", False):
        return None
    fn = QDOT_FUNCTIONS.get(system)
    if fn is None:
        t, q, v = system.t_sym, system.q_sym, system.v_sym
        rate = ca.substitute(ca.mtimes(system.kinematics_expr, v), q, normalized_expr(system, q))
        fn = QDOT_FUNCTIONS[system] = ca.Function("event_qdot", [t, q, v], [rate])
    return fn


QDOT_FUNCTIONS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


class StateData:
    """Everything the contact problems need at one state, with the KKT matrix factorized once."""

    def __init__(self, A, F, G, zeta, H, Hdv, gap, check: bool = False):
        self.A, self.F, self.G, self.zeta, self.H, self.Hdv, self.gap = A, F, G, zeta, H, Hdv, gap
        n, nb = A.shape[0], G.shape[0]
        self.n, self.nb = n, nb
        self.K = K = np.block([[A, G.T], [G, np.zeros((nb, nb))]]) if nb else A
        # LU with partial pivoting per solve (LAPACK gesv): for these tiny systems it is faster than
        # reusing a factorization through scipy.linalg.lu_solve, whose multi-column path is slow
        if check:
            import scipy.linalg as sla  # only for the one-off check (keeps `import lcp` cheap)

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


class ContactKinematics:
    """Gaps and contact Jacobian of a model: from the constant ``gap0``, ``HN`` and ``H`` when the
    model is ``constant``, else evaluated by its System ``sys`` (shared by the planar and spatial
    event models)."""

    def gaps(self, q, t=None) -> np.ndarray:
        """g(t, q) (t is needed where a contact moves, ignored otherwise)."""
        if self.constant:
            return self.gap0 + self.HN @ q
        return self.sys.gaps(q, t)

    def jac(self, q, t=None) -> np.ndarray:
        """H(t, q): the normal rows, then the tangent rows."""
        if self.constant:
            return self.H
        return self.sys.contact_jacobian(q, t)

    #: coordinates n_q and the rate of q (None: qdot = v); set by :meth:`init_kinematics`
    nq = None
    kinematic = False
    _qdot = None

    def init_kinematics(self, system) -> None:
        """Newton-Euler kinematics (qdot = T(t, q) v, :mod:`lcp.model.kinematics`): n_q coordinates
        and T(t, q) v by CasADi; without them n_q = n and qdot = v."""
        self.nq = system.n_q
        self.kinematic = bool(getattr(system, "has_kinematics", False))
        self._qdot = qdot_function(system)

    def qdot(self, t, q, v) -> np.ndarray:
        """qdot = T(t, q) v (v itself without kinematics)."""
        if self._qdot is None:
            return v
        return np.array(self._qdot(t, q, v), dtype=float).ravel()

    def advance(self, t, q, dq) -> np.ndarray:
        """q moved by a v-space correction dq: q + T(q) dq, quaternions renormalised (q + dq
        without kinematics)."""
        if self._qdot is None:
            return q + dq
        out = q + self.qdot(t, q, dq)
        return normalize_quaternions(self.sys, out)

    def normalize(self, q) -> np.ndarray:
        """q with its unit quaternions divided by their norms (in place; q itself without any)."""
        if self._qdot is not None:
            normalize_quaternions(self.sys, q)
        return q

    @property
    def moving(self) -> bool:
        """Whether a contact moves with time (a gap or tangent of t: a moving table, a cam, a belt)."""
        return bool(getattr(self.sys, "contacts_depend_on_t", False))

    def local_velocity(self, t, q, v) -> np.ndarray:
        """u = H(t, q) v + b(t, q): normal, then tangential local velocities; b = (dg/dt, ds/dt) is
        zero for fixed contacts (u = H v)."""
        if self.constant:
            return self.H @ v
        if not self.moving:
            return self.sys.contact_jacobian(q) @ v
        return self.sys.contact_jacobian(q, t) @ v + self.sys.contact_rates(q, t)


class SystemModel(ContactKinematics):
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

    A system that is constant apart from a scheduled control force B u(t), piecewise affine in t
    (:func:`~lcp.events.forcing.time_forcing`), is constant here too, its force at t being
    ``forcing.at(t) + Kq q + Cv v`` (no CasADi call); with state-independent forces (``cubic``) its
    phases are polynomial in t as well (:class:`~lcp.events.cubic_phase.CubicPhase`). ``general=True``
    ignores the forcing (the integration then evaluates the System, for horizons the schedule's
    checked range does not cover).
    """

    def __init__(self, system, general: bool = False):
        self.sys = system
        self.n, self.m, self.nb = system.n, system.n_contacts, system.n_bilateral
        self.init_kinematics(system)
        self.all_contacts = tuple(range(self.m))
        #: the piecewise-affine time dependence of the force, or None
        self.forcing = None if general or system.is_constant else time_forcing(system)
        self.constant = system.is_constant or self.forcing is not None
        # polynomial (quadratic) phases: constant mass, kinematics and forces
        self.polynomial = system.is_constant and not system.force_depends_on_state
        # cubic phases: as polynomial, plus a force affine in t between the schedule's breakpoints
        self.cubic = self.forcing is not None and not system.force_depends_on_state
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
            self._const_data = StateData(self.A, self.F0, self.G, np.zeros(system.n_bilateral), self.H,
                                     np.zeros(2 * m), self.gap0, check=True)
            self.proj_cache = {}
            self.mode_memo = {}
            self.phase_memo = {}
            self.impact_memo = {}
            self.free_ready = {}  # closed-form phase data with no closed contact (ClosedFormPhase.ready)

    def data(self, t, q, v) -> StateData:
        if self.constant:
            if self.polynomial:
                return self._const_data  # nothing depends on the state (gaps: see gaps())
            d = StateData.__new__(StateData)
            d.__dict__.update(self._const_data.__dict__)  # shares the factorization
            d.gap = self.gap0 + self.HN @ q
            F0 = self.F0 if self.forcing is None else self.forcing.at(t)
            d.F = F0 + self.Kq @ q + self.Cv @ v
            d._qdd_free = None
            return d
        n, m, nb = self.n, self.m, self.sys.n_bilateral
        A, F, G, zeta, H, Hdv, gap = accel_arrays(self.sys, t, q, v)
        if not all_finite(F.ravel()):
            bad = [self.sys.names[i] for i in np.flatnonzero(~np.isfinite(F.ravel()))]
            raise FloatingPointError(f"the force F(t, q, v) is not finite at t = {t:.10g} (coordinates {bad})")
        return StateData(A.reshape(n, n), F.ravel(), G.reshape(nb, n), zeta.ravel(), H.reshape(2 * m, n),
                     Hdv.ravel(), gap.ravel())


    def projector(self, key, rows) -> np.ndarray:
        """Constant system: the matrix C with mass_projection(A, J, r) = C r, J = vstack(rows)."""
        C = self.proj_cache.get(("C",) + key)
        if C is None:
            J = np.vstack(rows)
            AJ = np.linalg.solve(self.A, J.T)
            C = self.proj_cache[("C",) + key] = AJ @ np.linalg.lstsq(J @ AJ, np.eye(J.shape[0]), rcond=None)[0]
        return C



MODELS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
GENERAL_MODELS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def system_model(system, general: bool = False) -> SystemModel:
    """The evaluator of a system, built once (a constant system is then assembled only once);
    ``general``: the one that ignores a piecewise-affine forcing (see :class:`SystemModel`)."""
    if general:
        model = MODELS.get(system)
        if model is not None and model.forcing is None:
            return model
        model = GENERAL_MODELS.get(system)
        if model is None:
            model = GENERAL_MODELS[system] = SystemModel(system, general=True)
        return model
    model = MODELS.get(system)
    if model is None:
        model = MODELS[system] = SystemModel(system)
    return model


def check_state(system, q0, v0):
    """``System.check_state``; for a constant system whose mass matrix was already validated,
    only the shapes and finiteness of q0 and v0 (anything else: the full check, and its message)."""
    model = MODELS.get(system)
    if model is not None and model.state_checked:
        q, v = np.asarray(q0, dtype=float), np.asarray(v0, dtype=float)
        if q.shape == v.shape == (model.n,) and all_finite(q) and all_finite(v):
            return q, v
    return system.check_state(q0, v0)


def coordinate_rows(J, target) -> tuple:
    """Constraint rows J x = target that fix one coordinate each (a flat contact, a fixed
    direction): ((i, target_r / J[r, i]), ...), so that the constraint can be imposed exactly
    rather than to rounding (a ball resting on a floor stays at height 0, not 1e-17)."""
    out = []
    for r in range(J.shape[0]):
        nz = np.flatnonzero(J[r])
        if nz.size == 1:
            out.append((int(nz[0]), float(target[r]) / float(J[r, nz[0]])))
    return tuple(out)


def mass_projection(A, J, r):
    """Smallest correction dx in the mass metric with J dx = r: A^-1 J' (J A^-1 J')^-1 r."""
    AJ = np.linalg.solve(A, J.T)
    return AJ @ np.linalg.lstsq(J @ AJ, r, rcond=None)[0]




def zero_test_scales(model, q0, v0, t_end) -> dict:
    """Scales of the zero tests (a velocity, a gap, a force "is zero"): velocity V, length L,
    acceleration A, impulse P and force F.

    Velocities reached and distances covered over the horizon, but over no more than 100 times
    the scene's own time scale: a ball resting on a floor for 1e6 s must not get a 1e6-fold
    coarser length tolerance.
    """
    n = model.n
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
    V0, L0 = (absmax(v0), absmax(q0)) if n else (0.0, 0.0)
    T = t_end
    if acc_scale > 0:
        T_own = 100.0 * max(math.sqrt(L0 / acc_scale), V0 / acc_scale)
        T = min(t_end, T_own) if T_own > 0 else t_end
    V = max(V0, acc_scale * T, 1e-300)
    return {"V": V, "L": max(V * T, L0, 1e-300), "A": max(acc_scale, V / T), "P": max(A_max * V, 1e-300),
            "F": max(A_max * max(acc_scale, V / T), 1e-300)}
