"""Steps with several active spatial contacts solved inside the compiled general loop's kernel
(lcp.timestepping.multi_kernels): the Python loop's results to the solver's tolerance (the NSGS
iterates are summed in another order), the kernel counting them, and each kernel solve passing the
Python route's acceptance test (Coulomb residual, natural-map error)."""
import numpy as np
import pytest

import lcp
from lcp.contact.law import natural_map_error
from lcp.contact.spatial_problem import ConeContactProblem
from lcp.numerics.jit import HAVE_NUMBA
from lcp.scenes.rigid_bodies import tumbling_box
from lcp.timestepping import codegen

pytestmark = pytest.mark.skipif(not HAVE_NUMBA or codegen.c_compiler() is None,
                                reason="needs numba and a C compiler")


def _close(a, b, tol):
    assert a.status == b.status and a.message == b.message
    assert a.q.shape == b.q.shape
    assert np.max(np.abs(a.q - b.q)) <= tol, float(np.max(np.abs(a.q - b.q)))
    assert np.max(np.abs(a.v - b.v)) <= tol, float(np.max(np.abs(a.v - b.v)))
    assert a.stats.solver_calls == b.stats.solver_calls and a.stats.free_steps == b.stats.free_steps
    assert b.stats.kernel_multi_steps == 0


def test_tumbling_box_comes_to_rest_as_the_python_loop():
    sc = tumbling_box()
    b = lcp.simulate(sc, 3.0, h=1e-3, fast=False)
    a = lcp.simulate(sc, 3.0, h=1e-3)
    _close(a, b, 1e-9)
    multi = int(np.sum(np.sum(b.modes >= 0, axis=1) >= 2))  # saved steps with two or more active contacts
    assert multi > 2000 and a.stats.kernel_multi_steps >= multi - 5  # (a few may fall back to Python)
    assert a.stats.mode_counts == b.stats.mode_counts
    for r in (a, b):  # at rest on a face: centre at half the side
        assert abs(r.q[-1, 2] - 0.5) <= 1e-9 and np.max(np.abs(r.v[-1])) <= 1e-9
    assert a.stats.max_residual <= 1e-10 * max(1.0, float(np.max(np.abs(a.p_N))))


def test_tumbling_box_with_restitution_as_the_python_loop():
    # bounces, then slides and rocks on several corners (both loops' solvers fail at t = 1.996)
    sc = tumbling_box(e=0.5)
    b = lcp.simulate(sc, 1.99, h=1e-3, fast=False)
    a = lcp.simulate(sc, 1.99, h=1e-3)
    _close(a, b, 1e-9)
    assert a.stats.kernel_multi_steps > 100
    assert [i.contact for i in a.impacts] == [i.contact for i in b.impacts]
    np.testing.assert_allclose([i.t for i in a.impacts], [i.t for i in b.impacts], rtol=0, atol=1e-9)


def _random_step(rng, m, n=6):
    """Step data of m spatial contacts on a body with n velocities, column-major as the kernel's
    buffers: (r, o_W, o_H, o_SHt, v, vfree, dvf)."""
    r = 3 * m
    H = rng.standard_normal((r, n))
    Minv = np.diag(rng.uniform(0.5, 2.0, n))
    SHt = Minv @ H.T
    W = H @ SHt
    v = rng.standard_normal(n)
    dvf = rng.standard_normal(n) * 0.1 - 0.5 * (H[:m].T @ np.ones(m)) / m
    return r, W.ravel(order="F"), H.ravel(order="F"), SHt.ravel(order="F"), v, v + dvf, dvf, W, H, SHt


@pytest.mark.parametrize("seed", range(12))
def test_kernel_solve_passes_the_acceptance_test(seed):
    from lcp.timestepping.multi_kernels import cone_multi_step

    rng = np.random.default_rng(seed)
    m = 2 + seed % 3
    r, oW, oH, oS, v, vfree, dvf, W, H, SHt = _random_step(rng, m, n=3 * m + 2)
    n = v.size
    act = np.arange(m)
    mu = rng.uniform(0.0, 1.0, m)
    e = np.zeros(m)
    dims = np.full(m, 2, dtype=np.int64)
    toff = np.arange(0, 2 * m + 1, 2, dtype=np.int64)
    istate, fstate = np.zeros(19, dtype=np.int64), np.zeros(3)
    dv, P, MD = np.empty(n), np.empty(3 * m), np.empty(m, dtype=np.int64)
    ok = cone_multi_step(act, m, m, n, r, oW, oH, oS, np.zeros(0), False, v, vfree, dvf, np.zeros(m), mu, e, dims,
                         toff, 1e-10, 1000, istate, fstate, dv, P, MD)
    if not ok:  # handed to Python: nothing counted
        assert istate[18] == 0
        return
    assert istate[18] == 1 and istate[2] == 1
    pb = ConeContactProblem(W, H @ vfree, mu, dims)
    # the Python route's acceptance test on the impulses before the all-stick correction: the
    # correction only cancels the velocities' rounding; both pass here
    assert pb.residual(P) <= 1e-10 * max(pb.scale, float(np.max(np.abs(P))))
    assert natural_map_error(W, H @ vfree, mu, P, dims=dims) <= 1e-10
    np.testing.assert_allclose(dv, dvf + SHt @ P, rtol=0, atol=1e-12 * max(1.0, float(np.max(np.abs(dv)))))
    ref = lcp.contact.spatial_solvers.make_cone_solver("auto").solve(pb)
    if ref.success:  # W p (the velocities) is unique for the symmetric positive W of a body
        u_ref, u = pb.velocity(ref.p), pb.velocity(P)
        assert np.max(np.abs(u - u_ref)) <= 1e-8 * max(1.0, float(np.max(np.abs(pb.q))))


@pytest.mark.parametrize("seed", range(8))
def test_natural_map_error_is_the_laws(seed):
    from lcp.timestepping.multi_kernels import cone_natural_map_error

    rng = np.random.default_rng(100 + seed)
    k = 3
    dims = rng.integers(1, 3, k).astype(np.int64)
    nn = k + int(dims.sum())
    toff = np.concatenate([[0], np.cumsum(dims)[:-1]]).astype(np.int64)
    A = rng.standard_normal((nn, nn))
    W, q, p, mu = A @ A.T, rng.standard_normal(nn), rng.standard_normal(nn), rng.uniform(0, 1, k)
    got = cone_natural_map_error(W, q, mu, dims, toff, p)
    assert got == pytest.approx(natural_map_error(W, q, mu, p, dims=dims), rel=1e-12)
