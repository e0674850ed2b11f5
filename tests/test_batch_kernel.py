"""The batch's numba kernel: the step's SX graph to the bit, any number of scenes and threads."""
import casadi as ca
import numpy as np
import pytest

from lcp.batch import jean_pratt_constants, simulate_batch
from lcp.sweeps.batch_kernel import BLOCK, kernel_source
from lcp.timestepping.compiled_step import step_function
from tests.test_batch import random_params


def test_kernel_equals_the_sx_step_bit_for_bit():
    """CasADi's own evaluation of the lean step, scene by scene and step by step, against the kernel."""
    n_scenes, steps, h = 37, 60, 1e-3
    m, M, alpha, R, v0, phi = random_params(n_scenes, seed=3)
    c, x0 = jean_pratt_constants(m, M, alpha, R, v0, phi=phi, h=h)
    res = simulate_batch((c, x0), steps * h, h=h, path="compiled")
    step = step_function(2, False, True).map(n_scenes)
    Z = ca.DM(np.vstack([x0, np.zeros((2, n_scenes))]))
    for _ in range(steps):
        Z = step(Z, ca.DM(c))
    Z = np.array(Z)
    assert res.steps == steps
    np.testing.assert_array_equal(res.q, Z[:2].T)
    np.testing.assert_array_equal(res.v, Z[2:4].T)
    np.testing.assert_array_equal(res.slide_steps, Z[8])
    np.testing.assert_array_equal(res.max_abs_gap, Z[9])
    assert (res.slide_steps > 0).any() and (res.slide_steps < steps).any()  # slides and sticks both ran


@pytest.mark.parametrize("n_scenes", [1, BLOCK - 1, BLOCK + 1, 3 * BLOCK])
def test_same_bits_for_any_count_and_threads(n_scenes):
    """Padding to whole blocks and the cut between threads change nothing in any scene."""
    m, M, alpha, R, v0, phi = random_params(3 * BLOCK, seed=5)
    consts = jean_pratt_constants(m, M, alpha, R, v0, phi=phi, h=1e-3)
    full = [simulate_batch(consts, 0.05, h=1e-3, threads=t) for t in (1, 2, 3)]
    for r in full[1:]:
        np.testing.assert_array_equal(r.q, full[0].q)
        np.testing.assert_array_equal(r.v, full[0].v)
    part = simulate_batch((consts[0][:, :n_scenes], consts[1][:, :n_scenes]), 0.05, h=1e-3, threads=2)
    np.testing.assert_array_equal(part.q, full[0].q[:n_scenes])
    np.testing.assert_array_equal(part.slide_steps, full[0].slide_steps[:n_scenes])
    assert part.stats["threads"] == min(2, -(-n_scenes // BLOCK))


def test_threads_argument_checked():
    consts = jean_pratt_constants(1.0, 1.0, 0.6, np.array([0.3, 0.8]), 1.0, h=1e-3)
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="threads"):
            simulate_batch(consts, 0.01, h=1e-3, threads=bad)


def test_unknown_sx_operation_is_refused():
    x = ca.SX.sym("x")
    with pytest.raises(NotImplementedError, match="SX operation"):
        kernel_source(ca.Function("f", [x, ca.SX.sym("c")], [ca.sin(x)]))
