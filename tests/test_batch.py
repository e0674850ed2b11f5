"""Batch mode: many scenes stepped together give what one-by-one simulation gives."""
import math

import numpy as np
import pytest

import lcp
from lcp.batch import jean_pratt_constants, simulate_batch


def random_params(n, seed=0):
    rng = np.random.default_rng(seed)
    m, M = rng.uniform(0.3, 3, n), rng.uniform(0.3, 3, n)
    alpha = rng.uniform(0.15, 1.3, n)
    t = np.tan(alpha)
    R = rng.uniform(0.05, 0.95, n) * (m + M * t * t) / (M * t)
    v0 = rng.uniform(-2, 2, n)
    phi = np.where(rng.uniform(size=n) < 0.3, rng.uniform(-15, 15, n), 0.0)
    return m, M, alpha, R, v0, phi


@pytest.mark.parametrize("path", ["compiled", "numpy"])
def test_batch_matches_single_scene_simulation(path):
    m, M, alpha, R, v0, phi = random_params(40)
    h, t_end = 1e-3, 0.4
    res = simulate_batch(jean_pratt_constants(m, M, alpha, R, v0, phi=phi, h=h), t_end, h=h, path=path)
    assert res.path == path and res.success.all()
    for i in range(40):
        sc = lcp.scenes.jean_pratt(m=m[i], M=M[i], alpha=alpha[i], R=R[i], v0=v0[i], phi=phi[i])
        one = lcp.simulate(sc, t_end, h=h)
        np.testing.assert_allclose(res.q[i], one.q[-1], atol=1e-14)
        np.testing.assert_allclose(res.v[i], one.v[-1], atol=1e-14)
        assert res.slide_steps[i] == np.count_nonzero(one.modes >= 2)
    assert np.max(res.max_abs_gap) <= 1e-12


def test_batch_stop_distances_against_exact():
    kappa = np.linspace(0.05, 0.95, 19)
    R = 2.0 * kappa  # m = M = 1, alpha = pi/4: kappa = R / 2
    h = 1e-4
    res = simulate_batch(jean_pratt_constants(1.0, 1.0, math.pi / 4, R, 1.0, h=h), 1.2, h=h)
    for k, Ri in enumerate(R):
        sc = lcp.scenes.jean_pratt(R=Ri)
        assert abs(res.q[k, 0] - sc.x_stop) <= sc.B * h * h / 8 + 1e-12
        assert abs(res.slide_steps[k] * h - sc.tau0) <= h


def test_batch_of_scene_objects_and_shock():
    scenes = [lcp.scenes.jean_pratt(R=R) for R in (0.5, 2.0, 2.5)]
    scenes.append(lcp.scenes.jean_pratt(coordinates="reduced", v0=-1))
    res = simulate_batch(scenes, 0.2, h=1e-3, theta=1.0)
    np.testing.assert_array_equal(res.slide_steps[1:3], 0)  # kappa >= 1: stopped in the first step
    assert np.max(np.abs(res.q[1:3, 0])) <= 1e-15


def test_batch_bad_input():
    with pytest.raises(ValueError, match="alpha"):
        jean_pratt_constants(1.0, 1.0, math.pi / 2, 0.5, h=1e-3)
    with pytest.raises(ValueError, match="h"):
        jean_pratt_constants(1.0, 1.0, 0.5, 0.5, h=0.0)
    with pytest.raises(ValueError, match="another h"):
        simulate_batch(jean_pratt_constants(1.0, 1.0, 0.5, 0.5, h=1e-3), 0.1, h=2e-3)
    with pytest.raises(ValueError, match="single-contact"):
        simulate_batch([lcp.scenes.block_chain(2)], 0.1, h=1e-3)
    with pytest.raises(ValueError, match="path"):
        simulate_batch([lcp.scenes.jean_pratt()], 0.1, h=1e-3, path="gpu")


def test_batch_records_the_path_and_warns_on_fallback(monkeypatch):
    import warnings

    from lcp.sweeps import batch as batch_module

    consts = jean_pratt_constants(1.0, 1.0, 0.6, np.array([0.3, 0.8]), 1.0, h=1e-3)
    ref = simulate_batch(consts, 0.1, h=1e-3, path="numpy")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an explicit NumPy run is no fallback
        assert simulate_batch(consts, 0.1, h=1e-3, path="numpy").path == "numpy"
    monkeypatch.setattr(batch_module, "batch_kernel", lambda n: None)  # as without numba
    with pytest.warns(RuntimeWarning, match="NumPy path"):
        res = simulate_batch(consts, 0.1, h=1e-3)
    assert res.path == "numpy" and "numba" in res.stats["fallback"]
    np.testing.assert_array_equal(res.q, ref.q)
    with pytest.raises(RuntimeError, match="numba"):
        simulate_batch(consts, 0.1, h=1e-3, path="compiled")


def test_a_penetrating_start_is_refused_by_name_not_stepped():
    # the batch has no per-scene message: a start beyond rounding is refused (lcp.simulate projects
    # it within the tolerance, with a note), never stepped from inside the floor
    import lcp

    good = lcp.scenes.jean_pratt()
    bad = lcp.scenes.jean_pratt(R=0.3)
    bad.q0 = bad.q0.copy()
    bad.q0[1] = -1e-4
    with pytest.raises(ValueError, match="scene 'jean_pratt.*start is not consistent"):
        simulate_batch([good, bad], 0.1, 1e-3)
    bad.q0[1] = 0.0  # on the floor: accepted, and the same run as lcp.simulate's
    res = simulate_batch([good, bad], 0.1, 1e-3)
    assert res.q.shape == (2, 2)
    np.testing.assert_allclose(res.q[1], lcp.simulate(bad, 0.1, h=1e-3).q[-1], rtol=0, atol=1e-14)
