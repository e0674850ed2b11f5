"""Classical systems of nonsmooth mechanics, with their exact solutions or independent references.

Each builder returns a :class:`lcp.scenes.Scene` (system, initial state, horizon, parameters) whose
``exact(t)`` evaluates the reference, derived here from the reduced equations:

- :func:`incline`: a block on an inclined plane with Coulomb friction; stick, slip down, a launch
  up the slope with stop and reversal (piecewise quadratic, exact);
- :func:`bouncing_ball`: Newton restitution e; impact times t_1 = sqrt(2 H / g),
  t_{k+1} = t_k + 2 e^k v_1 / g, accumulating at t_inf = t_1 (1 + e) / (1 - e), rest afterwards;
- :func:`painleve_rod`: a rod sliding on one end; consistent sliding (reference: ``solve_ivp`` of
  the sliding equations until lift-off or stop), and the paradoxical configurations, where the
  consistent motion starts with a tangential impact (:class:`PainleveRod`);
- :func:`pendulum`: a point mass held by the bilateral constraint x^2 + y^2 = L^2; exact motion
  through Jacobi's elliptic functions, period 4 K(k) sqrt(L / g), k = sin(theta0 / 2);
- :func:`stacked_blocks`: K blocks stacked on a floor (at rest), or two pushed at the bottom
  (all stick, sliding together, top slipping: exact);
- :func:`box_on_corners`: a box on its two bottom corners under a ramp force P = c t applied on
  its side; it slides (exact) or tips about its front corner (reference: ``solve_ivp``);
- :func:`rocking_block`: Housner's rocking block (e = 0, no slip): rotation about a corner, and at
  each impact theta' <- (1 - 3/2 sin^2 alpha) theta' (reference: ``solve_ivp`` with events);
- :func:`slider_crank` (from :mod:`lcp.scenes.slider_crank`): a slider-crank with a q-dependent mass
  matrix and nonlinear loop-closure constraints (reference: ``solve_ivp`` of the reduced equation);
- :func:`slider_crank_clearance` (:mod:`lcp.scenes.slider_crank_clearance`): Flores's slider-crank
  with a clearance joint, its slider's four corners as contacts (reference with zero clearance: the
  ideal crank);
- :func:`woodpecker` (:mod:`lcp.scenes.woodpecker`): Glocker's woodpecker toy, Siconos's data;
- :func:`bowl` and :func:`impacting_rod` (:mod:`lcp.scenes.bowl_rod`): a point mass in a bowl
  (curved gap; reference: the sliding phases by ``solve_ivp``) and a rod falling onto a floor on
  two end contacts (reference: flights in closed form and one-end impacts).

The references are derived here, independently of the simulators, so that tests can compare.
"""
from __future__ import annotations

import math

import casadi as ca
import numpy as np

from lcp.scenes.jean_pratt_exact import Segment
from lcp.model.forces import point_force
from lcp.scenes.scene import Scene
from lcp.model.system import Contact, System
from lcp.scenes.slider_crank import SliderCrankReference, slider_crank
from lcp.scenes.bowl_rod import BowlReference, RodImpactsReference, bowl, impacting_rod
from lcp.scenes.slider_crank_clearance import slider_crank_clearance
from lcp.scenes.woodpecker import woodpecker
from lcp.scenes.bead_column import bead_column

__all__ = [
    "bead_column",
    "BouncingBallExact",
    "BowlReference",
    "RodImpactsReference",
    "bowl",
    "impacting_rod",
    "slider_crank_clearance",
    "woodpecker",
    "BoxReference",
    "PainleveRod",
    "PendulumExact",
    "PiecewiseQuadratic",
    "RockingReference",
    "SliderCrankReference",
    "bouncing_ball",
    "box_on_corners",
    "incline",
    "painleve_rod",
    "pendulum",
    "rocking_block",
    "slider_crank",
    "stacked_blocks",
]


def _positive(**kw):
    for k, val in kw.items():
        if not isinstance(val, (int, float, np.floating, np.integer)) or not np.isfinite(val) or val <= 0:
            raise ValueError(f"{k} must be finite and > 0, got {val!r}")


def _finite(**kw):
    for k, val in kw.items():
        if not isinstance(val, (int, float, np.floating, np.integer)) or not np.isfinite(val):
            raise ValueError(f"{k} must be a finite number, got {val!r}")


def _mu(mu, name="mu"):
    _finite(**{name: mu})
    if mu < 0:
        raise ValueError(f"{name} must be >= 0, got {mu!r}")
    return float(mu)


# ----------------------------------------------------------------------------- piecewise quadratic
class PiecewiseQuadratic:
    """A motion s(t) made of constant-acceleration segments (:class:`lcp.scenes.jean_pratt_exact.Segment`), and the
    map from s to the scene's coordinates.

    ``self(t)`` returns ``s``, ``sd`` (its rate), ``N``, ``f`` per time, and ``q`` (len(t), n).
    """

    def __init__(self, segments, to_q):
        self.segments, self.to_q = list(segments), to_q

    def switch_times(self) -> np.ndarray:
        return np.array([sg.t0 for sg in self.segments[1:]])

    def __call__(self, t) -> dict:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        starts = np.array([sg.t0 for sg in self.segments])
        k = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(self.segments) - 1)
        out = {key: np.empty_like(t) for key in ("s", "sd", "N", "f")}
        for i, sg in enumerate(self.segments):
            sel = k == i
            dt = t[sel] - sg.t0
            out["s"][sel] = sg.x0 + sg.v0 * dt + 0.5 * sg.a * dt * dt
            out["sd"][sel] = sg.v0 + sg.a * dt
            out["N"][sel], out["f"][sel] = sg.N, sg.f
        out["q"] = self.to_q(out["s"])
        return out


def _segments(v0, t_end, accel, stick_ok, N, mu):
    """Segments of a 1-D Coulomb slider from s = 0 with velocity v0: ``accel(sign)`` is the
    acceleration while sliding in direction sign (+1/-1), ``stick_ok`` whether it sticks once at
    rest, ``N`` the (constant) normal force. f is the friction force along s."""
    segs, t, s, v = [], 0.0, 0.0, float(v0)
    while t < t_end and len(segs) < 4:
        if v == 0.0:
            if stick_ok:
                segs.append(Segment(t, math.inf, s, 0.0, 0.0, "stick", N, accel(0)))
                break
            a = accel(-1) if accel(-1) < 0 else accel(+1)  # leaves rest where the load points
            sign = -1.0 if a < 0 else 1.0
        else:
            sign = math.copysign(1.0, v)
            a = accel(sign)
        f = -sign * mu * N
        if a * sign >= 0:  # never stops
            segs.append(Segment(t, math.inf, s, v, a, "slide+" if sign > 0 else "slide-", N, f))
            break
        dt = -v / a
        segs.append(Segment(t, t + dt, s, v, a, "slide+" if sign > 0 else "slide-", N, f))
        s, t, v = s + v * dt + 0.5 * a * dt * dt, t + dt, 0.0
    return segs


# ----------------------------------------------------------------------------- incline
def incline(alpha: float = 0.3, mu: float = 0.2, v0: float = 0.0, m: float = 1.0, g: float = 9.81,
            t_end: float = 1.0) -> Scene:
    """A block (point mass) on a plane inclined at ``alpha``, with Coulomb friction.

    Coordinates q = (x, y) in the horizontal/vertical frame; the contact's gap is the distance to
    the plane n = -x sin(alpha) + y cos(alpha), its tangent the up-slope coordinate
    s = x cos(alpha) + y sin(alpha). Start at s = 0 with up-slope velocity ``v0``.

    Regimes (exact, piecewise quadratic in s): at rest it sticks iff tan(alpha) <= mu, else slides
    down at g (sin - mu cos); launched up (v0 > 0) it decelerates at g (sin + mu cos), stops at
    t1 = v0 / (g (sin + mu cos)), then sticks or slides back down (reversal).

    Examples
    --------
    >>> from lcp.scenes.classical import incline
    >>> sc = incline(alpha=0.5, mu=0.2, v0=2.0)
    >>> ex = sc.exact([0.0, 0.5, 1.0]); [round(float(x), 6) for x in ex["s"]]
    [0.0, 0.258197, -0.395784]
    """
    _finite(alpha=alpha, v0=v0)
    _positive(m=m, g=g, t_end=t_end)
    mu = _mu(mu)
    if not 0 <= alpha < math.pi / 2:
        raise ValueError(f"alpha must lie in [0, pi/2), got {alpha!r}")
    ca_, sa = math.cos(alpha), math.sin(alpha)
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    n_ = -q[0] * sa + q[1] * ca_
    s_ = q[0] * ca_ + q[1] * sa
    system = System(q, v, m * ca.SX.eye(2), ca.vertcat(0, -m * g),
                    contacts=[Contact(gap=n_, tangent=s_, mu=mu, name="plane")], names=("x", "y"))
    N = m * g * ca_

    def accel(sign):
        if sign == 0:  # stick: friction balances the weight along the slope
            return m * g * sa
        return -g * sa - sign * mu * g * ca_

    segs = _segments(v0, t_end, accel, sa <= mu * ca_, N, mu)
    sol = PiecewiseQuadratic(segs, lambda s: np.column_stack([s * ca_, s * sa]))
    params = dict(alpha=alpha, mu=mu, v0=v0, m=m, g=g)
    return Scene(system, np.zeros(2), v0 * np.array([ca_, sa]), float(t_end), "incline", params, sol)


# ----------------------------------------------------------------------------- bouncing ball
class BouncingBallExact:
    """Exact motion of a ball dropped from ``height`` with Newton restitution ``e``.

    Attributes: ``impact_times`` (those resolvable in floating point), ``impulses`` (m (1 + e) of
    each approach speed), ``t_inf`` (accumulation time t_1 (1 + e) / (1 - e), inf for e = 1).
    """

    def __init__(self, e, height, m, g):
        self.e, self.height, self.m, self.g = e, height, m, g
        t1 = math.sqrt(2 * height / g)
        v1 = g * t1
        times, speeds = [t1], [v1]  # impact times and approach speeds
        while len(times) < 2000:
            w = e * speeds[-1]
            if w <= 1e-15 * v1:
                break
            times.append(times[-1] + 2 * w / g)
            speeds.append(w)
        self.impact_times = np.array(times)
        self.approach_speeds = np.array(speeds)
        self.impulses = m * (1 + e) * self.approach_speeds
        self.t_inf = t1 * (1 + e) / (1 - e) if e < 1 else math.inf

    def __call__(self, t) -> dict:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        g, e = self.g, self.e
        k = np.searchsorted(self.impact_times, t, side="right")  # impacts before t
        y = np.zeros_like(t)
        yd = np.zeros_like(t)
        before = k == 0
        y[before] = self.height - 0.5 * g * t[before] ** 2
        yd[before] = -g * t[before]
        fly = (k > 0) & (t < self.t_inf)
        kk = k[fly] - 1
        w = e * self.approach_speeds[kk]  # rebound speed after impact kk
        dt = t[fly] - self.impact_times[kk]
        y[fly] = np.maximum(w * dt - 0.5 * g * dt * dt, 0.0)
        yd[fly] = w - g * dt
        return {"y": y, "yd": yd, "q": np.column_stack([np.zeros_like(t), y])}


def bouncing_ball(e: float = 0.5, height: float = 1.0, m: float = 1.0, g: float = 9.81, t_end: float | None = None,
                  mu: float = 0.0) -> Scene:
    """A ball (point mass, q = (x, y)) dropped from ``height`` onto the floor y = 0 with Newton
    restitution ``e`` in [0, 1].

    For e < 1 the impacts accumulate at t_inf = t_1 (1 + e) / (1 - e) (Zeno), after which the ball
    rests on the floor. The default horizon is 1.5 t_inf (4 t_1 for e = 1).

    Examples
    --------
    >>> from lcp.scenes.classical import bouncing_ball
    >>> sc = bouncing_ball(e=0.5, height=1.0)
    >>> round(sc.solution.t_inf, 6), round(float(sc.solution.impact_times[1]), 6)
    (1.354571, 0.903047)
    """
    _positive(height=height, m=m, g=g)
    _finite(e=e)
    if not 0 <= e <= 1:
        raise ValueError(f"e must lie in [0, 1], got {e!r}")
    mu = _mu(mu)
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    system = System(q, v, m * ca.SX.eye(2), ca.vertcat(0, -m * g),
                    contacts=[Contact(gap=q[1], tangent=q[0], mu=mu, e=e, name="floor")], names=("x", "y"))
    sol = BouncingBallExact(float(e), float(height), float(m), float(g))
    if t_end is None:
        t_end = 1.5 * sol.t_inf if e < 1 else 4 * sol.impact_times[0]
    _positive(t_end=t_end)
    return Scene(system, np.array([0.0, height]), np.zeros(2), float(t_end), "bouncing_ball",
                 dict(e=e, height=height, m=m, g=g, mu=mu), sol)


# ----------------------------------------------------------------------------- Painleve rod
class PainleveRod:
    """Analysis of a rod of half-length l, mass m, on one end A on a floor with friction mu.

    Coordinates q = (x, y, theta) of the centre of mass and the angle to the floor; A = (x - l cos
    theta, y - l sin theta). With the Delassus operator W (normal, tangent rows of A) and the free
    normal acceleration b_N = -g + l theta'^2 sin(theta):

    - sliding with u_T < 0 has normal coefficient W_NN + mu W_NT = (1 + 3 cos^2 - 3 mu sin cos) / m;
      where it is negative the configuration is paradoxical: **inconsistent** if b_N < 0 (no
      sliding or lift-off motion exists) and **indeterminate** if b_N > 0 (lift-off and an
      impulse both fit). The consistent motion then begins with a tangential impact that stops A
      at once: p = -W^-1 (0, u_T-), admissible exactly in that region (|p_T| <= mu p_N);
    - otherwise the rod slides (or lifts off if b_N > 0); :meth:`reference` integrates the
      sliding equations by ``solve_ivp`` until lift-off (N = 0) or stop (u_T = 0).
    """

    def __init__(self, mu, l, m, g, theta0, u0, omega0, horizon: float = 10.0):
        self.mu, self.l, self.m, self.g = mu, l, m, g
        self.theta0, self.u0, self.omega0 = theta0, u0, omega0
        s, c = math.sin(theta0), math.cos(theta0)
        self.W = np.array([[1 + 3 * c * c, -3 * s * c], [-3 * s * c, 1 + 3 * s * s]]) / m
        self.b_N = -g + l * omega0 ** 2 * s
        sign = math.copysign(1.0, u0) if u0 else 0.0
        self.slide_coefficient = self.W[0, 0] - sign * mu * self.W[0, 1]
        self.paradoxical = u0 != 0 and self.slide_coefficient <= 0
        if self.paradoxical:
            self.regime = "inconsistent" if self.b_N < 0 else "indeterminate"
        else:
            self.regime = "sliding" if self.b_N <= 0 else "lift-off"
        self._ref = None
        # the reference is integrated over [0, horizon] only: near a singular configuration the
        # sliding ODE becomes stiff, and integrating past what anybody asked for can take forever
        self.horizon = float(horizon)

    def tangential_impact(self):
        """(p_N, p_T), the impulse that stops A at once (stick), and the velocity jump dv."""
        p = -np.linalg.solve(self.W, np.array([0.0, self.u0]))
        s, c = math.sin(self.theta0), math.cos(self.theta0)
        H = np.array([[0.0, 1.0, -self.l * c], [1.0, 0.0, self.l * s]])
        Minv = np.diag([1 / self.m, 1 / self.m, 3 / (self.m * self.l ** 2)])
        return p, Minv @ H.T @ p

    def _rhs(self, _, z):
        _, _, th, xd, yd, thd = z
        m, l, g, mu = self.m, self.l, self.g, self.mu
        s, c = math.sin(th), math.cos(th)
        I = m * l * l / 3
        # the sliding branch keeps the direction of the launch: with sign(u_T) of the current state the
        # right-hand side jumps where u_T = 0 and the integrator chatters there instead of stopping
        # on the stop event (u_T crosses zero smoothly on the continued branch)
        sg = math.copysign(1.0, self.u0)
        # unknowns xdd, ydd, thdd, N: Newton-Euler with f = -sg mu N, and yA'' = 0
        HN, HT = np.array([0.0, 1.0, -l * c]), np.array([1.0, 0.0, l * s])
        M = np.diag([m, m, I])
        K = np.zeros((4, 4))
        K[:3, :3] = M
        K[:3, 3] = -(HN - sg * mu * HT)
        K[3, :3] = HN
        rhs = np.array([0.0, -m * g, 0.0, -l * s * thd * thd])
        sol = np.linalg.solve(K, rhs)
        return np.array([xd, yd, thd, *sol[:3]]), sol[3]

    @property
    def t_valid(self) -> float:
        """End of the sliding reference: lift-off (N = 0), stop (u_T = 0), the rod lying flat, the approach of
        a Painleve singularity (sliding coefficient down to 1e-3 of its start), or the horizon."""
        return float(self._sliding().t[-1])

    def _sliding(self):
        from scipy.integrate import solve_ivp

        if self.regime != "sliding":
            raise ValueError(f"no sliding reference in the {self.regime} regime")
        if self._ref is None:
            l, th = self.l, self.theta0
            s, c = math.sin(th), math.cos(th)
            z0 = [0.0, l * s, th, self.u0 - l * s * self.omega0, l * c * self.omega0, self.omega0]

            def lift(_, z):
                return self._rhs(_, z)[1]

            def stop(_, z):
                return z[3] + l * math.sin(z[2]) * z[5]

            def flat(_, z):
                return z[2]

            sg = math.copysign(1.0, self.u0)
            mu, W00 = self.mu, self.W[0, 0]

            def painleve(_, z):
                # the sliding coefficient W_NN - sg mu W_NT of the current angle: where it reaches zero
                # the normal force blows up (Painleve) and the sliding ODE turns infinitely stiff, so
                # the reference ends a little before, at 1e-3 of its value at the start
                si, co = math.sin(z[2]), math.cos(z[2])
                return (1 + 3 * co * co + sg * mu * 3 * si * co) / self.m - 1e-3 * abs(W00)

            for ev in (lift, stop, flat, painleve):
                ev.terminal = True
            self._ref = solve_ivp(lambda tt, z: self._rhs(tt, z)[0], (0.0, self.horizon), z0, method="DOP853",
                                  rtol=1e-12, atol=1e-14, dense_output=True, events=(lift, stop, flat, painleve))
        return self._ref

    def reference(self, t):
        """q(t) of the consistent sliding motion (``solve_ivp``, DOP853, rtol 1e-12), valid for
        t <= :attr:`t_valid`."""
        t = np.atleast_1d(np.asarray(t, dtype=float))
        sol = self._sliding()
        if np.any(t > self.t_valid + 1e-15):
            raise ValueError(f"the sliding reference ends at t = {self.t_valid:.6g}")
        return sol.sol(t)[:3].T

    def __call__(self, t) -> dict:
        return {"q": self.reference(t)}


def painleve_rod(mu: float = 0.3, theta0: float = math.pi / 6, u0: float = -1.0, omega0: float = 0.0,
                 l: float = 0.5, m: float = 1.0, g: float = 9.81, t_end: float = 0.2) -> Scene:
    """The Painleve rod: a rod (half-length l, mass m, centroidal inertia m l^2 / 3) at angle
    ``theta0`` to the floor, its lower end A sliding at ``u0`` (A = left end: u0 < 0 moves A away
    from the rod's top), turning at ``omega0``; contact at A with friction ``mu``.

    ``scene.solution`` is a :class:`PainleveRod` (regime, tangential impact, sliding reference).
    With u0 < 0 the configuration is paradoxical when mu > (1 + 3 cos^2) / (3 sin cos) (2.50 at
    theta0 = pi/6).

    Examples
    --------
    >>> from lcp.scenes.classical import painleve_rod
    >>> painleve_rod(mu=3.0).solution.regime, painleve_rod(mu=3.0, omega0=8.0).solution.regime
    ('inconsistent', 'indeterminate')
    """
    _positive(l=l, m=m, g=g, t_end=t_end)
    _finite(u0=u0, omega0=omega0)
    mu = _mu(mu)
    if not 0 < theta0 < math.pi / 2:
        raise ValueError(f"theta0 must lie in (0, pi/2), got {theta0!r}")
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    x, y, th = q[0], q[1], q[2]
    A = ca.vertcat(x - l * ca.cos(th), y - l * ca.sin(th))
    system = System(q, v, ca.diag(ca.vertcat(m, m, m * l * l / 3)), ca.vertcat(0, -m * g, 0),
                    contacts=[Contact(gap=A[1], tangent=A[0], mu=mu, name="A")], names=("x", "y", "theta"))
    s, c = math.sin(theta0), math.cos(theta0)
    q0 = np.array([0.0, l * s, theta0])
    v0 = np.array([u0 - l * s * omega0, l * c * omega0, omega0])
    sol = PainleveRod(mu, l, m, g, theta0, u0, omega0, horizon=2.0 * float(t_end))
    return Scene(system, q0, v0, float(t_end), "painleve_rod",
                 dict(mu=mu, theta0=theta0, u0=u0, omega0=omega0, l=l, m=m, g=g), sol)


# ----------------------------------------------------------------------------- pendulum
class PendulumExact:
    """theta(t) = 2 arcsin(k sn(K - w t | k^2)), k = sin(theta0 / 2), w = sqrt(g / L): the exact
    pendulum released from rest at theta0 (from the downward vertical). ``period`` = 4 K / w."""

    def __init__(self, L, theta0, g):
        from scipy.special import ellipk

        self.L, self.theta0, self.g = L, theta0, g
        self.k = math.sin(theta0 / 2)
        self.K = float(ellipk(self.k ** 2))
        self.w = math.sqrt(g / L)
        self.period = 4 * self.K / self.w

    def __call__(self, t) -> dict:
        from scipy.special import ellipj

        t = np.atleast_1d(np.asarray(t, dtype=float))
        sn, cn, dn, _ = ellipj(self.K - self.w * t, self.k ** 2)
        th = 2 * np.arcsin(self.k * sn)
        thd = -2 * self.k * self.w * cn * dn / np.cos(th / 2)
        L = self.L
        q = np.column_stack([L * np.sin(th), -L * np.cos(th)])
        return {"theta": th, "theta_dot": thd, "q": q,
                "v": np.column_stack([L * np.cos(th) * thd, L * np.sin(th) * thd])}


def pendulum(L: float = 1.0, theta0: float = math.pi / 2, m: float = 1.0, g: float = 9.81,
             periods: float = 1.0) -> Scene:
    """A point mass on a massless rod of length L about the origin: q = (x, y) and the bilateral
    constraint x^2 + y^2 - L^2 = 0 (nonlinear in q: Moreau-Jean projects it, :mod:`lcp.timestepping.projection`).
    Released from rest at ``theta0`` in (0, pi) from the downward vertical; horizon ``periods``
    exact periods.

    Examples
    --------
    >>> from lcp.scenes.classical import pendulum
    >>> sc = pendulum(L=1.0, theta0=math.pi / 2)
    >>> round(sc.solution.period, 10)
    2.3678419476
    """
    _positive(L=L, m=m, g=g, periods=periods)
    if not 0 < theta0 < math.pi:
        raise ValueError(f"theta0 must lie in (0, pi), got {theta0!r}")
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    system = System(q, v, m * ca.SX.eye(2), ca.vertcat(0, -m * g), constraints=q[0] ** 2 + q[1] ** 2 - L ** 2,
                    names=("x", "y"))
    sol = PendulumExact(float(L), float(theta0), float(g))
    q0 = np.array([L * math.sin(theta0), -L * math.cos(theta0)])
    return Scene(system, q0, np.zeros(2), periods * sol.period, "pendulum",
                 dict(L=L, theta0=theta0, m=m, g=g), sol)


# ----------------------------------------------------------------------------- stacked blocks
def stacked_blocks(K: int = 2, m=1.0, mu=0.5, push: float = 0.0, height: float = 0.1, g: float = 9.81,
                   t_end: float = 1.0) -> Scene:
    """K blocks (translating point masses, q = (x_0, y_0, ..., x_{K-1}, y_{K-1})) stacked on a floor,
    block i resting on block i - 1 (gap y_i - y_{i-1} - height, tangent x_i - x_{i-1}, friction
    mu[i]; block 0 on the floor with mu[0]); a constant horizontal force ``push`` >= 0 on block 0.

    Exact solution (``scene.exact``: x, N per contact) at rest (push = 0, any K), and for K = 2
    pushed: all stick if push <= mu_0 (m_0 + m_1) g; else both slide together at
    a = (push - mu_0 (m_0 + m_1) g) / (m_0 + m_1) if a <= mu_1 g; else the top slips (a_1 = mu_1 g).
    The regime is ``scene.params["regime"]``.

    Examples
    --------
    >>> from lcp.scenes.classical import stacked_blocks
    >>> [stacked_blocks(2, mu=[0.5, 0.3], push=P).params["regime"] for P in (5.0, 12.0, 20.0)]
    ['stick', 'together', 'top slips']
    """
    if not isinstance(K, (int, np.integer)) or K < 1:
        raise ValueError(f"K must be an integer >= 1, got {K!r}")
    ms = np.broadcast_to(np.asarray(m, dtype=float), (K,)).copy()
    mus = np.broadcast_to(np.asarray(mu, dtype=float), (K,)).copy()
    if np.any(~np.isfinite(ms)) or np.any(ms <= 0):
        raise ValueError(f"m must be finite and > 0, got {m!r}")
    if np.any(~np.isfinite(mus)) or np.any(mus < 0):
        raise ValueError(f"mu must be finite and >= 0, got {mu!r}")
    _positive(height=height, g=g, t_end=t_end)
    _finite(push=push)
    if push < 0:
        raise ValueError(f"push must be >= 0, got {push!r}")
    if push > 0 and K != 2:
        raise ValueError("a pushed stack has an exact solution here for K = 2 only")
    n = 2 * K
    q, v = ca.SX.sym("q", n), ca.SX.sym("v", n)
    contacts = [Contact(gap=q[1], tangent=q[0], mu=float(mus[0]), name="floor")]
    for i in range(1, K):
        contacts.append(Contact(gap=q[2 * i + 1] - q[2 * i - 1] - height, tangent=q[2 * i] - q[2 * i - 2],
                                mu=float(mus[i]), name=f"block{i - 1}-block{i}"))
    F = [0.0] * n
    for i in range(K):
        F[2 * i + 1] = -ms[i] * g
    F[0] += push
    system = System(q, v, ca.SX(np.diag(np.repeat(ms, 2))), ca.vertcat(*F), contacts=contacts,
                    names=[nm for i in range(K) for nm in (f"x{i}", f"y{i}")])
    q0 = np.zeros(n)
    q0[1::2] = height * np.arange(K)
    N = g * np.cumsum(ms[::-1])[::-1]  # contact i carries the blocks i..K-1
    acc = np.zeros(K)
    regime = "rest"
    if push > 0:
        M = ms.sum()
        if push <= mus[0] * M * g:
            regime = "stick"
        else:
            a = (push - mus[0] * M * g) / M
            if a <= mus[1] * g:
                regime, acc[:] = "together", a
            else:
                regime = "top slips"
                acc[1] = mus[1] * g
                acc[0] = (push - mus[0] * M * g - mus[1] * ms[1] * g) / ms[0]

    def exact(t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        Q = np.tile(q0, (t.size, 1))
        Q[:, 0::2] += 0.5 * np.outer(t * t, acc)
        return {"q": Q, "N": np.tile(N, (t.size, 1)), "a": acc}

    params = dict(K=K, m=ms, mu=mus, push=push, height=height, g=g, regime=regime)
    return Scene(system, q0, np.zeros(n), float(t_end), f"stacked_blocks_{K}", params, exact)


# ----------------------------------------------------------------------------- box on two corners
def _box_system(w, H, m, g, mu, e, extra_force=None, t=None, name="box"):
    """A rigid box (q = x, y of the centre, angle theta) with its two bottom corners as contacts."""
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    x, y, th = q[0], q[1], q[2]
    c, s = ca.cos(th), ca.sin(th)

    def body_point(a, b):
        return ca.vertcat(x + a * c - b * s, y + a * s + b * c)

    corners = [body_point(-w / 2, -H / 2), body_point(w / 2, -H / 2)]
    contacts = [Contact(gap=p[1], tangent=p[0], mu=mu, e=e, name=nm) for p, nm in zip(corners, ("back", "front"))]
    I = m * (w * w + H * H) / 12
    F = ca.vertcat(0, -m * g, 0)
    if extra_force is not None:
        F = F + extra_force(q, body_point)
    system = System(q, v, ca.diag(ca.vertcat(m, m, I)), F, contacts=contacts, t=t, names=("x", "y", "theta"))
    return system


class BoxReference:
    """Reference motion of the box pushed by P = c t at height hp on its back face.

    Statics: it slides when P reaches mu m g (t_slide), tips about the front corner when the moment
    P hp reaches m g w / 2 (t_tip); whichever comes first. While sliding without rotation,
    x = c (t - t_slide)^3 / (6 m) (exact), valid while the back corner stays loaded:
    P (hp - H/2) + mu m g H/2 <= m g w / 2. While tipping on a sticking front corner, theta follows
    I_O theta'' = m g (w/2 cos + H/2 sin) + (w sin - hp cos) P(t), I_O = m (w^2 + H^2) / 3
    (``solve_ivp``, rtol 1e-12), valid while the corner's friction holds (checked: :attr:`t_valid`).
    """

    def __init__(self, w, H, m, g, mu, c, hp):
        self.w, self.H, self.m, self.g, self.mu, self.c, self.hp = w, H, m, g, mu, c, hp
        self.t_slide = mu * m * g / c
        self.t_tip = m * g * w / (2 * hp * c)
        self.regime = "slide" if self.t_slide < self.t_tip else "tip"
        if self.regime == "slide":
            lever = hp - H / 2
            P_max = (m * g * w / 2 - mu * m * g * H / 2) / lever if lever > 0 else math.inf
            self.t_valid = P_max / c
        else:
            self.t_valid = math.inf
        self._ref = None

    def _tip_rhs(self, t, z):
        th, thd = z
        w, H, m, g, hp = self.w, self.H, self.m, self.g, self.hp
        IO = m * (w * w + H * H) / 3
        P = self.c * t
        thdd = (m * g * (w / 2 * math.cos(th) + H / 2 * math.sin(th)) + (w * math.sin(th) - hp * math.cos(th)) * P) / IO
        return [thd, thdd]

    def _pivot_force(self, t, z):
        """Reaction (R_x, R_y) at the front corner while tipping about it."""
        th, thd = z
        thdd = self._tip_rhs(t, z)[1]
        a, b = -self.w / 2, self.H / 2  # centre relative to the corner, body frame
        c, s = math.cos(th), math.sin(th)
        rx, ry = a * c - b * s, a * s + b * c
        ax = -ry * thdd - rx * thd * thd
        ay = rx * thdd - ry * thd * thd
        return self.m * ax - self.c * t, self.m * ay + self.m * self.g

    def __call__(self, t) -> dict:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if np.any(t > self.t_valid):
            raise ValueError(f"the reference holds up to t = {self.t_valid:.6g}")
        if self.regime == "slide":
            dt = np.maximum(t - self.t_slide, 0.0)
            return {"x": self.c * dt ** 3 / (6 * self.m), "theta": np.zeros_like(t)}
        return {"theta": self.tip_angle(t), "x": None}

    def tip_angle(self, t):
        from scipy.integrate import solve_ivp

        t = np.atleast_1d(np.asarray(t, dtype=float))
        if self._ref is None:
            def slip(tt, z):
                Rx, Ry = self._pivot_force(tt, z)
                return self.mu * Ry - abs(Rx)
            slip.terminal = True
            self._ref = solve_ivp(self._tip_rhs, (self.t_tip, self.t_tip + 5.0), [0.0, 0.0], method="DOP853",
                                  rtol=1e-12, atol=1e-14, dense_output=True, events=slip)
            self.t_valid = float(self._ref.t[-1])
        out = np.zeros_like(t)
        late = t > self.t_tip
        if late.any():
            out[late] = self._ref.sol(t[late])[0]
        return out


def box_on_corners(w: float = 1.0, H: float = 0.5, m: float = 1.0, mu: float = 0.3, ramp: float = 5.0,
                   push_height: float = 0.25, g: float = 9.81, t_end: float = 1.2) -> Scene:
    """A box (width w, height H, mass m) resting on its two bottom corners, pushed horizontally
    by P(t) = ramp t at ``push_height`` above its base on its back face (the force is written with
    :func:`lcp.model.forces.point_force`, so it follows the face when the box turns).

    It slides first when mu m g < m g w / (2 push_height), else it tips about its front corner
    (``scene.solution``: :class:`BoxReference`).

    Examples
    --------
    >>> from lcp.scenes.classical import box_on_corners
    >>> box_on_corners(mu=0.3).solution.regime, box_on_corners(mu=1.2, push_height=0.45).solution.regime
    ('slide', 'tip')
    """
    _positive(w=w, H=H, m=m, ramp=ramp, push_height=push_height, g=g, t_end=t_end)
    mu = _mu(mu)
    if push_height > H:
        raise ValueError(f"push_height must lie on the face (<= H = {H}), got {push_height!r}")
    t = ca.SX.sym("t")

    def push(q, body_point):
        return point_force(q, body_point(-w / 2, -H / 2 + push_height), ca.vertcat(ramp * t, 0))

    system = _box_system(w, H, m, g, mu, 0.0, push, t=t)
    sol = BoxReference(w, H, m, g, mu, ramp, push_height)
    return Scene(system, np.array([0.0, H / 2, 0.0]), np.zeros(3), float(t_end), "box_on_corners",
                 dict(w=w, H=H, m=m, mu=mu, ramp=ramp, push_height=push_height, g=g), sol)


# ----------------------------------------------------------------------------- rocking block
class RockingReference:
    """Housner's rocking block: rotation about the corner in contact, I_O theta'' =
    -m g R sin(alpha sign(theta) - theta) with I_O = 4 m R^2 / 3, R the half-diagonal,
    alpha = atan(b / h); at theta = 0 the other corner takes over without bounce or slip and
    angular momentum about it is kept: theta' <- r theta', r = 1 - 3/2 sin^2(alpha)
    (``solve_ivp`` with events, rtol 1e-12). ``impact_times`` lists the impacts found."""

    def __init__(self, b, h, g, theta0):
        from scipy.integrate import solve_ivp

        self.R = math.hypot(b, h)
        self.alpha = math.atan2(b, h)
        self.p2 = 3 * g / (4 * self.R)
        self.r = 1 - 1.5 * math.sin(self.alpha) ** 2
        al, p2 = self.alpha, self.p2

        def rhs(_, z):
            th, thd = z
            sgn = 1.0 if th > 0 or (th == 0 and thd > 0) else -1.0
            return [thd, -p2 * math.sin(al * sgn - th)]

        self.pieces, self.impact_times = [], []
        t0, z = 0.0, [theta0, 0.0]
        while len(self.impact_times) < 12:
            def cross(_, y):
                return y[0]
            cross.terminal = True
            # the next crossing, not the one a piece starts on
            cross.direction = -1.0 if z[0] > 0 or (z[0] == 0 and z[1] > 0) else 1.0
            sol = solve_ivp(rhs, (t0, t0 + 10.0), z, method="DOP853", rtol=1e-12, atol=1e-14,
                            dense_output=True, events=cross)
            self.pieces.append(sol)
            if sol.status != 1:
                break
            t0 = float(sol.t[-1])
            self.impact_times.append(t0)
            z = [0.0, self.r * float(sol.y[1, -1])]

    def __call__(self, t) -> dict:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        th = np.empty_like(t)
        starts = np.array([p.t[0] for p in self.pieces])
        k = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(self.pieces) - 1)
        for i, p in enumerate(self.pieces):
            sel = k == i
            if sel.any():
                th[sel] = p.sol(t[sel])[0]
        return {"theta": th}


def rocking_block(b: float = 0.1, h: float = 0.4, theta0: float = 0.1, m: float = 1.0, g: float = 9.81,
                  mu: float = 2.0, t_end: float = 1.5) -> Scene:
    """Housner's rocking block: a block of half-width b, half-height h on its two bottom corners
    (e = 0, friction mu large enough not to slip), released from rest tilted by ``theta0`` in
    (0, alpha) about its left corner. ``scene.solution``: :class:`RockingReference`.

    Examples
    --------
    >>> from lcp.scenes.classical import rocking_block
    >>> sc = rocking_block()
    >>> round(sc.solution.r, 6), round(sc.solution.impact_times[0], 6)
    (0.911765, 0.264713)
    """
    _positive(b=b, h=h, m=m, g=g, t_end=t_end, theta0=theta0)
    mu = _mu(mu)
    alpha = math.atan2(b, h)
    if theta0 >= alpha:
        raise ValueError(f"theta0 must be < alpha = atan(b / h) = {alpha:.6g} (the block would topple)")
    system = _box_system(2 * b, 2 * h, m, g, mu, 0.0)
    # the left corner at the origin, the block turned by theta0 about it
    c, s = math.cos(theta0), math.sin(theta0)
    q0 = np.array([b * c - h * s, b * s + h * c, theta0])
    sol = RockingReference(b, h, g, theta0)
    return Scene(system, q0, np.zeros(3), float(t_end), "rocking_block",
                 dict(b=b, h=h, theta0=theta0, m=m, g=g, mu=mu), sol)
