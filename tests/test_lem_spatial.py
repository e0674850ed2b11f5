"""The LEM on the spatial sliding branch (lem.spatial_sliding) against the exact slides."""
import math

import numpy as np
import pytest

from lcp.scenes.spatial_exact import InclineSlideExact, LateralForceSlideExact, PlaneSlideExact
from lem.spatial_sliding import solve_spatial_sliding, spatial_sliding_field

#: the LEM target on the incline with mu = tan(theta), horizontal launch, t <= 2 s
LEM_TOL = 1e-9


def _run(ex, T, te, **kw):
    return solve_spatial_sliding(ex.v0, T, accel=ex.accel, decel=ex.decel, t_eval=te, **kw)


def _errors(res, ref):
    pos = max(np.abs(res.x - ref["x"]).max(), np.abs(res.y - ref["y"]).max())
    vel = max(np.abs(res.vx - ref["vx"]).max(), np.abs(res.vy - ref["vy"]).max())
    return pos, vel


@pytest.mark.parametrize("formulation", ["velocity", "direction"])
def test_incline_mu_tan_theta_horizontal_launch(formulation):
    ex = InclineSlideExact(math.radians(30), 2.0)
    te = np.linspace(0.0, 2.0, 21)
    res = _run(ex, 2.0, te, formulation=formulation, degree=8)
    assert res.success and res.t_stop == math.inf
    ref = ex.reference(te)       # the high-accuracy reduced integration
    pos, vel = _errors(res, ref)
    assert pos <= LEM_TOL and vel <= LEM_TOL
    pos, vel = _errors(res, ex.state(te))
    assert pos <= LEM_TOL and vel <= LEM_TOL
    assert np.all(res.error_estimate <= LEM_TOL)
    # the invariant speed (1 + cos phi) = v0 holds along the LEM solution too
    assert np.max(np.abs(res.speed + res.vx - 2.0)) <= LEM_TOL


def test_plane_oblique_launch_up_to_and_beyond_the_stop():
    ex = PlaneSlideExact(1.0, 0.3, 9.81, 2.0, 0.7)
    te = np.union1d(np.linspace(0, 1.0, 11), ex.t_stop * (1 - np.array([1e-2, 1e-4, 1e-6])))
    res = _run(ex, 1.0, te)
    assert res.success
    assert abs(res.t_stop - ex.t_stop) <= 1e-12
    pos, vel = _errors(res, ex.state(te))
    assert pos <= LEM_TOL and vel <= LEM_TOL
    after = te > res.t_stop
    assert np.all(res.speed[after] == 0.0)


@pytest.mark.slow
@pytest.mark.parametrize("v0", [[2.0, -1.0], [-1.0, -3.0]])
def test_lateral_force_up_to_and_beyond_the_stop(v0):
    ex = LateralForceSlideExact(2.0, 0.4, 9.81, [1.0, 3.0], v0)
    te = np.union1d(np.linspace(0, 1.0, 11), ex.t_stop * (1 - np.array([1e-2, 1e-4, 1e-6])))
    res = _run(ex, 1.0, te)
    assert res.success
    assert abs(res.t_stop - ex.t_stop) <= 1e-12
    pos, vel = _errors(res, ex.state(te))
    assert pos <= LEM_TOL and vel <= LEM_TOL


@pytest.mark.parametrize("formulation", ["velocity", "direction"])
def test_field_is_the_sliding_law_on_the_branch(formulation):
    rng = np.random.default_rng(1)
    b, a = np.array([1.3, -0.4]), 2.1
    f = spatial_sliding_field(b, a, formulation)
    for _ in range(5):
        U = rng.normal(size=2)
        s = np.hypot(*U)
        X = rng.normal(size=2)
        acc = b - a * U / s
        if formulation == "velocity":
            d = f(0.0, [U[0], U[1], 1 / s, X[0], X[1]])
            np.testing.assert_allclose(d[:2], acc, rtol=1e-14, atol=1e-14)
            np.testing.assert_allclose(d[2], -(U @ acc) / s ** 3, rtol=1e-13)
            np.testing.assert_allclose(d[3:], U, rtol=1e-15)
        else:
            e = U / s
            d = f(0.0, [e[0], e[1], 1 / s, s, X[0], X[1]])
            sdot = e @ acc
            np.testing.assert_allclose(d[:2], (acc - sdot * e) / s, rtol=1e-13, atol=1e-14)
            np.testing.assert_allclose(d[2], -sdot / s ** 2, rtol=1e-13)
            np.testing.assert_allclose(d[3], sdot, rtol=1e-13, atol=1e-14)
            np.testing.assert_allclose(d[4:], U, rtol=1e-14)


@pytest.mark.parametrize("kw, name", [
    ({"v0": [0.0, 0.0]}, "v0"),
    ({"t_end": 0.0}, "t_end"),
    ({"decel": -1.0}, "decel"),
    ({"accel": [1.0]}, "accel"),
    ({"formulation": "polar"}, "formulation"),
    ({"stop_speed": 1.5}, "stop_speed"),
    ({"window_fraction": 0.0}, "window_fraction"),
    ({"t_eval": [0.5, 0.2]}, "t_eval"),
    ({"degree": 0}, "degree"),
])
def test_bad_input_names_the_parameter(kw, name):
    args = {"v0": [1.0, 0.0], "t_end": 1.0, "decel": 1.0}
    args.update(kw)
    with pytest.raises(ValueError, match=name):
        solve_spatial_sliding(args.pop("v0"), args.pop("t_end"), **args)
