"""Two curved-geometry examples with references derived here: a point mass in a bowl, a rod falling
onto a floor.

Holds :func:`bowl` with :class:`BowlReference`, and :func:`impacting_rod` with
:class:`RodImpactsReference` (both re-exported by :mod:`lcp.scenes.classical`). Imports the model
(:mod:`lcp.model`) and :class:`~lcp.scenes.scene.Scene`; never the simulation, the time stepping or
the event method.

- The bowl: a point mass inside a circle of radius R (gap R - |q|, a curved gap whose normal turns
  with q), Coulomb friction mu. While it slides on the wall at angle theta from the bottom,
  R theta'' = -g sin(theta) - mu sign(theta') (g cos(theta) + R theta'^2), with N = m (g cos(theta)
  + R theta'^2) > 0 below the rim; at each stop it sticks for ever if |tan(theta)| <= mu, and
  slides back otherwise. The reference integrates these phases (SciPy's DOP853, rtol 1e-12) with
  the stops as events.
- The rod: a rigid rod (half-length l, mass m, centroidal inertia m l^2 / 3) released at rest at an
  angle, its ends A (the lower) and B as two contacts with the floor (Coulomb mu, Newton e). Flights
  are in closed form (a parabola for the centre, a constant spin), each impact on one end is the
  one-contact Newton-Coulomb impulse (stick: u_T+ = 0 within the cone; else slide with
  |p_T| = mu p_N), and the next impact is the first root of either end's height. The reference
  covers the impacts on one end at a time and stops (``t_valid``) before two ends hit together or
  an impact comes slower than ``v_min`` (the approach of a resting or sliding phase).
"""
from __future__ import annotations

import math

import casadi as ca
import numpy as np

from lcp.model.system import Contact, System
from lcp.scenes.scene import Scene, check_params

__all__ = ["BowlReference", "RodImpactsReference", "bowl", "impacting_rod"]


# ----------------------------------------------------------------------------- the bowl
class BowlReference:
    """theta(t) of a point mass sliding on the wall of a circular bowl (module docstring).

    ``self(t)`` returns ``theta``, ``theta_dot``, ``N`` (normal force) and ``q``, ``v`` (len(t), 2);
    ``stops`` holds the times where theta' = 0, and ``stick_time`` the start of the final rest
    (inf if it slides on to the horizon).
    """

    def __init__(self, R: float, m: float, g: float, mu: float, theta0: float, omega0: float, t_end: float):
        from scipy.integrate import solve_ivp

        self.R, self.m, self.g, self.mu = R, m, g, mu
        self.pieces, self.stops, self.stick_time = [], [], math.inf
        t, th, w = 0.0, float(theta0), float(omega0)
        while t < t_end and len(self.pieces) < 10_000:
            if w == 0.0:
                if abs(math.tan(th)) <= mu:
                    self.stick_time = t
                    break
                sign = -math.copysign(1.0, th)  # it slides down, towards the bottom
            else:
                sign = math.copysign(1.0, w)

            def rhs(_, y, sign=sign):
                return [y[1], (-g * math.sin(y[0]) - sign * mu * (g * math.cos(y[0]) + R * y[1] ** 2)) / R]

            def stop(_, y):
                return y[1]

            stop.terminal, stop.direction = True, -sign
            sol = solve_ivp(rhs, (t, t_end), [th, w], method="DOP853", rtol=1e-12, atol=1e-14,
                            dense_output=True, events=stop)
            self.pieces.append((t, sol.t[-1], sol.sol))
            t, th = float(sol.t[-1]), float(sol.y[0, -1])
            if sol.status != 1:
                break
            w = 0.0
            self.stops.append(t)
        self.t_end = t_end
        self.final = (t, th)

    def __call__(self, t) -> dict:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        th, w = np.full(t.shape, self.final[1]), np.zeros(t.shape)
        for t0, t1, sol in self.pieces:
            sel = (t >= t0) & (t <= t1)
            if np.any(sel):
                y = sol(t[sel])
                th[sel], w[sel] = y[0], y[1]
        R = self.R
        q = np.column_stack([R * np.sin(th), -R * np.cos(th)])
        v = np.column_stack([R * np.cos(th) * w, R * np.sin(th) * w])
        N = self.m * (self.g * np.cos(th) + R * w * w)
        return {"theta": th, "theta_dot": w, "N": N, "q": q, "v": v}


def bowl(R: float = 1.0, mu: float = 0.1, theta0: float = 1.0, omega0: float = 0.0, m: float = 1.0,
         g: float = 9.81, e: float = 0.0, t_end: float = 3.0) -> Scene:
    """A point mass in a circular bowl of radius R centred at the origin: q = (x, y), gap R - |q|,
    tangent R atan2(x, -y) (the arc length from the bottom), friction ``mu``, restitution ``e``.
    Started on the wall at angle ``theta0`` from the bottom (|theta0| < pi/2, the contact stays
    loaded) with angular rate ``omega0``. Reference: :class:`BowlReference`.

    Examples
    --------
    >>> from lcp.scenes.bowl_rod import bowl
    >>> sc = bowl(mu=0.0, theta0=0.5, t_end=1.0)
    >>> float(sc.system.gaps(sc.q0)[0]) == 0.0, round(float(sc.exact([0.0])["N"][0]), 4)
    (True, 8.6091)
    """
    check_params(R=R, mu=mu, theta0=theta0, omega0=omega0, m=m, g=g, e=e, t_end=t_end)
    for k, val in dict(R=R, m=m, g=g, t_end=t_end).items():
        if val <= 0:
            raise ValueError(f"{k} must be > 0, got {val!r}")
    if mu < 0 or not 0 <= e <= 1:
        raise ValueError(f"need mu >= 0 and e in [0, 1], got mu = {mu!r}, e = {e!r}")
    if not abs(theta0) < math.pi / 2:
        raise ValueError(f"theta0 must lie in (-pi/2, pi/2) (below the rim), got {theta0!r}")
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    contact = Contact(gap=R - ca.sqrt(q[0] ** 2 + q[1] ** 2), tangent=R * ca.atan2(q[0], -q[1]), mu=mu, e=e,
                      name="bowl")
    system = System(q, v, m * ca.SX.eye(2), ca.vertcat(0, -m * g), contacts=[contact], names=("x", "y"))
    ref = BowlReference(float(R), float(m), float(g), float(mu), float(theta0), float(omega0), float(t_end))
    start = ref(0.0)
    return Scene(system, start["q"][0], start["v"][0], float(t_end), "bowl",
                 dict(R=R, mu=mu, theta0=theta0, omega0=omega0, m=m, g=g, e=e), ref)


# ----------------------------------------------------------------------------- the rod
class RodImpactsReference:
    """The falling rod's motion through its first impacts, each on one end (module docstring).

    ``impacts`` lists (time, end, p_N, p_T, mode) per impact (end 0 = A, 1 = B, mode "stick" or
    "slide"); ``t_valid`` is where the reference ends; ``self(t)`` returns ``q`` and ``v``
    (len(t), 3) for t <= t_valid.
    """

    def __init__(self, l, m, g, mu, e, q0, v0, t_end, max_impacts: int = 8, v_min: float = 0.05):
        from scipy.optimize import brentq

        self.l, self.m, self.g, self.mu, self.e = l, m, g, mu, e
        self.Minv = np.diag([1 / m, 1 / m, 3 / (m * l * l)])
        self.flights, self.impacts = [], []
        t, q, v = 0.0, np.array(q0, float), np.array(v0, float)
        self.t_valid = float(t_end)
        while len(self.impacts) < max_impacts:
            hits = []
            for end in (0, 1):
                t_hit = self._first_root(lambda s, end=end: self._end_height(q, v, s, end), t_end - t, brentq)
                if t_hit is not None:
                    hits.append((t_hit, end))
            self.flights.append((t, q.copy(), v.copy()))
            if not hits:
                break
            hits.sort()
            dt, end = hits[0]
            if len(hits) == 2 and hits[1][0] - dt < 1e-9 * max(1.0, dt):
                self.t_valid = t + dt  # both ends at once: outside this reference
                break
            q, v = self._flight(q, v, dt)
            t += dt
            H = self._rows(q[2], end)
            u = H @ v
            if -u[0] < v_min:
                self.t_valid = t  # a slow impact: a contact phase follows, outside this reference
                break
            p, mode = self._impulse(H, u)
            v = v + self.Minv @ H.T @ p
            self.impacts.append((t, end, float(p[0]), float(p[1]), mode))
        else:
            self.t_valid = min(self.t_valid, t)

    def _rows(self, th, end):
        s = -1.0 if end == 0 else 1.0  # A = centre - l e(theta), B = centre + l e(theta)
        return np.array([[0.0, 1.0, s * self.l * math.cos(th)], [1.0, 0.0, -s * self.l * math.sin(th)]])

    def _end_height(self, q, v, s, end):
        qq, _ = self._flight(q, v, s)
        sign = -1.0 if end == 0 else 1.0
        return qq[1] + sign * self.l * math.sin(qq[2])

    def _flight(self, q, v, s):
        return (np.array([q[0] + v[0] * s, q[1] + v[1] * s - 0.5 * self.g * s * s, q[2] + v[2] * s]),
                np.array([v[0], v[1] - self.g * s, v[2]]))

    @staticmethod
    def _first_root(f, horizon, brentq):
        """The first s in (0, horizon] where f changes sign (f > 0 at s = 0+), scanned on a grid fine
        enough for the spin (brentq on the first bracket)."""
        n = 4000
        s = np.linspace(0.0, horizon, n + 1)
        vals = np.array([f(x) for x in s])
        start = 1 if abs(vals[0]) < 1e-12 else 0  # leaving the floor just after an impact
        for i in range(start, n):
            if vals[i] > 0 >= vals[i + 1]:
                return brentq(f, s[i], s[i + 1], xtol=1e-15, rtol=4 * np.finfo(float).eps)
        return None

    def _impulse(self, H, u):
        W = H @ self.Minv @ H.T
        target = np.array([-self.e * u[0], 0.0])
        p = np.linalg.solve(W, target - u)
        if abs(p[1]) <= self.mu * p[0]:
            return p, "stick"
        s = math.copysign(1.0, p[1])  # friction along the sticking impulse, at its bound
        pN = -(1 + self.e) * u[0] / (W[0, 0] + s * self.mu * W[0, 1])
        return np.array([pN, s * self.mu * pN]), "slide"

    def __call__(self, t) -> dict:
        t = np.atleast_1d(np.asarray(t, dtype=float))
        if np.any(t > self.t_valid * (1 + 1e-12)):
            raise ValueError(f"the rod's reference ends at t = {self.t_valid:.6g}")
        starts = np.array([f[0] for f in self.flights])
        k = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(self.flights) - 1)
        q, v = np.empty((t.size, 3)), np.empty((t.size, 3))
        for i, (t0, qf, vf) in enumerate(self.flights):
            for j in np.flatnonzero(k == i):
                q[j], v[j] = self._flight(qf, vf, t[j] - t0)
        return {"q": q, "v": v}


def impacting_rod(theta0: float = 0.5, height: float = 0.5, mu: float = 0.3, e: float = 0.5, l: float = 0.5,
                  m: float = 1.0, g: float = 9.81, omega0: float = 0.0, t_end: float = 1.0) -> Scene:
    """A rigid rod (half-length l, mass m, inertia m l^2 / 3 about its centre) released at angle
    ``theta0`` to the floor, its lower end A at ``height`` above it, spinning at ``omega0``;
    q = (x, y, theta), contacts at both ends A = c - l e(theta) and B = c + l e(theta) with the floor
    (friction ``mu``, restitution ``e``). Reference: :class:`RodImpactsReference` (its impacts on
    one end, up to ``t_valid``).

    Examples
    --------
    >>> from lcp.scenes.bowl_rod import impacting_rod
    >>> sc = impacting_rod()
    >>> [(round(t, 6), end, mode) for t, end, _, _, mode in sc.solution.impacts[:2]]
    [(0.319275, 0, 'slide'), (0.408437, 1, 'slide')]
    """
    check_params(theta0=theta0, height=height, mu=mu, e=e, l=l, m=m, g=g, omega0=omega0, t_end=t_end)
    for k, val in dict(l=l, m=m, g=g, t_end=t_end).items():
        if val <= 0:
            raise ValueError(f"{k} must be > 0, got {val!r}")
    if height < 0 or mu < 0 or not 0 <= e <= 1:
        raise ValueError(f"need height >= 0, mu >= 0 and e in [0, 1], got {height!r}, {mu!r}, {e!r}")
    if not 0 <= theta0 < math.pi / 2:
        raise ValueError(f"theta0 must lie in [0, pi/2), got {theta0!r}")
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    x, y, th = q[0], q[1], q[2]
    ends = [(x - l * ca.cos(th), y - l * ca.sin(th)), (x + l * ca.cos(th), y + l * ca.sin(th))]
    contacts = [Contact(gap=ey, tangent=ex, mu=mu, e=e, name=name) for (ex, ey), name in zip(ends, "AB")]
    system = System(q, v, ca.diag(ca.DM([m, m, m * l * l / 3])), ca.vertcat(0, -m * g, 0), contacts=contacts,
                    names=("x", "y", "theta"))
    q0 = np.array([0.0, height + l * math.sin(theta0), theta0])
    v0 = np.array([0.0, 0.0, omega0])
    ref = RodImpactsReference(float(l), float(m), float(g), float(mu), float(e), q0, v0, float(t_end))
    return Scene(system, q0, v0, float(t_end), "impacting_rod",
                 dict(theta0=theta0, height=height, mu=mu, e=e, l=l, m=m, g=g, omega0=omega0), ref)
