"""The LEM engine (lem.solve and its modules) against exact solutions, exact series and solve_ivp references."""
import math
import warnings
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

from lem import series
from lem.fields import AnalyticField, PolynomialField
from lem.jets import Jet, monomial_space
from lem.moments import moment_system
from lem.paper_equations import (moment_rhs_3_16, smooth_friction_field, tanh_ode_field,
                                 tanh_taylor_coefficients)
from lem.propagation import solve
from lem.result import STATUS_MESSAGES, LEMOptions, LEMWarning
from lem.taylor import double_series, initial_data_coefficients, taylor_coefficients

#: reference integrations (solve_ivp with rtol 1e-13)
REF = dict(method="DOP853", rtol=1e-13, atol=1e-15)


def tanh_f(t, y):
    return [y[1], np.tanh(y[0])]


def reference(f, x_span, y0, t_eval):
    """solve_ivp (rtol 1e-13) stopped exactly at each point: its dense output between steps is
    only good to ~1e-12, the step ends to ~1e-14."""
    out, x, y = [], x_span[0], np.asarray(y0, dtype=float)
    for xe in t_eval:
        if xe != x:
            r = solve_ivp(f, (x, xe), y, **REF)
            assert r.success
            x, y = xe, r.y[:, -1]
        out.append(y)
    return np.array(out).T


#: y'' = tanh y, y(0) = 0, y'(0) = 1 at x = 0.5, 1, 1.5, 2 (mpmath.odefun, 30 digits)
TANH_XS = np.array([0.5, 1.0, 1.5, 2.0])
TANH_Y = np.array([[0.52056612954445011314, 1.1577789407135090997, 1.9957093643787531142,
                    3.0722894863499802515],
                   [1.1223045313890293636, 1.4551766389450711022, 1.9083328370097695333,
                    2.4005353932953388872]])


@pytest.fixture(scope="module")
def tanh_ref():
    Y = reference(tanh_f, (0.0, 2.0), [0.0, 1.0], TANH_XS)
    assert np.max(np.abs(Y - TANH_Y)) <= 1e-13
    return TANH_XS, TANH_Y


# ---------------------------------------------------------------------------------- outcomes
def test_x1_error_falls_geometrically_to_1e10_by_N61(tanh_ref):
    xs, Y = tanh_ref
    Ns = [11, 21, 31, 41, 51, 61]
    errs, ests = [], []
    for N in Ns:
        r = solve(tanh_f, (0.0, 1.0), [0.0, 1.0], degree=N)
        assert r.status >= 0 and not r.diverging, r.message
        errs.append(abs(r.y[0, -1] - Y[0, 1]))
        ests.append(r.error_estimate[0, -1])
        # the estimate is honest: never below the true error
        assert np.all(r.error_estimate[:, -1] >= np.abs(r.y[:, -1] - Y[:, 1]))
    ratios = np.array(errs[1:]) / np.array(errs[:-1])
    assert np.all(ratios < 0.1)            # geometric: more than a decade per 10 degrees
    assert np.ptp(np.log(ratios)) < 1.0    # at a steady rate
    assert errs[-1] <= 1e-10
    assert ests[-1] <= 1e-9


def test_x2_plain_flags_divergence_restarted_within_1e10(tanh_ref):
    xs, Y = tanh_ref
    for N in (21, 41, 61):
        with pytest.warns(LEMWarning, match="diverge"):
            r = solve(tanh_f, (0.0, 2.0), [0.0, 1.0], degree=N, t_eval=xs)
        assert r.status == -1 and not r.success and r.diverging
        assert r.message.startswith(STATUS_MESSAGES[-1])
        # converged where the series converges, flagged where it does not
        assert not r.diverging_points[0] and r.diverging_points[-1]
        assert abs(r.y[0, 0] - Y[0, 0]) <= 1e-10
    for restart in ("auto", 0.25):
        r = solve(tanh_f, (0.0, 2.0), [0.0, 1.0], degree=20, restart=restart, t_eval=xs)
        assert r.status == 0, r.message
        assert r.n_restarts >= 3 and not r.diverging
        err = np.abs(r.y - Y)
        assert err.max() <= 1e-10
        assert np.all(r.error_estimate >= err)


def test_generated_coefficients_equal_exact_series_through_x7():
    # the true series: y = z0 x + z0 x^3/6 - z0(2 z0^2 - 1) x^5/120
    #                           + z0(16 z0^4 - 22 z0^2 + 1) x^7/5040
    for z0 in (Fraction(1), Fraction(2), Fraction(1, 2), Fraction(-3, 7)):
        c = taylor_coefficients(tanh_ode_field(7), [0, z0], 7)[0]
        expected = [0, z0, 0, z0 / 6, 0, -z0 * (2 * z0**2 - 1) / 120, 0,
                    z0 * (16 * z0**4 - 22 * z0**2 + 1) / 5040]
        assert all(isinstance(v, Fraction) for v in c)
        assert list(c) == expected
        assert list(c) == series.tanh_ode_true_coefficients(z0, 7)


def test_analytic_field_coefficients_to_1e14():
    for z0 in (0.3, 1.0, 1.7):
        c = taylor_coefficients(tanh_f, [0.0, z0], 11)[0]
        ex = [float(v) for v in series.tanh_ode_true_coefficients(Fraction(z0), 11)]
        assert np.max(np.abs(c - ex)) <= 1e-14


@given(num=st.integers(-30, 30), den=st.integers(1, 12))
def test_coefficients_exact_for_rational_z0(num, den):
    z0 = Fraction(num, den)
    c = taylor_coefficients(tanh_ode_field(9), [0, z0], 9)[0]
    assert list(c) == series.tanh_ode_true_coefficients(z0, 9)


def test_double_series_is_polynomial_in_z0():
    # with f(0) = 0 the degree-N truncation is the Taylor polynomial in the initial data
    c = double_series(tanh_ode_field(7), 7, 7)
    y = {k: {g[1]: v[0] for (kk, g), v in c.items() if kk == k and g[0] == 0 and v[0] != 0}
         for k in range(8)}
    assert y[1] == {1: 1} and y[3] == {1: Fraction(1, 6)}
    assert y[5] == {1: Fraction(1, 120), 3: Fraction(-2, 120)}
    assert y[7] == {1: Fraction(1, 5040), 3: Fraction(-22, 5040), 5: Fraction(16, 5040)}
    assert y[2] == {} and y[4] == {} and y[6] == {}


def test_printed_series_3_20_is_not_the_true_series():
    for z0 in (0.5, 1.0, 2.0):
        printed = series.series_3_20_printed_coefficients(z0)
        true = taylor_coefficients(tanh_ode_field(5, exact=False), [0.0, z0], 5)[0][1:]
        assert true[0] == printed[0] == z0          # the slope agrees
        assert true[1] == 0.0 and printed[1] == -0.5  # y''(0) = tanh(0) = 0, printed -1
        assert not np.allclose(true, printed)


@settings(max_examples=15)
@given(q0=st.floats(-5, 5), v0=st.floats(-5, 5), x=st.floats(0.01, 10), N=st.integers(1, 40))
def test_sliding_block_qdd_minus_one_exact_at_every_degree(q0, v0, x, N):
    f = PolynomialField([{(0, 1): 1}, {(0, 0): -1}])
    te = np.linspace(0.0, x, 5)
    for restart in (None, x / 3):
        r = solve(f, (0.0, x), [q0, v0], degree=N, t_eval=te, restart=restart)
        exact = np.array([q0 + v0 * te - te**2 / 2, v0 - te])
        assert r.status == 0
        assert np.max(np.abs(r.y - exact)) <= 1e-15 * max(1.0, np.max(np.abs(exact)))
        assert r.moment_dimension == 3  # v_0 = 1, q, v: nothing else is needed


# ---------------------------------------------------------------------------- the moment system
def test_moment_rows_are_the_corrected_3_16():
    N = 9
    S = moment_system(tanh_ode_field(N), N)
    A = S.triplets
    rows: dict = {}
    for r, c, v in zip(*A):
        g_r = tuple(int(e) for e in S.exponents[r])
        g_c = tuple(int(e) for e in S.exponents[c])
        rows.setdefault(g_r, {})[g_c] = rows.setdefault(g_r, {}).get(g_c, 0) + v
    for g in map(tuple, S.exponents.tolist()):
        expected = {k: v for k, v in moment_rhs_3_16(g[0], g[1], N).items() if v != 0}
        assert rows.get(g, {}) == expected, g
    # only odd degrees are reachable from y and z (the paper's V_(2m-1))
    assert set(S.exponents.sum(axis=1).tolist()) == {1, 3, 5, 7, 9}
    assert S.dimension == sum(d + 1 for d in (1, 3, 5, 7, 9))


def test_tanh_coefficients_corrected_3_13():
    c = tanh_taylor_coefficients(9)
    assert c[:10] == [0, 1, 0, Fraction(-1, 3), 0, Fraction(2, 15), 0, Fraction(-17, 315), 0,
                      Fraction(62, 2835)]


def test_pruning_and_constant_moment():
    f = [{(0, 1): 1}, {(1, 0): 1, (3, 0): 1}]  # y'' = y + y^3: f(0) = 0, odd
    assert moment_system(f, 7).dimension == sum(d + 1 for d in (1, 3, 5, 7))
    full = moment_system(f, 7, prune=False)
    assert full.dimension == math.comb(9, 2) - 1 and full.constant_index is None
    # re-centred, f(c) != 0: v_0 = 1 enters and every degree is coupled to the one below
    S = moment_system(f, 7, centre=[0.5, 0.2])
    assert S.constant_index is not None and S.dimension == math.comb(9, 2)
    # only the moments an output needs: y' = y^2 alone never touches z
    S = moment_system([{(2, 0): 1}, {(0, 1): 1, (1, 0): 1}], 6, outputs=[0])
    assert set(map(tuple, S.exponents.tolist())) == {(k, 0) for k in range(1, 7)}


def test_moment_system_matches_paper_triangular_form():
    S = moment_system(tanh_f, 7, n=2)
    A = S.A.toarray()
    deg = S.exponents.sum(axis=1)
    # block upper triangular in degree (3.18): no coupling to lower degrees when f(0) = 0
    assert np.all(A[deg[:, None] > deg[None, :]] == 0)


# ---------------------------------------------------------------------------- other equations
def test_logistic_divergence_flag_follows_the_radius():
    # y' = y(1 - y): y(x) = y0 e^x / (1 - y0 + y0 e^x); as a series in y0 its radius is
    # 1 / (e^x - 1), so the plain engine converges for y0 inside it and must say when it does not.
    f = [{(1,): 1, (2,): -1}]
    x = 1.0
    R = 1.0 / (math.e - 1.0)

    def exact(y0):
        return y0 * math.e / (1 - y0 + y0 * math.e)

    for y0 in (0.2 * R, 0.5 * R, 0.7 * R, 0.9 * R):
        r = solve(f, (0.0, x), [y0], degree=60)
        # converging at the rate y0/R per degree: 0.9**60 is not 1e-10, and it says so
        assert r.status == (0 if y0 <= 0.5 * R else 1) and not r.diverging
        assert abs(r.y[0, -1] - exact(y0)) <= r.error_estimate[0, -1] + 1e-15
    for y0 in (1.3 * R, 2.0 * R, 3.0 * R):
        with pytest.warns(LEMWarning):
            r = solve(f, (0.0, x), [y0], degree=60)
        assert r.status == -1 and r.diverging
        r = solve(f, (0.0, x), [y0], degree=20, restart="auto")
        assert r.status == 0 and abs(r.y[0, -1] - exact(y0)) <= 1e-9


@settings(max_examples=10)
@given(y0=st.floats(-1.0, 1.0), z0=st.floats(-1.5, 1.5), x=st.floats(0.1, 3.0),
       N=st.integers(5, 40), which=st.sampled_from(["tanh", "pendulum", "vdp"]))
def test_never_silently_wrong(y0, z0, x, N, which):
    f = {"tanh": tanh_f, "pendulum": lambda t, y: [y[1], -np.sin(y[0])],
         "vdp": lambda t, y: [y[1], (1 - y[0] ** 2) * y[1] - y[0]]}[which]
    ref = reference(f, (0.0, x), [y0, z0], [x])[:, -1]
    for restart in (None, "auto"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LEMWarning)
            r = solve(f, (0.0, x), [y0, z0], degree=N, rtol=1e-8, atol=1e-10, restart=restart)
        err = np.abs(r.y[:, -1] - ref)
        if r.status == 0:
            assert np.all(err <= 3 * (1e-10 + 1e-8 * np.abs(ref)))
        if r.status in (0, 1):
            assert np.all(err <= 3 * r.error_estimate[:, -1] + 1e-12)
        if restart == "auto":
            # local errors are controlled; their sum, amplified by the flow, may exceed the
            # tolerance (status 1), but the result is never rejected as diverging
            assert r.status in (0, 1) and not r.diverging


@pytest.mark.parametrize("eps", [1e-2, 1e-4, 1e-8])
def test_saturated_tanh_friction_is_not_crossed_silently(eps):
    # Jean-Pratt slide with friction R N tanh(v/eps): at v = 1, tanh(v/eps) is 1 to the last bit and
    # its derivatives underflow, so every truncation agrees and the differences say "exact". The
    # jets know tanh's poles at v = +-i pi eps/2: restarts must approach v = 0 through them.
    def f(t, y):
        th = np.tanh(y[1] / eps)
        return [y[1], -9.81 * th / (2.0 - 0.5 * th)]

    te = np.linspace(0.0, 0.3, 7)
    Y = reference(f, (0.0, 0.3), [0.0, 1.0], te) if eps >= 1e-4 else None
    tau0, B = 1.0 / 6.54, 6.54
    exact_x = np.where(te < tau0, te - B * te**2 / 2, 1.0 / (2 * B))
    r = solve(f, (0.0, 0.3), [0.0, 1.0], degree=12, restart="auto", t_eval=te)
    assert r.status == 0 and np.all(r.radius_ratio <= 0.5)
    if Y is not None:
        assert np.max(np.abs(r.y - Y)) <= 1e-10
    assert np.max(np.abs(r.y[0] - exact_x)) <= 3 * eps  # Coulomb's stop, up to the smoothing
    # a fixed restart longer than the stop distance allows is reported, not trusted
    with pytest.warns(LEMWarning):
        bad = solve(f, (0.0, 0.3), [0.0, 1.0], degree=12, restart=0.1, t_eval=te)
    assert bad.status == -1 and bad.diverging


def test_pendulum_long_horizon_with_restarts():
    f = lambda t, y: [y[1], -np.sin(y[0])]  # noqa: E731
    te = np.linspace(0.0, 30.0, 7)
    Y = reference(f, (0.0, 30.0), [2.0, 0.0], te)
    r = solve(f, (0.0, 30.0), [2.0, 0.0], degree=16, restart="auto", t_eval=te, rtol=1e-12)
    assert r.status == 0 and r.n_restarts > 20
    err = np.abs(r.y - Y)
    assert err.max() <= 1e-12
    # local estimates carried through the exact segment sensitivities: honest (to the reference's
    # own 1e-14), and not orders of magnitude too big
    assert np.all(err <= r.error_estimate + 5e-14) and np.all(r.error_estimate <= 1e-11)


def test_time_varying_coefficients():
    # y' = cos(t) y: y = exp(sin t). Callable coefficient -> solve_ivp path.
    r = solve([{(1,): np.cos}], (0.0, 3.0), [1.0], degree=6, restart=0.5)
    assert r.stats.time_varying and r.status == 0
    assert abs(r.y[0, -1] - math.exp(math.sin(3.0))) <= 1e-10
    # the same through an analytic field: t becomes a state variable
    r = solve(lambda t, y: [np.cos(t) * y[0]], (0.0, 3.0), [1.0], degree=12, restart="auto")
    assert r.stats.time_augmented and r.status == 0
    assert abs(r.y[0, -1] - math.exp(math.sin(3.0))) <= 1e-10


def test_forced_duffing_against_reference():
    f = lambda t, y: [y[1], -y[0] - y[0] ** 3 + 0.3 * np.cos(1.2 * t)]  # noqa: E731
    te = np.linspace(0.0, 10.0, 6)
    Y = reference(f, (0.0, 10.0), [0.5, 0.0], te)
    r = solve(f, (0.0, 10.0), [0.5, 0.0], degree=14, restart="auto", t_eval=te)
    assert r.status == 0 and np.max(np.abs(r.y - Y)) <= 1e-9


def test_backward_integration_and_outputs():
    r = solve(tanh_f, (1.0, 0.0), [1.1577789, 1.4551766], degree=16, restart="auto")
    Y = reference(tanh_f, (1.0, 0.0), [1.1577789, 1.4551766], [0.0])
    assert r.status == 0 and np.max(np.abs(r.y[:, -1] - Y[:, -1])) <= 1e-10
    r = solve(tanh_f, (0.0, 1.0), [0.0, 1.0], degree=31, outputs=[1])
    assert r.y.shape == (1, 2) and r.sensitivity.shape == (1, 2, 2)


def test_sensitivity_matches_finite_differences():
    h = 1e-6
    for restart in (None, 0.3):
        r = solve(tanh_f, (0.0, 1.0), [0.1, 0.8], degree=30, restart=restart)
        fd = np.column_stack([
            (solve(tanh_f, (0.0, 1.0), np.array([0.1, 0.8]) + h * e, degree=30, restart=restart).y[:, -1]
             - solve(tanh_f, (0.0, 1.0), np.array([0.1, 0.8]) - h * e, degree=30, restart=restart).y[:, -1])
            / (2 * h) for e in np.eye(2)])
        assert np.max(np.abs(r.sensitivity[:, :, -1] - fd)) <= 1e-7


def test_initial_data_coefficients():
    C = initial_data_coefficients([{(1,): 1.0}], 2.0, 3)  # y' = y: y(x) = e^x y0
    assert set(C) == {(1,)} and abs(C[(1,)][0] - math.exp(2.0)) <= 1e-13
    # for tanh these are the x = 1 values of the double series' polynomials in (y0, z0)
    C = initial_data_coefficients(tanh_f, 0.5, 5, n=2)
    D = double_series(tanh_ode_field(5, exact=False), 40, 5)
    for g, v in C.items():
        s = sum(D[(k, gg)] * 0.5**k for (k, gg) in D if gg == g)
        assert np.max(np.abs(v - s)) <= 1e-13


def test_smooth_friction_series_and_coulomb_limit():
    B, v0 = 6.54, 1.0
    for eps in (1.0, 0.3, 0.1):
        c = taylor_coefficients(smooth_friction_field(B, eps), [0.0, v0], 5)[0]
        th = math.tanh(v0 / eps)
        assert abs(c[1] - v0) <= 1e-15
        assert abs(c[2] + B * th / 2) <= 1e-14
        # q''' = -B sech^2(v/eps) q'' / eps
        assert abs(c[3] - (-B / eps) * (1 - th**2) * (-B * th) / 6) <= 1e-12
    # eps -> 0: the series tends to the exact Coulomb slide v0 t - B t^2 / 2
    c = taylor_coefficients(smooth_friction_field(B, 0.01), [0.0, v0], 5)[0]
    assert np.allclose(c, [0.0, v0, -B / 2, 0.0, 0.0, 0.0], atol=1e-30)


# ---------------------------------------------------------------------------------- jets
JET_CASES = [("tanh", 0.7), ("tanh", -3.0), ("sinh", 1.3), ("cosh", -0.4), ("exp", 0.2),
             ("log", 2.5), ("sqrt", 0.6), ("sin", 1.1), ("cos", -2.0), ("tan", 0.4),
             ("arctan", 1.5)]


@pytest.mark.parametrize("name,u0", JET_CASES)
def test_jet_coefficients_against_cauchy_integrals(name, u0):
    # independent of any series recursion: c_k = mean over the circle |u - u0| = r of
    # f(u) (u - u0)**-k (trapezoidal rule, exact up to aliasing ~ (r/R)**M)
    D, M, r = 12, 256, 0.25
    theta = 2 * np.pi * np.arange(M) / M
    vals = getattr(np, name)(u0 + r * np.exp(1j * theta))
    ref = [float((np.mean(vals * np.exp(-1j * k * theta)) / r**k).real) for k in range(D + 1)]
    coeffs = getattr(np, name)(Jet.variable(monomial_space(2, D), 0, u0)).coefficients()
    for k in range(D + 1):
        scale = max(abs(v) * r**j for j, v in enumerate(ref)) / r**k
        assert abs(coeffs.get((k, 0), 0.0) - ref[k]) <= 1e-13 * scale


@pytest.mark.parametrize("name,u0", JET_CASES)
def test_jet_univariate_coefficients(name, u0):
    mpmath = pytest.importorskip("mpmath")
    D = 25
    space = monomial_space(2, D)
    u = Jet.variable(space, 0, u0)
    g = getattr(np, name)(u)
    coeffs = g.coefficients()
    mp_f = {"tanh": mpmath.tanh, "sinh": mpmath.sinh, "cosh": mpmath.cosh, "exp": mpmath.exp,
            "log": mpmath.log, "sqrt": mpmath.sqrt, "sin": mpmath.sin, "cos": mpmath.cos,
            "tan": mpmath.tan, "arctan": mpmath.atan}[name]
    ref = mpmath.taylor(mp_f, u0, D)
    for k in range(D + 1):
        got = coeffs.get((k, 0), 0.0)
        assert abs(got - float(ref[k])) <= 1e-14 * max(1.0, abs(float(ref[k])), abs(float(ref[0])))


def test_jet_multivariate_identities():
    space = monomial_space(2, 12)
    a = Jet.variable(space, 0, 0.3)
    b = Jet.variable(space, 1, -0.2)
    lhs = np.exp(a + 2 * b)
    rhs = np.exp(a) * np.exp(b) ** 2
    assert np.max(np.abs(lhs.c - rhs.c)) <= 1e-14
    q = (a * b + 1.5) / (a - b + 2.0)
    back = q * (a - b + 2.0)
    assert np.max(np.abs(back.c - (a * b + 1.5).c)) <= 1e-14
    with pytest.raises(TypeError):
        np.sign(a)
    with pytest.raises(TypeError):
        bool(a > 0)
    with pytest.raises(ValueError):
        np.log(Jet.variable(space, 0, -1.0))


# --------------------------------------------------------------------------------- validation
@pytest.mark.parametrize("kwargs,name", [
    (dict(degree=0), "degree"), (dict(degree=2.5), "degree"), (dict(degree=True), "degree"),
    (dict(check_step=0), "check_step"), (dict(rtol=-1.0), "rtol"), (dict(atol=math.nan), "atol"),
    (dict(restart=-0.1), "restart"), (dict(restart="sometimes"), "restart"),
    (dict(restart=math.inf), "restart"), (dict(centre="middle"), "centre"),
    (dict(restart="auto", check=False), "restart"), (dict(ivp_method="Euler"), "ivp_method"),
    (dict(degreee=3), "unknown option"),
])
def test_bad_options_raise_naming_the_parameter(kwargs, name):
    with pytest.raises(ValueError, match=name):
        solve(tanh_f, (0.0, 1.0), [0.0, 1.0], **kwargs)


def test_bad_inputs_raise():
    with pytest.raises(ValueError, match="y0"):
        solve(tanh_f, (0.0, 1.0), [0.0, math.nan])
    with pytest.raises(ValueError, match="x_span"):
        solve(tanh_f, (0.0, 0.0), [0.0, 1.0])
    with pytest.raises(ValueError, match="x_span"):
        solve(tanh_f, (0.0, math.inf), [0.0, 1.0])
    with pytest.raises(ValueError, match="t_eval"):
        solve(tanh_f, (0.0, 1.0), [0.0, 1.0], t_eval=[0.5, 2.0])
    with pytest.raises(ValueError, match="outputs"):
        solve(tanh_f, (0.0, 1.0), [0.0, 1.0], outputs=[2])
    with pytest.raises(ValueError, match="exponent"):
        PolynomialField([{(1,): 1.0}, {(0, 1): 1.0}])
    with pytest.raises(ValueError, match="finite"):
        PolynomialField([{(1,): math.inf}])
    with pytest.raises(ValueError, match="components"):
        solve(tanh_f, (0.0, 1.0), [0.0, 1.0, 2.0])
    with pytest.raises(ValueError, match="max_dimension"):
        solve(tanh_f, (0.0, 1.0), [0.0, 1.0], degree=40, max_dimension=100)
    with pytest.raises(TypeError, match="Taylor"):
        solve(lambda t, y: [y[1], math.tanh(y[0])], (0.0, 1.0), [0.0, 1.0])
    with pytest.raises(ValueError, match="known options"):
        LEMOptions.from_kwargs(order=3)


def test_status_table_and_result_fields():
    r = solve(tanh_f, (0.0, 0.5), [0.0, 1.0], degree=20)
    assert r.success and r.status == 0 and r.message == STATUS_MESSAGES[0]
    assert r.degree == 20 and r.check_degrees == (16, 18, 20, 22)
    assert r.t.tolist() == [0.0, 0.5] and r.y.shape == (2, 2) and r.error_estimate.shape == (2, 2)
    assert r.moment_dimension == sum(d + 1 for d in range(1, 21, 2))
    r = solve(tanh_f, (0.0, 0.5), [0.0, 1.0], degree=20, check=False)
    assert r.status == 2 and r.success and np.isnan(r.error_estimate[0, -1])
    assert all(k in STATUS_MESSAGES for k in (0, 1, 2, -1, -2, -3, -4, -5))
    assert isinstance(AnalyticField(tanh_f, 2).expansion(0.0, [0.0, 0.0], 3).vals, np.ndarray)


# ------------------------------------------------------------------ modules, caches, propagator
def test_truncation_module_is_a_deprecated_alias():
    import importlib

    import lem.fields
    import lem.propagation
    old = importlib.import_module("lem.truncation")
    with pytest.warns(DeprecationWarning, match=r"import solve from lem\.propagation"):
        assert old.solve is lem.propagation.solve
    with pytest.warns(DeprecationWarning, match=r"lem\.fields"):
        from lem.truncation import AnalyticField as Old  # noqa: N813
    assert Old is lem.fields.AnalyticField
    with pytest.warns(DeprecationWarning, match="monomial_space"):
        assert old._space is monomial_space
    with pytest.raises(AttributeError):
        old.no_such_name  # noqa: B018


def test_cached_structure_gives_bit_identical_results():
    # the structure (kept moments, term placement) is reused across restarts and solves of the
    # same field; a solve on a warm cache must equal one that builds every structure afresh
    from lem.moments import clear_structure_cache
    from lem.troesch import troesch_field

    f = troesch_field(5.0)
    kw = dict(degree=12, restart="auto", rtol=1e-10)
    clear_structure_cache()
    fresh = solve(f, (0.0, 1.0), [0.0, 0.046], **kw)
    warm = solve(f, (0.0, 1.0), [0.0, 0.046], **kw)
    for a, b in ((fresh.y, warm.y), (fresh.error_estimate, warm.error_estimate),
                 (fresh.sensitivity, warm.sensitivity), (fresh.restart_points, warm.restart_points)):
        assert np.array_equal(a, b)
    assert fresh.status == warm.status == 0


@pytest.mark.parametrize("centre", [[0.0, 0.0], [0.3, -0.2], [0.0, 0.7]])
def test_cached_matrix_equals_direct_assembly(centre):
    # the cached placement refills values; compare with triplets summed by scipy's COO -> CSR
    import scipy.sparse as sp

    from lem.fields import as_field
    from lem.moments import build_system, moment_structure

    fld = as_field(tanh_f, 2)
    exp = fld.expansion(0.0, centre, 9)
    S = build_system(exp, 9, (0, 1), True, 10**6)
    st = moment_structure(exp, 9, (0, 1), True, 10**6)
    pl = st.placements[0]
    direct = sp.csr_matrix((pl.mult * exp.vals[pl.terms], (pl.rows, pl.cidx)),
                           shape=(st.dimension, st.dimension))
    assert abs(S.A - direct).max() <= 1e-15 * abs(direct).max()
    # every placed term lands on the moment gamma - e_j + mu of its row
    comp = exp.comp[pl.terms]
    target = st.exponents[pl.rows] + exp.exps[pl.terms]
    target[np.arange(target.shape[0]), comp] -= 1
    assert np.array_equal(st.exponents[pl.cidx], target)


@pytest.mark.parametrize("compiled", [True, False])
def test_expmv_against_dense_exponential(compiled):
    import scipy.sparse as sp
    from scipy.linalg import expm

    from lem.expmv import expmv, onenorm

    rng = np.random.default_rng(3)
    for d, scale in ((5, 0.1), (30, 3.0), (60, 20.0)):
        A = sp.random(d, d, density=0.2, random_state=rng, format="csr") * scale
        B = rng.standard_normal((d, 3))
        assert onenorm(A) == pytest.approx(np.abs(A.toarray()).sum(axis=0).max(), rel=1e-15)
        for t in (0.0, 0.3, -1.0):
            ref = expm(t * A.toarray()) @ B
            got = expmv(A, B, t, compiled=compiled)
            assert np.max(np.abs(got - ref)) <= 1e-12 * max(1.0, np.abs(ref).max())


def test_nonnegative_expm():
    from scipy.linalg import expm

    from lem.expmv import nonnegative_expm

    rng = np.random.default_rng(0)
    for scale in (0.0, 1e-3, 1.0, 50.0, 350.0):
        M = rng.random((3, 3)) * scale
        # squaring k times costs ~2**k eps (k ~ log2 of the norm): 1e-12 at norm 1e3
        assert np.allclose(nonnegative_expm(M), expm(M), rtol=1e-11, atol=0)
    with pytest.raises(ValueError, match="non-negative"):
        nonnegative_expm(-np.eye(2))


def test_step_hint_is_checked_by_the_same_error_control():
    f = tanh_f
    base = solve(f, (0.0, 2.0), [0.0, 1.0], degree=16, restart="auto")
    hint = tuple(np.diff(base.restart_points))
    again = solve(f, (0.0, 2.0), [0.0, 1.0], degree=16, restart="auto", step_hint=hint)
    assert again.stats.n_rejected == 0
    assert np.array_equal(again.restart_points, base.restart_points)
    assert np.array_equal(again.y, base.y)
    # a hint far too long is rejected and shortened by the controller: same tolerance met
    bad = solve(f, (0.0, 2.0), [0.0, 1.0], degree=16, restart="auto", step_hint=(2.0,) * 50)
    assert bad.status == 0 and bad.stats.n_rejected > 0
    ref = reference(f, (0.0, 2.0), [0.0, 1.0], [2.0])
    assert abs(bad.y[0, -1] - ref[0, -1]) <= 1e-9
    for wrong in ((0.1, -0.2), ("a",), (np.inf,)):
        with pytest.raises(ValueError, match="step_hint"):
            solve(f, (0.0, 1.0), [0.0, 1.0], restart="auto", step_hint=wrong)


def test_taylor_parameters_use_power_norm_bounds():
    from lem.expmv import THETA, taylor_parameters

    assert taylor_parameters(0.0) == (0, 1)
    m, s = taylor_parameters(100.0)
    assert 100.0 / s <= THETA[m]
    # a nilpotent-like matrix: ||A**p||**(1/p) far below ||A||, fewer products
    m2, s2 = taylor_parameters(100.0, [100.0, 30.0, 20.0, 15.0, 12.0])
    assert m2 * s2 < m * s
    # admissible for some p: m >= p (p - 1) - 1 and alpha_p = max(d_p, d_(p+1)) within theta_m
    assert any(m2 >= p * (p - 1) - 1 and alpha / s2 <= THETA[m2]
               for p, alpha in [(1, 100.0), (2, 30.0), (3, 20.0), (4, 15.0)])
