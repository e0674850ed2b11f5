"""The cheap set-up of a Moreau-Jean run gives the same bits as the general construction it replaces.

- the constant data of a small system come from a CasADi core cached per structure, not from the
  system's own one-step Function: the same numbers to the last bit, and that Function is never built;
- the compiled single-contact run goes through a C driver of the generated step: the same bits as
  the CasADi chunk (``mapaccum``) it replaces;
- a large sparse mass matrix is checked block by block: the same verdicts as the dense test.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
import scipy.sparse as sp

import lcp
from lcp.timestepping import compiled_step as compiled
from lcp.model import state_checks
from lcp.timestepping import assembly
from lcp.timestepping.assembly import StepAssembly
from lcp.model.system import Contact, System


def _copies(K, blk=((2.0, -1.0), (-1.0, 1.0)), dense=False):
    """K independent two-coordinate bodies on a floor, one contact each (the benchmark's copies)."""
    n = 2 * K
    q, v = ca.SX.sym("q", n), ca.SX.sym("v", n)
    A = sp.kron(sp.eye(K), np.array(blk))
    mass = ca.SX(A.toarray()) if dense else ca.SX(ca.DM(sp.csc_matrix(A)))
    force = ca.SX(np.tile([0.0, -9.81], K))
    contacts = [Contact(gap=q[2 * i + 1], tangent=q[2 * i], mu=0.5, name=f"P{i}") for i in range(K)]
    return System(q, v, mass, force, contacts=contacts)


def _dense_chain():
    """block_chain(3) with damping, its mass matrix dense (structural zeros): springs and dashpots."""
    sc = lcp.scenes.block_chain(3, damping=0.7)
    s = sc.system
    return System(s.q_sym, s.v_sym, ca.SX(np.diag(np.full(6, 1.0))), s.force_expr, contacts=s.contacts)


SYSTEMS = {
    "jean_pratt": lambda: lcp.scenes.jean_pratt().system,
    "jean_pratt_full": lambda: lcp.scenes.jean_pratt(coordinates="full").system,  # a bilateral constraint
    "chain_damped": lambda: lcp.scenes.block_chain(3, damping=0.7).system,
    "chain_dense_mass": _dense_chain,
    "copies": lambda: _copies(4),
    "copies_dense_mass": lambda: _copies(4, dense=True),
}


@pytest.mark.parametrize("name", sorted(SYSTEMS))
@pytest.mark.parametrize("h, theta", [(1e-3, 0.5), (1e-2, 1.0)])
def test_constant_data_equal_those_of_the_one_step_function_to_the_bit(name, h, theta):
    s = SYSTEMS[name]()
    asm = StepAssembly(s, h, theta)
    assert asm.matrices_constant and not asm.sparse
    assert s not in assembly.ONE_STEP_FUNCTIONS  # the per-system Function was not built
    z = np.zeros(s.n)
    _, S, T, SHt, W, gap, H = asm._eval(0.0, z, z)  # the general construction
    for got, ref in ((asm.S, S), (asm.T, T), (asm.SHt, SHt), (asm.W, W), (asm.gap0, gap), (asm.H, H)):
        assert got.shape == ref.shape and got.flags.c_contiguous
        np.testing.assert_array_equal(got, ref)
    K, C = (np.array(x, dtype=float).reshape(s.n, s.n) for x in s.force_jac_fn(0.0, z, z))
    np.testing.assert_array_equal(asm.Kq, -K)
    np.testing.assert_array_equal(asm.Cv, -C)
    np.testing.assert_array_equal(asm.F0, s.force(z, z))
    _, G, phi_t = (np.array(x, dtype=float) for x in s.constraints_fn(0.0, z))
    np.testing.assert_array_equal(asm.G, G.reshape(s.n_bilateral, s.n))
    np.testing.assert_array_equal(asm.phi_t, phi_t.ravel())


def test_the_core_is_shared_by_systems_of_one_structure_and_not_by_others():
    from lcp.timestepping.assembly import _constant_core

    a, b = _copies(3), _copies(3, blk=((3.0, 0.5), (0.5, 2.0)))
    assert _constant_core(a) is _constant_core(b)
    assert _constant_core(a) is not _constant_core(_copies(3, dense=True))  # another sparsity pattern


def test_a_singular_mass_matrix_is_still_reported():
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    s = System(q, v, ca.SX(np.array([[1.0, 1.0], [1.0, 1.0]])), ca.vertcat(0, -9.81),
               contacts=[Contact(gap=q[1], tangent=q[0], mu=0.3)])
    with pytest.raises(ValueError, match="singular"):
        lcp.simulate(s, 0.01, h=1e-3, q0=[0.0, 0.0], v0=[0.0, 0.0])


@pytest.mark.parametrize("affine", [False, True])
def test_the_c_driver_equals_the_casadi_chunk_to_the_bit(affine):
    # the full Jean-Pratt coordinates: a bilateral constraint makes the free velocity state-dependent
    sc = lcp.scenes.jean_pratt(coordinates="full") if affine else lcp.scenes.block_chain(1)
    n = sc.system.n
    asm = StepAssembly(sc.system, 1e-3, 0.5)
    assert compiled.needs_affine(asm) == affine
    if compiled.run_library(n, affine) is None:
        pytest.skip("no C compiler")
    c = compiled.pack(asm, affine)
    run, x, X, info = compiled._chunk_runner(n, c, affine, True, compiled.CHUNK)
    run_ref, x_ref, X_ref, info_ref = compiled._bound_chunk(n, c, affine, True)
    for buf in (x, x_ref):
        buf[:n], buf[n:2 * n] = sc.q0, sc.v0
    run(compiled.CHUNK)
    run_ref()
    np.testing.assert_array_equal(X, X_ref)
    np.testing.assert_array_equal(info, info_ref)


@pytest.mark.parametrize("every", [1, 7])
def test_a_compiled_run_of_any_length_equals_a_longer_one_cut(every):
    sc = lcp.scenes.block_chain(1)
    long = lcp.simulate(sc, 2.5, h=1e-3, save_every=every)  # more steps than one chunk
    short = lcp.simulate(lcp.scenes.block_chain(1), 0.7, h=1e-3, save_every=every)
    assert long.solver == short.solver == "auto (compiled)"
    k = short.q.shape[0]
    for name in ("q", "v"):
        np.testing.assert_array_equal(getattr(short, name), getattr(long, name)[:k])
    for name in ("p_N", "p_T"):
        np.testing.assert_array_equal(getattr(short, name), getattr(long, name)[:k - 1])


def test_constant_kinematics_take_no_projection():
    res = lcp.simulate(lcp.scenes.block_chain(3), 0.05, h=1e-3)
    assert res.stats.projections == 0


def _block_mass_system(blocks):
    """A system of many small mass blocks (more than 200 coordinates: the sparse check)."""
    A = sp.block_diag(blocks, format="csc")
    n = A.shape[0]
    q, v = ca.SX.sym("q", n), ca.SX.sym("v", n)
    return System(q, v, ca.SX(ca.DM(A)), ca.SX.zeros(n), contacts=[Contact(gap=q[1], tangent=q[0], mu=0.3)])


@pytest.mark.parametrize("copies", [20, 150])  # the eigenvalue test (n <= 200), the Cholesky test
def test_the_sparse_mass_check_gives_the_dense_verdicts(copies):
    good = [np.array([[2.0, -1.0], [-1.0, 1.0]])] * copies + [np.diag([1.0, 2.0, 3.0])] * 10
    s = _block_mass_system(good)
    z = np.zeros(s.n)
    s.check_state(z, z)  # positive definite: accepted
    for bad, word in (([np.array([[1.0, 1.0], [1.0, 1.0]])], "singular"),
                      ([np.array([[1.0, 2.0], [2.0, 1.0]])], "not positive definite"),
                      ([np.array([[1.0, 0.5], [0.0, 1.0]])], "symmetric")):
        s = _block_mass_system(good + bad)
        with pytest.raises(ValueError, match=word):
            s.check_state(np.zeros(s.n), np.zeros(s.n))


def _state_dependent_mass():
    """Two coordinates, A(t, q) with entries in q and t (and a structural zero)."""
    q, v, t = ca.SX.sym("q", 2), ca.SX.sym("v", 2), ca.SX.sym("t")
    A = ca.SX.zeros(2, 2)
    A[0, 0] = 2.0 + ca.cos(q[1]) + 0.1 * t
    A[1, 1] = 1.0 + q[0] ** 2
    return System(q, v, A, ca.vertcat(0.0, -9.81), contacts=[Contact(gap=q[1], tangent=q[0], mu=0.3)], t=t)


@pytest.mark.parametrize("name", [*sorted(SYSTEMS), "pendulum", "state_dependent"])
def test_the_mass_read_from_buffers_equals_casadis(name):
    """The checks read the mass matrix from CasADi's buffers (dense, or CSC of its nonzeros): the
    same numbers as the public System.mass, for constant and for state-dependent mass matrices."""
    from lcp.classical import pendulum

    systems = dict(SYSTEMS, pendulum=lambda: pendulum().system, state_dependent=_state_dependent_mass)
    s = systems[name]()
    rng = np.random.default_rng(0)
    for _ in range(3):
        q, t = rng.normal(size=s.n), float(rng.uniform(0, 2))
        A = s.mass(q, t)
        np.testing.assert_array_equal(state_checks.dense_mass(s, q, t), A)
        np.testing.assert_array_equal(s.sparse_mass(q, t).toarray(), A)
