r"""Exact solutions of a point mass sliding in a plane with isotropic (disk) Coulomb friction.

While the sliding velocity U (a 2-vector in the plane) is non-zero, the reduced motion is

    U' = b - a U / |U|,        X' = U,

with ``b`` the in-plane applied acceleration (gravity's in-plane part, a lateral force over the
mass) and ``a = mu N / m`` the friction deceleration (N constant). When |U| reaches 0 the block
sticks if |b| <= a; otherwise it slips again along b with acceleration |b| - a.

**The turning solution.** Take e1 = b / |b|, f = |b|, k = a / f, and let phi in [0, pi] be the
angle from e1 to U. Along and across U the equations read s' = f cos(phi) - a (s = |U|) and
s phi' = -f sin(phi): the velocity turns towards b. Dividing, d ln s / d phi = k / sin(phi) -
cot(phi), so s = C tan(phi/2)**k / sin(phi). With u = tan(phi/2), dt = -s du / (f u), and the
time and the positions are integrals of powers of u. Normalised by the launch, r = u / u0 in
(0, 1] (r = 1 at t = 0, r -> 0 at the stop or as t -> inf), c = cos(phi0/2), sg = sin(phi0/2) and
J(r, p) = (1 - r**p) / p (-> -ln r for p = 0), everything is a short sum::

    t      = (s0 / f)   [c**2 J(r, k-1) + sg**2 J(r, k+1)]
    U_par  = s0 r**(k-1) (c**2 - sg**2 r**2),       U_perp = s0 sin(phi0) r**k
    speed  = s0 r**(k-1) (c**2 + sg**2 r**2)
    X_par  = (s0**2 / f) [c**4 J(r, 2k-2) - sg**4 J(r, 2k+2)]
    X_perp = (2 s0**2 / f) [c**3 sg J(r, 2k-1) + c sg**3 J(r, 2k+1)]
    path   = (s0**2 / f) [c**4 J(r, 2k-2) + 2 c**2 sg**2 J(r, 2k) + sg**4 J(r, 2k+2)]

(par along e1, perp towards the launch side). Each line was checked by differentiation: d/dr of
the positions over dt/dr gives the velocities, and those satisfy the equations of motion; the
energy balance s**2/2 - s0**2/2 = f X_par - a path holds identically. The straight launches
phi0 = 0 (c = 1) and phi0 = pi (sg = 0) are the same formulas; k = 1 and k = 1/2 turn terms into
logarithms through J(r, 0) = -ln r, which :func:`_J` evaluates as -expm1(-p z)/p with z = -ln r
(continuous in p, no cancellation near the logarithmic cases).

The stop (r -> 0 at finite t) happens when k > 1, or for phi0 = pi with any k:
t_stop = (s0 / f) [c**2 / (k-1) + sg**2 / (k+1)]. For k = 1 (an incline with mu = tan(theta)) the
block never stops: s (1 + cos(phi)) = s0 (1 + cos(phi0)) is conserved, the speed tends to
s0 cos(phi0/2)**2 (v0/2 for a horizontal launch) and the lateral drift to
(2 s0**2 / f) (c**3 sg + c sg**3 / 3).

Given t, r follows from the first line by a safeguarded Newton iteration in z = -ln r (dt/dz =
speed / f > 0), to round-off. Without in-plane load (b = 0) the motion is straight with constant
deceleration a: t_stop = s0 / a, distance s0**2 / (2 a).

:func:`reduced_reference` integrates the reduced equations numerically (DOP853, rtol 1e-14) in
the rescaled time tau with dt = |U| d tau (smooth up to the stop, which it approaches
exponentially), as an independent check of the closed forms.

Examples
--------
>>> import math
>>> from lcp.scenes.spatial_exact import InclineSlideExact
>>> inc = InclineSlideExact(theta=math.radians(30), v0=2.0)
>>> inc.limit_speed, inc.t_stop
(1.0, inf)
>>> st = inc.state([0.0, 1.0])
>>> [round(float(v), 12) for v in st["speed"] * (1 + st["vx"] / st["speed"])]
[2.0, 2.0]
"""
from __future__ import annotations

import math
import numbers

import numpy as np
from scipy.integrate import solve_ivp

__all__ = [
    "ConstantLoadSlide",
    "InclineSlideExact",
    "LateralForceSlideExact",
    "PlaneSlideExact",
    "reduced_reference",
]

_KEYS = ("t", "x", "y", "vx", "vy", "speed", "phi", "path")


def _number(name, v, lo=None, strict=False, hi=None, hi_strict=True):
    if isinstance(v, bool) or not isinstance(v, (numbers.Real, np.number)) or not math.isfinite(float(v)):
        raise ValueError(f"{name} must be a finite number, got {v!r}")
    v = float(v)
    if lo is not None and (v <= lo if strict else v < lo):
        raise ValueError(f"{name} must be {'>' if strict else '>='} {lo}, got {v!r}")
    if hi is not None and (v >= hi if hi_strict else v > hi):
        raise ValueError(f"{name} must be {'<' if hi_strict else '<='} {hi}, got {v!r}")
    return v


def _vector2(name, v):
    try:
        arr = np.asarray(v, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a 2-vector of finite numbers, got {v!r}") from exc
    if arr.shape != (2,) or not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be a 2-vector of finite numbers, got {v!r}")
    return arr


def _times(t):
    t = np.asarray(t, dtype=float)
    if not np.all(np.isfinite(t)) or np.any(t < 0):
        raise ValueError("t must hold finite times >= 0")
    return t


def _J(z, p):
    """J(r, p) = (1 - r**p) / p at r = exp(-z), continuous in p (J = z at p = 0)."""
    if p == 0.0:
        return z
    with np.errstate(over="ignore"):
        return -np.expm1(-p * z) / p


class ConstantLoadSlide:
    """Sliding under a constant in-plane acceleration ``accel`` and friction deceleration ``decel``.

    The general solution behind the scenes of this module (see the module docstring for the
    formulas): U' = accel - decel U/|U| while U != 0, then stick if |accel| <= decel, else slip
    from rest along accel.

    Parameters
    ----------
    accel : 2-vector
        In-plane applied acceleration b (force over mass).
    decel : float
        Friction deceleration a = mu N / m >= 0.
    v0 : 2-vector
        Initial sliding velocity.

    Attributes
    ----------
    k : float
        decel / |accel| (inf without load).
    t_stop : float
        Time at which U reaches 0 (inf if it never does).
    limit_speed : float
        Speed as t -> inf while sliding (0 if the block stops and sticks, inf if it accelerates).

    Examples
    --------
    >>> s = ConstantLoadSlide(accel=[1.0, 0.0], decel=2.0, v0=[0.0, 1.0])
    >>> round(s.t_stop, 12)           # (s0/f) [c**2/(k-1) + sg**2/(k+1)] with c**2 = sg**2 = 1/2
    0.666666666667
    >>> st = s.state([s.t_stop, 5.0])
    >>> st["speed"].tolist(), bool(st["x"][0] == st["x"][1])
    ([0.0, 0.0], True)
    """

    def __init__(self, accel, decel, v0):
        self.accel = _vector2("accel", accel)
        self.decel = _number("decel", decel, 0.0)
        self.v0 = _vector2("v0", v0)
        b, a = self.accel, self.decel
        self.f = float(math.hypot(*b))
        self.s0 = float(math.hypot(*self.v0))
        if 0 < self.f <= 1e-18 * a:
            # a load below rounding against friction (k > 1e18, overflowing for subnormal loads)
            # changes nothing in the slide: treat it as none (the block sticks at the end anyway)
            self.f = 0.0
        s0, f = self.s0, self.f
        if f > 0:
            self.e1 = b / math.hypot(*b)
        elif s0 > 0:
            self.e1 = self.v0 / s0   # no load: the frame follows the launch
        else:
            self.e1 = np.array([1.0, 0.0])
        perp = np.array([-self.e1[1], self.e1[0]])
        vpar, vperp = float(self.v0 @ self.e1), float(self.v0 @ perp)
        self.e2 = perp if vperp >= 0 else -perp   # the launch side
        vperp = abs(vperp)
        self.k = a / f if f > 0 else math.inf
        # cos**2 and sin**2 of phi0/2 without cancellation: exactly 0 for straight launches
        if s0 == 0:
            c2, sg2 = 1.0, 0.0
        elif vpar >= 0:
            c2, sg2 = (s0 + vpar) / (2 * s0), vperp * vperp / (2 * s0 * (s0 + vpar))
        else:
            sg2, c2 = (s0 - vpar) / (2 * s0), vperp * vperp / (2 * s0 * (s0 - vpar))
        self.c2, self.sg2, self.csg = c2, sg2, vperp / (2 * s0) if s0 > 0 else 0.0
        self.phi0 = math.atan2(vperp, vpar) if s0 > 0 else 0.0
        k = self.k
        if s0 == 0:
            self.t_stop = 0.0
        elif f == 0:
            self.t_stop = s0 / a if a > 0 else math.inf
        elif c2 == 0 or k > 1:
            self.t_stop = (s0 / f) * ((c2 / (k - 1) if c2 > 0 else 0.0) + sg2 / (k + 1))
        else:
            self.t_stop = math.inf
        self.sticks = f <= a
        if math.isfinite(self.t_stop):
            self.limit_speed = 0.0 if self.sticks else math.inf
        elif f > 0 and k == 1:
            self.limit_speed = s0 * c2
        else:
            self.limit_speed = math.inf if f > 0 or a == 0 else 0.0
            if f == 0 and a == 0:
                self.limit_speed = s0
        self.launch_direction = math.atan2(self.v0[1], self.v0[0]) if s0 > 0 else 0.0
        self._stop = None
        if s0 == 0:
            self._stop = {key: np.zeros(1) for key in ("par", "perp", "vpar", "vperp", "speed", "phi", "path")}
        elif math.isfinite(self.t_stop):
            self._stop = self._sliding(np.array([self.t_stop]), at_stop=True)

    # -- the sliding arc in the frame (e1, e2) -------------------------------------------------
    def _z_of_t(self, t):
        """z = -ln r solving t(z) = t (t < t_stop), by Newton with a bisection safeguard."""
        s0, f, k, c2, sg2 = self.s0, self.f, self.k, self.c2, self.sg2

        def T(z):
            return (s0 / f) * (c2 * _J(z, k - 1) + sg2 * _J(z, k + 1))

        def dT(z):
            return (s0 / f) * (c2 * np.exp(-(k - 1) * z) + sg2 * np.exp(-(k + 1) * z))

        lo = np.zeros_like(t)
        hi = np.full_like(t, 1.0 / (k + 1))   # z scales like 1/k: a weak load (k ~ 1e80) needs tiny z
        for _ in range(2200):          # bracket: T(hi) >= t
            short = (T(hi) < t) & (hi < 1e300)
            if not np.any(short):
                break
            lo = np.where(short, hi, lo)
            hi = np.where(short, 2 * hi, hi)
        # times within rounding of t_stop: no finite z reaches them, the state is the stop state
        unreached = ~(T(hi) >= t)
        hi = np.where(unreached, lo, hi)
        z = 0.5 * (lo + hi)
        for _ in range(200):
            g = T(z) - t
            lo = np.where(g <= 0, z, lo)
            hi = np.where(g >= 0, z, hi)
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                zn = z - g / dT(z)
            bad = ~np.isfinite(zn) | (zn < lo) | (zn > hi)
            zn = np.where(bad, 0.5 * (lo + hi), zn)
            done = unreached | (np.abs(zn - z) <= 4e-16 * np.abs(z))   # relative: z ~ 1/k can be tiny
            z = zn
            if np.all(done):
                break
        return np.where(unreached, np.inf, z)

    def _sliding(self, t, at_stop=False):
        s0, f, k, c2, sg2, csg = self.s0, self.f, self.k, self.c2, self.sg2, self.csg
        if f == 0:
            a = self.decel
            # straight line, constant deceleration (or uniform motion without friction)
            tt = np.minimum(t, self.t_stop)
            sp = np.maximum(s0 - a * tt, 0.0) if not at_stop else np.zeros_like(tt)
            par = s0 * tt - 0.5 * a * tt * tt
            return {"par": par, "perp": np.zeros_like(tt), "vpar": sp, "vperp": np.zeros_like(tt), "speed": sp,
                        "phi": np.full_like(tt, self.launch_direction), "path": par}
        if at_stop:
            z = np.full_like(t, np.inf)
        else:
            z = self._z_of_t(t)
        with np.errstate(over="ignore", invalid="ignore"):
            r = np.exp(-z)
            rk1 = np.exp(-(k - 1) * z) if k != 1 else np.ones_like(z)
            if at_stop:
                rk1 = np.zeros_like(z) if (k > 1 or c2 == 0) else rk1
        vpar = s0 * rk1 * (c2 - sg2 * r * r)
        vperp = 2 * s0 * csg * rk1 * r
        speed = s0 * rk1 * (c2 + sg2 * r * r)
        q = s0 * s0 / f

        def terms(*pairs):
            out = np.zeros_like(z)
            for w, p in pairs:
                if w != 0:
                    out = out + w * (np.full_like(z, 1.0 / p) if (at_stop and p > 0) else _J(z, p))
            return out

        par = q * terms((c2 * c2, 2 * k - 2), (-sg2 * sg2, 2 * k + 2))
        perp = 2 * q * terms((c2 * csg, 2 * k - 1), (sg2 * csg, 2 * k + 1))
        path = q * terms((c2 * c2, 2 * k - 2), (2 * c2 * sg2, 2 * k), (sg2 * sg2, 2 * k + 2))
        phi = 2 * np.arctan2(r * math.sqrt(sg2), math.sqrt(c2)) if c2 > 0 else np.full_like(z, math.pi)
        return {"par": par, "perp": perp, "vpar": vpar, "vperp": vperp, "speed": speed, "phi": phi, "path": path}

    def state(self, t) -> dict:
        """The exact state at times ``t`` (array_like, >= 0), vectorised.

        Returns a dict of arrays shaped like ``t``: ``x, y`` (position in the plane, from the
        origin), ``vx, vy`` (velocity), ``speed``, ``phi`` (angle from the load direction e1 to the
        velocity, in [0, pi]; for an unloaded slide the direction
        of the launch in the (x, y) frame; after a stop its value at
        the stop), ``path`` (arc length travelled) and ``t``.
        """
        t = _times(t)
        shape = t.shape
        t = t.ravel()
        out = {key: np.zeros_like(t) for key in ("par", "perp", "vpar", "vperp", "speed", "phi", "path")}
        before = t < self.t_stop
        if np.any(before):
            part = self._sliding(t[before])
            for key, arr in out.items():
                arr[before] = part[key]
        after = ~before
        if np.any(after):
            st = self._stop
            dt = t[after] - self.t_stop
            extra = 0.0 if self.sticks else self.f - self.decel   # slip again from rest along e1
            for key, arr in out.items():
                arr[after] = st[key][0]
            out["vpar"][after] = extra * dt
            out["vperp"][after] = 0.0
            out["speed"][after] = extra * dt
            out["par"][after] += 0.5 * extra * dt * dt
            out["path"][after] += 0.5 * extra * dt * dt
            if extra > 0:
                out["phi"][after] = np.where(dt > 0, 0.0, st["phi"][0])
        e1, e2 = self.e1, self.e2
        res = {"t": t, "x": out["par"] * e1[0] + out["perp"] * e2[0], "y": out["par"] * e1[1] + out["perp"] * e2[1],
                   "vx": out["vpar"] * e1[0] + out["vperp"] * e2[0], "vy": out["vpar"] * e1[1] + out["vperp"] * e2[1],
                   "speed": out["speed"], "phi": out["phi"], "path": out["path"]}
        return {key: res[key].reshape(shape) for key in _KEYS}

    __call__ = state

    def reference(self, t, **kw) -> dict:
        """:func:`reduced_reference` for this slide (same keys as :meth:`state`)."""
        return reduced_reference(t, self.v0, self.accel, self.decel, **kw)


class PlaneSlideExact(ConstantLoadSlide):
    """Oblique launch on a horizontal plane: straight path, deceleration mu g, then rest.

    x = v0 cos(beta) d(t), y = v0 sin(beta) d(t) / v0 ... with distance d(t) = v0 t - mu g t**2 / 2
    up to t_stop = v0 / (mu g), where d = v0**2 / (2 mu g); v = 0 exactly afterwards.

    Examples
    --------
    >>> p = PlaneSlideExact(m=1.0, mu=0.5, g=10.0, v0=2.0, beta=0.3)
    >>> p.t_stop, p.stop_distance
    (0.4, 0.4)
    >>> st = p.state(1.0)
    >>> float(st["speed"]), round(float(st["path"]), 15)
    (0.0, 0.4)
    """

    def __init__(self, m=1.0, mu=0.3, g=9.81, v0=1.0, beta=0.0):
        self.m = _number("m", m, 0.0, strict=True)
        self.mu = _number("mu", mu, 0.0)
        self.g = _number("g", g, 0.0, strict=True)
        v0 = _number("v0", v0, 0.0)
        self.beta = _number("beta", beta)
        super().__init__([0.0, 0.0], self.mu * self.g, [v0 * math.cos(self.beta), v0 * math.sin(self.beta)])
        self.stop_distance = v0 * v0 / (2 * self.decel) if self.decel > 0 else math.inf


class InclineSlideExact(ConstantLoadSlide):
    """Block on an incline of angle theta, launched at ``launch_angle`` from the descent line.

    Coordinates in the plane: x down the line of steepest descent, y horizontal (towards the
    launch side). f = g sin(theta), a = mu g cos(theta), k = mu / tan(theta); mu = None means
    mu = tan(theta) (k = 1 exactly): the block never stops, s (1 + cos(phi)) is conserved and
    the speed tends to ``limit_speed`` = v0 cos(phi0/2)**2 (v0/2 for the default horizontal
    launch), while the lateral offset tends to ``limit_drift``.

    Examples
    --------
    >>> import math
    >>> inc = InclineSlideExact(theta=math.pi / 6, v0=3.0, g=9.81)
    >>> inc.limit_speed, round(inc.limit_drift, 12)    # 2 v0**2 / (3 g sin(theta))
    (1.5, 1.223241590214)
    """

    def __init__(self, theta, v0, g=9.81, mu=None, launch_angle=math.pi / 2):
        self.theta = _number("theta", theta, 0.0, strict=True, hi=math.pi / 2)
        self.g = _number("g", g, 0.0, strict=True)
        v0 = _number("v0", v0, 0.0)
        self.launch_angle = _number("launch_angle", launch_angle, 0.0, hi=math.pi, hi_strict=False)
        f = self.g * math.sin(self.theta)
        if mu is None:
            self.mu, a = math.tan(self.theta), f       # k = 1 exactly, whatever tan rounds to
        else:
            self.mu = _number("mu", mu, 0.0)
            a = self.mu * self.g * math.cos(self.theta)
        pa = self.launch_angle
        # pi/2 and pi must give exactly horizontal and upward launches (cos(pi/2) = 6e-17)
        v = [0.0 if pa == math.pi / 2 else v0 * math.cos(pa), 0.0 if pa == math.pi else v0 * math.sin(pa)]
        super().__init__([f, 0.0], a, v)
        self.limit_drift = math.inf
        if self.k == 1 and self.c2 > 0:
            self.limit_drift = (2 * self.s0 ** 2 / f) * (self.c2 * self.csg + self.sg2 * self.csg / 3)


class LateralForceSlideExact(ConstantLoadSlide):
    """Horizontal plane, constant lateral force F with |F| < mu m g: the path bends towards F and
    the block stops at ``t_stop`` = (s0/f) [c**2/(k-1) + sg**2/(k+1)] (k = mu m g / |F| > 1), then
    sticks. Launches along or against F are the straight-line cases of the same formulas.

    Examples
    --------
    >>> sl = LateralForceSlideExact(m=2.0, mu=0.5, g=10.0, F=[0.0, 5.0], v0=[1.0, 0.0])
    >>> sl.k, round(sl.t_stop, 12)          # k = 2, f = 2.5, c**2 = sg**2 = 1/2
    (2.0, 0.266666666667)
    """

    def __init__(self, m, mu, g, F, v0):
        self.m = _number("m", m, 0.0, strict=True)
        self.mu = _number("mu", mu, 0.0)
        self.g = _number("g", g, 0.0, strict=True)
        self.F = _vector2("F", F)
        v0 = _vector2("v0", v0)
        if not math.hypot(*self.F) < self.mu * self.m * self.g:
            raise ValueError(f"F must satisfy |F| < mu m g = {self.mu * self.m * self.g!r} (the slide "
                             f"ends in sticking), got |F| = {math.hypot(*self.F)!r}")
        super().__init__(self.F / self.m, self.mu * self.g, v0)


def reduced_reference(t, v0, accel, decel, *, rtol=1e-14, method="DOP853") -> dict:
    """High-accuracy numerical solution of U' = accel - decel U/|U|, X' = U (then stick or slip).

    The equations are integrated in the rescaled time tau, dt = |U| d tau::

        dU/dtau = |U| accel - decel U,  dX/dtau = |U| U,  dt/dtau = |U|,  dpath/dtau = |U|**2,

    whose right-hand side is smooth while U != 0; a stop (U -> 0 at finite t) is approached
    exponentially in tau and ends the integration once |U| < 1e-15 of the launch speed, where the
    remaining straight deceleration is added (t_stop = t + |U| / (decel - accel.U/|U|)). After a
    stop the block sticks if |accel| <= decel, otherwise slips from rest along accel. Output times
    are found on the dense output by Newton's method on t(tau) (dt/dtau = |U|).

    Parameters
    ----------
    t : array_like
        Output times >= 0.
    v0, accel : 2-vectors
        Initial velocity and in-plane applied acceleration.
    decel : float
        Friction deceleration mu N / m.
    rtol : float
        Relative tolerance of the integrator (raised to SciPy's floor 100 eps = 2.2e-14 if smaller);
        the absolute tolerances are 1e-3 rtol times the scales of the components (launch speed,
        s0 t, t), so that the decay of U towards a stop is followed far below the launch speed.
    method : str
        A ``scipy.integrate.solve_ivp`` method.

    Returns
    -------
    dict
        The keys of :meth:`ConstantLoadSlide.state` plus ``t_stop`` (inf if no stop was reached).

    Examples
    --------
    >>> ref = reduced_reference([0.5], v0=[1.0, 0.0], accel=[0.0, 0.0], decel=2.0)
    >>> round(ref["t_stop"], 13), round(float(ref["x"][0]), 13)
    (0.5, 0.25)
    """
    t = _times(t)
    shape = t.shape
    t = t.ravel()
    v0 = _vector2("v0", v0)
    b = _vector2("accel", accel)
    a = _number("decel", decel, 0.0)
    rtol = max(_number("rtol", rtol, 0.0, strict=True), 100 * np.finfo(float).eps)   # SciPy's floor
    s0 = float(math.hypot(*v0))
    fb = float(math.hypot(*b))
    t_max = float(t.max(initial=0.0))
    tiny = 1e-15 * max(s0, 1e-300)

    def rhs(_tau, y):
        U = y[:2]
        s = math.hypot(U[0], U[1])
        return [s * b[0] - a * U[0], s * b[1] - a * U[1], s * U[0], s * U[1], s, s * s]

    def ev_time(_tau, y):
        return y[4] - t_max * (1 + 1e-6)   # a little beyond t_max: the last output is interpolated
    ev_time.terminal, ev_time.direction = True, 1

    def ev_stop(_tau, y):
        return math.hypot(y[0], y[1]) - tiny
    ev_stop.terminal, ev_stop.direction = True, -1

    y0 = np.array([v0[0], v0[1], 0.0, 0.0, 0.0, 0.0])
    out = {key: np.zeros_like(t) for key in ("x", "y", "vx", "vy", "speed", "path")}
    t_stop, y_stop = math.inf, None
    done = np.zeros(t.shape, dtype=bool)
    if s0 > 0 and t_max > 0:
        # tau to cover [0, t_max] while sliding (|U| >= s_min), or to decay to the stop
        rate = max(a - fb, 0.0)
        tau_end = 1e3 * (t_max / s0 + (40.0 / rate if rate > 0 else 0.0) + 1.0 / (a + fb + 1e-300))
        T = t_max if math.isfinite(t_max) else 1.0
        scale = np.array([s0, s0, s0 * T, s0 * T, T, s0 * s0 * T])
        sol = solve_ivp(rhs, (0.0, tau_end), y0, method=method, rtol=rtol, atol=1e-3 * rtol * scale,
                        dense_output=True,
                        events=[ev_time, ev_stop])
        if sol.status < 0:
            raise RuntimeError(f"reduced_reference: the integrator failed: {sol.message}")
        yend = sol.y[:, -1]
        if sol.t_events[1].size:
            U = yend[:2]
            s = math.hypot(*U)
            dec = a - float(b @ U) / s
            t_stop = yend[4] + s / dec
            y_stop = yend.copy()
            y_stop[2:4] += U * (s / (2 * dec))
            y_stop[5] += s * s / (2 * dec)
            y_stop[:2] = 0.0
            y_stop[4] = t_stop
        inside = t <= yend[4]
        if np.any(inside):
            ts = sol.sol.ts
            tt = sol.sol(ts)[4]
            i = np.clip(np.searchsorted(tt, t[inside], side="right") - 1, 0, ts.size - 2)
            lo, hi = ts[i], ts[i + 1]
            Ulo = sol.sol(lo)[:2]
            tau = lo + (t[inside] - tt[i]) / np.maximum(np.hypot(Ulo[0], Ulo[1]), 1e-300)
            tau = np.clip(tau, lo, hi)
            for _ in range(8):
                Y = sol.sol(tau)
                step = (Y[4] - t[inside]) / np.maximum(np.hypot(Y[0], Y[1]), 1e-300)
                tau = np.clip(tau - step, lo, hi)
            # The dense output is less accurate than the steps (components decaying towards a stop
            # lose their relative accuracy in it): integrate from the step point before each output
            # to its tau, so that every output is a step of the integrator; correct tau by Newton.
            Y = np.empty((6, tau.size))
            nodes = sol.sol(lo)
            for j in range(tau.size):
                tj, tau_j = t[inside][j], tau[j]
                for _ in range(3):
                    if tau_j == lo[j]:
                        yj = nodes[:, j]
                    else:
                        part = solve_ivp(rhs, (lo[j], tau_j), nodes[:, j], method=method, rtol=rtol,
                                         atol=1e-3 * rtol * scale)
                        yj = part.y[:, -1]
                    miss = yj[4] - tj
                    if abs(miss) <= 4 * np.finfo(float).eps * max(tj, 1e-300):
                        break
                    tau_j = tau_j - miss / max(math.hypot(yj[0], yj[1]), 1e-300)
                Y[:, j] = yj
            for key, row in (("vx", 0), ("vy", 1), ("x", 2), ("y", 3), ("path", 5)):
                out[key][inside] = Y[row]
            out["speed"][inside] = np.hypot(Y[0], Y[1])
            done |= inside
    elif s0 == 0:
        t_stop, y_stop = 0.0, y0.copy()
    if y_stop is not None:
        rest = ~done | (t >= t_stop)
        dt = np.maximum(t[rest] - t_stop, 0.0)
        extra = 0.0 if fb <= a else fb - a
        e1 = b / fb if fb > 0 else np.zeros(2)
        out["x"][rest] = y_stop[2] + 0.5 * extra * dt * dt * e1[0]
        out["y"][rest] = y_stop[3] + 0.5 * extra * dt * dt * e1[1]
        out["vx"][rest] = extra * dt * e1[0]
        out["vy"][rest] = extra * dt * e1[1]
        out["speed"][rest] = extra * dt
        out["path"][rest] = y_stop[5] + 0.5 * extra * dt * dt
    res = {key: out[key].reshape(shape) for key in out}
    res["t"] = t.reshape(shape)
    res["t_stop"] = float(t_stop)
    return res
