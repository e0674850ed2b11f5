"""Vector fields of the LEM engine and their Taylor expansions about a centre.

:class:`PolynomialField` (the paper's (3.1), coefficients numbers, Fractions or callables of t) and
:class:`AnalyticField` (any ``fun(t, y)`` written with NumPy ufuncs, expanded exactly by jets) both
give an :class:`Expansion`: the Taylor polynomial ``w_j' = sum_mu a_{j,mu} w**mu`` of the field in
the displacement ``w`` from the centre, from which :mod:`lem.moments` builds the moment system.
"""
from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np

from .jets import Jet, monomial_space
from .validation import is_exact_number

__all__ = ["AnalyticField", "Expansion", "PolynomialField", "as_field"]


@dataclass
class Expansion:
    """Taylor polynomial of the field at a centre: w_j' = sum vals * w**exps (per term)."""

    n: int                       # number of moment variables (n, or n + 1 when t is a state)
    comp: np.ndarray             # (T,) component index of each term
    exps: np.ndarray             # (T, n) exponents
    vals: np.ndarray             # (T,) float or object (Fraction) coefficients
    varying: list = field(default_factory=list)  # [(a(t), comp, exps, vals)]: a(t) * polynomial
    time_augmented: bool = False
    # [(exps over (y, t), |coefficients|, R)]: an argument of f whose displacement (majorant
    # sum |a| |w|**e, in y and t) must stay below R, the distance to a singularity of f
    radii: list = field(default_factory=list)

    def truncated(self, D: int) -> Expansion:
        keep = self.exps.sum(axis=1) <= D
        var = []
        for a, c, e, v in self.varying:
            k = e.sum(axis=1) <= D
            var.append((a, c[k], e[k], v[k]))
        return Expansion(self.n, self.comp[keep], self.exps[keep], self.vals[keep], var,
                          self.time_augmented, self.radii)

    def radius_ratio(self, w: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """max over singular arguments of |their displacement| / R at displacements w (n, m) of
        the state after times tau (m,); 0 for polynomial and entire fields."""
        m = tau.size
        if not self.radii:
            return np.zeros(m)
        W = np.vstack([np.abs(w), np.abs(tau)[None, :]])
        out = np.zeros(m)
        with np.errstate(over="ignore", invalid="ignore"):
            for exps, a, R in self.radii:
                mono = np.prod(W[None, :, :] ** exps[:, :, None], axis=1)
                out = np.maximum(out, (a @ mono) / R)
        return np.where(np.isfinite(out), out, np.inf)

    @property
    def has_constant(self) -> bool:
        z = self.exps.sum(axis=1) == 0
        if np.any(z & (self.vals != 0)):
            return True
        return any(np.any(e.sum(axis=1) == 0) for _, _, e, _ in self.varying)


class PolynomialField:
    r"""A polynomial vector field ``y_j' = sum_mu a_{j,mu}(t) y**mu`` (the paper's (3.1)).

    Parameters
    ----------
    components : sequence of mappings
        One mapping per component ``j``: ``{exponent tuple mu: coefficient}``. A coefficient is a
        number (int and :class:`fractions.Fraction` keep exact rational arithmetic available) or a
        callable ``a(t)`` returning a float (time-varying coefficients, only needed to be
        continuous: such fields are integrated with ``solve_ivp``).

    Examples
    --------
    The Coulomb slide q'' = -1 as ``q' = v, v' = -1``:

    >>> f = PolynomialField([{(0, 1): 1}, {(0, 0): -1}])
    >>> f.n, f.degree, f.autonomous, f.exact
    (2, 1, True, True)
    >>> f(0.0, [0.0, 2.0]).tolist()
    [2.0, -1.0]
    """

    def __init__(self, components: Sequence[Mapping]):
        if isinstance(components, Mapping) or not isinstance(components, Sequence) or not components:
            raise ValueError("components must be a non-empty sequence of {exponent tuple: coefficient} "
                             "mappings, one per component")
        n = len(components)
        terms = []
        for j, comp in enumerate(components):
            if not isinstance(comp, Mapping):
                raise ValueError(f"components[{j}] must be a mapping {{exponent tuple: coefficient}}")
            cterms = []
            for mu, a in comp.items():
                mu = tuple(mu) if not isinstance(mu, numbers.Integral) else (mu,)
                if len(mu) != n or any((not isinstance(e, (numbers.Integral, np.integer))) or e < 0
                                       for e in mu):
                    raise ValueError(f"components[{j}]: exponent {mu!r} must be a tuple of {n} "
                                     f"non-negative integers")
                mu = tuple(int(e) for e in mu)
                if callable(a):
                    cterms.append((mu, a))
                    continue
                if isinstance(a, bool) or not isinstance(a, (numbers.Real, np.number)):
                    raise ValueError(f"components[{j}][{mu}]: coefficient must be a real number or "
                                     f"a callable of t, got {a!r}")
                if not is_exact_number(a) and not np.isfinite(float(a)):
                    raise ValueError(f"components[{j}][{mu}]: coefficient must be finite, got {a!r}")
                if a != 0:
                    cterms.append((mu, a if is_exact_number(a) else float(a)))
            terms.append(tuple(cterms))
        self.n = n
        self.terms = tuple(terms)
        self.autonomous = not any(callable(a) for comp in terms for _, a in comp)
        self.exact = all(is_exact_number(a) for comp in terms for _, a in comp)
        self.degree = max((sum(mu) for comp in terms for mu, _ in comp), default=0)

    def __call__(self, t, y) -> np.ndarray:
        """Evaluate f(t, y) with floats (for reference integrators such as ``solve_ivp``)."""
        y = np.asarray(y, dtype=float)
        out = np.zeros((self.n,) + y.shape[1:])
        for j, comp in enumerate(self.terms):
            for mu, a in comp:
                coef = a(t) if callable(a) else float(a)
                m = coef
                for i, e in enumerate(mu):
                    if e:
                        m = m * y[i] ** e
                out[j] = out[j] + m
        return out

    def expansion(self, t: float, centre, degree: int) -> Expansion:
        exact = self.exact and all(is_exact_number(c) for c in centre)
        if exact:
            centre = [Fraction(c) for c in centre]
        else:
            centre = [float(c) for c in centre]
        const: dict = {}
        varying: list = []
        for j, comp in enumerate(self.terms):
            for mu, a in comp:
                shifted = _shift_monomial(mu, centre, degree, exact)
                if callable(a):
                    varying.append((a, {(j, nu): v for nu, v in shifted.items()}))
                else:
                    for nu, v in shifted.items():
                        const[(j, nu)] = const.get((j, nu), 0) + a * v
        comp, exps, vals = _terms_to_arrays(const, self.n, exact)
        var = []
        for a, d in varying:
            c2, e2, v2 = _terms_to_arrays(d, self.n, False)
            var.append((a, c2, e2, v2))
        return Expansion(self.n, comp, exps, vals, var)


def _shift_monomial(mu, centre, degree, exact):
    """(c + w)**mu = sum_nu prod binom(mu_i, nu_i) c_i**(mu_i - nu_i) w**nu, |nu| <= degree."""
    parts = [{}]
    parts[0][()] = Fraction(1) if exact else 1.0
    for i, m in enumerate(mu):
        ci = centre[i]
        new = {}
        for nu, v in parts[0].items():
            for k in range(m + 1):
                if ci == 0 and k < m:
                    continue
                coef = math.comb(m, k) * (ci ** (m - k) if m - k else 1)
                new[nu + (k,)] = v * coef
        parts[0] = new
    return {nu: v for nu, v in parts[0].items() if sum(nu) <= degree and v != 0}


def _terms_to_arrays(d: dict, n: int, exact: bool):
    items = [(j, nu, v) for (j, nu), v in d.items() if v != 0]
    comp = np.array([j for j, _, _ in items], dtype=np.int64)
    exps = np.array([nu for _, nu, _ in items], dtype=np.int64).reshape(len(items), n)
    if exact:
        vals = np.empty(len(items), dtype=object)
        vals[:] = [v for _, _, v in items]
    else:
        vals = np.array([float(v) for _, _, v in items], dtype=float)
    return comp, exps, vals


class AnalyticField:
    """An analytic vector field given as a Python function ``fun(t, y)`` written with NumPy ufuncs.

    The LEM engine calls ``fun`` with :class:`Jet` arguments to get the exact Taylor polynomial of
    ``f`` at each expansion centre, up to the truncation degree (higher terms cannot enter the
    truncated system). ``t`` is expanded too: if the result depends on it, ``t`` becomes an extra
    state variable (``t' = 1``), so analytic time dependence is handled by the same linear system.

    Parameters
    ----------
    fun : callable ``fun(t, y) -> sequence of n values``
        Must work both for floats (``y`` an array) and for jets (``y`` an object array of jets):
        use ``np.tanh(y[0])``, not ``math.tanh(y[0])``, and no branching on the state.
    n : int
        Number of components.

    Examples
    --------
    >>> import numpy as np
    >>> f = AnalyticField(lambda t, y: [y[1], np.tanh(y[0])], 2)
    >>> e = f.expansion(0.0, [0.0, 0.0], 5)
    >>> sorted((int(j), tuple(int(i) for i in mu), round(float(v), 6)) for j, mu, v in zip(e.comp, e.exps, e.vals))
    [(0, (0, 1), 1.0), (1, (1, 0), 1.0), (1, (3, 0), -0.333333), (1, (5, 0), 0.133333)]
    """

    exact = False

    def __init__(self, fun: Callable, n: int):
        if not callable(fun):
            raise ValueError("fun must be callable as fun(t, y)")
        if not isinstance(n, numbers.Integral) or n < 1:
            raise ValueError(f"n must be a positive integer, got {n!r}")
        self.fun = fun
        self.n = int(n)
        self.autonomous = None  # decided from the jets at each expansion

    def __call__(self, t, y) -> np.ndarray:
        return np.asarray(self.fun(t, np.asarray(y, dtype=float)), dtype=float)

    def expansion(self, t: float, centre, degree: int) -> Expansion:
        n = self.n
        space = monomial_space(n + 1, degree)
        Y = np.empty(n, dtype=object)
        for i in range(n):
            Y[i] = Jet.variable(space, i, float(centre[i]))
        T = Jet.variable(space, n, float(t))
        try:
            out = self.fun(T, Y)
        except TypeError as exc:
            raise TypeError(f"fun(t, y) could not be expanded in Taylor series: {exc}") from exc
        out = list(out)
        if len(out) != n:
            raise ValueError(f"fun(t, y) returned {len(out)} components, expected {n}")
        coefs = []
        for j, o in enumerate(out):
            if isinstance(o, Jet):
                c = o.c
            elif isinstance(o, (numbers.Real, np.number)) or (isinstance(o, np.ndarray) and o.ndim == 0):
                c = np.zeros(space.size)
                c[0] = float(o)
            else:
                raise ValueError(f"fun(t, y)[{j}] is neither a number nor a jet: {o!r}")
            if not np.all(np.isfinite(c)):
                raise ValueError(f"the Taylor coefficients of fun(t, y)[{j}] at y = {list(centre)} "
                                 f"are not finite")
            coefs.append(c)
        coefs = np.array(coefs)
        radii, seen = [], set()
        for o in out:
            for a, R in (o.sing if isinstance(o, Jet) else ()):
                nz = np.flatnonzero(a)
                if id(a) in seen or nz.size == 0:
                    continue  # an argument that does not move cannot reach its singularity
                seen.add(id(a))
                radii.append((space.exps[nz], a[nz], R))
        t_dep = bool(np.any(coefs[:, space.exps[:, n] > 0] != 0))
        jj, ii = np.nonzero(coefs)
        if t_dep:
            comp = np.concatenate([jj, [n]])
            exps = np.vstack([space.exps[ii], np.zeros((1, n + 1), dtype=np.int64)])
            vals = np.concatenate([coefs[jj, ii], [1.0]])
            return Expansion(n + 1, comp.astype(np.int64), exps, vals, [], True, radii)
        return Expansion(n, jj.astype(np.int64), space.exps[ii][:, :n].copy(), coefs[jj, ii],
                          radii=radii)


def as_field(fun, n: int | None = None):
    """Turn what the user passed into a field: a field object, a list of dicts, or ``fun(t, y)``."""
    if isinstance(fun, (PolynomialField, AnalyticField)):
        f = fun
    elif isinstance(fun, Sequence) and not isinstance(fun, (str, bytes)) and fun and all(
            isinstance(c, Mapping) for c in fun):
        f = PolynomialField(fun)
    elif callable(fun):
        if n is None:
            raise ValueError("n (the number of components) is needed for a callable fun")
        f = AnalyticField(fun, n)
    else:
        raise ValueError("fun must be a PolynomialField, AnalyticField, a list of "
                         "{exponent tuple: coefficient} dicts, or a callable fun(t, y)")
    if n is not None and f.n != n:
        raise ValueError(f"fun has {f.n} components but y0 has {n}")
    return f
