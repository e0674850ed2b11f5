"""The set-up of a Moreau-Jean run analyses the mass matrix and the contact rows once.

- a mass matrix whose pattern is its diagonal is checked on its entries: the verdicts and messages
  of the dense test, its condition number (1) kept for the run, and its blocks those the sparse
  check finds;
- the constant assembly is built before the start check, which reads its contact rows: the same
  start, note and errors as the check's own evaluation;
- on a constant system the run evaluates the step data once and the mass matrix not at all;
- a CasADi evaluation at the origin (inputs left out) and one through a kept buffer give the bits of
  an ordinary evaluation.
"""
from __future__ import annotations

import threading

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import lcp
from lcp.model import conditioning, state_checks
from lcp.model.start import consistent_start
from lcp.model.system import Contact, System
from lcp.numerics.block_diagonal import compressed_diagonal_blocks
from lcp.numerics.casadi_eval import evaluate_into, evaluate_kept


def _pucks(masses, mu=0.3, dense=False):
    """Point masses (x, z, y) on the floor y = 0, one disk contact each; the mass matrix diagonal
    (structurally, or written dense with zeros off the diagonal)."""
    masses = np.asarray(masses, dtype=float)
    K = masses.size
    n = 3 * K
    q, v = ca.SX.sym("q", n), ca.SX.sym("v", n)
    diag = np.repeat(masses, 3)
    mass = ca.SX(np.diag(diag)) if dense else ca.diag(ca.SX(diag))
    f = np.zeros(n)
    f[2::3] = -9.81 * np.abs(masses)
    contacts = [Contact(gap=q[3 * i + 2], tangent=ca.vertcat(q[3 * i], q[3 * i + 1]), mu=mu, name=f"P{i}")
                for i in range(K)]
    return System(q, v, mass, ca.SX(f), contacts=contacts)


def _verdict(fn, system, q0):
    try:
        fn(system, q0, 0.0)
    except ValueError as exc:
        return str(exc)
    return None


@settings(max_examples=60, deadline=None)
@given(st.lists(st.one_of(st.floats(-2.0, 2.0), st.sampled_from([0.0, 1e-15, 1e-14, 1.5e-14, -1e-300, 1e-300]),
                          st.floats(1e-20, 1e20)), min_size=1, max_size=14))
def test_the_diagonal_check_gives_the_dense_verdicts_and_messages(masses):
    s = _pucks(masses)
    assert state_checks._structurally_diagonal(s)
    q0 = np.zeros(s.n)
    assert _verdict(state_checks.check_diagonal_mass, s, q0) == _verdict(state_checks.check_dense_mass, s, q0)


def test_a_dense_pattern_with_zeros_off_the_diagonal_is_not_taken_for_diagonal():
    assert not state_checks._structurally_diagonal(_pucks([1.0, 2.0], dense=True))
    assert state_checks._structurally_diagonal(_pucks([1.0, 2.0]))


@pytest.mark.parametrize("masses", [[1.0], [1.0, 1e12, 3.0], list(np.linspace(0.5, 4.0, 12))])
def test_the_kept_condition_number_is_the_block_condition(masses):
    s = _pucks(masses)
    s.check_state(np.zeros(s.n), np.zeros(s.n))
    kept = conditioning.mass_condition(s, np.zeros(s.n))
    s2 = _pucks(masses)  # not checked: the condition found from A's blocks
    assert "_mass_kappa" not in s2.__dict__
    assert kept == conditioning.mass_condition(s2, np.zeros(s2.n)) == 1.0


def test_the_kept_blocks_are_those_of_the_sparse_check():
    masses = np.linspace(0.5, 4.0, 15)  # 45 coordinates: past the dense test's size
    s = _pucks(masses)
    s.check_state(np.zeros(s.n), np.zeros(s.n))
    data, row, colind = state_checks.mass_ccs_values(s, np.zeros(s.n), 0.0)
    (idx, B), = compressed_diagonal_blocks(s.n, colind, row, data, True)
    (idx2, B2), = s.mass_blocks
    assert np.array_equal(idx, idx2) and np.array_equal(B, B2) and B.dtype == B2.dtype and B.shape == B2.shape


@pytest.mark.parametrize("masses, match", [([1.0, 0.0], "singular or not positive definite"),
                                           ([1.0, -2.0], "singular or not positive definite")])
def test_a_bad_diagonal_mass_is_named_by_simulate(masses, match):
    s = _pucks(masses)
    with pytest.raises(ValueError, match=match):
        lcp.simulate(s, 0.01, h=1e-3, q0=np.zeros(s.n), v0=np.zeros(s.n))


def test_a_diagonal_mass_not_finite_at_q0_is_named():
    q, v = ca.SX.sym("q", 3), ca.SX.sym("v", 3)
    s = System(q, v, ca.diag(ca.vertcat(1.0 / q[0], 1.0, 1.0)), ca.SX(np.array([0.0, 0.0, -9.81])),
               contacts=[Contact(gap=q[2], tangent=ca.vertcat(q[0], q[1]), mu=0.3, name="P")])
    assert state_checks._structurally_diagonal(s)
    with pytest.raises(ValueError, match="mass matrix is not finite at q0"):
        lcp.simulate(s, 0.01, h=1e-3, q0=np.zeros(3), v0=np.zeros(3))
    res = lcp.simulate(s, 0.01, h=1e-3, q0=np.array([1.0, 0.0, 0.0]), v0=np.zeros(3))
    assert res.success


@pytest.mark.parametrize("what, q0, v0, match", [
    ("q0 shape", np.zeros(2), np.zeros(3), "q0 must have shape"),
    ("v0 finite", np.zeros(3), np.array([np.nan, 0.0, 0.0]), "v0 must be finite"),
    ("deep start", np.array([0.0, 0.0, -0.5]), np.zeros(3), "penetrates contact 'P0'"),
])
def test_bad_starts_are_still_named(what, q0, v0, match):
    s = _pucks([1.0])
    with pytest.raises(ValueError, match=match):
        lcp.simulate(s, 0.01, h=1e-3, q0=q0, v0=v0)


def test_the_start_check_on_the_assemblys_rows_equals_its_own():
    """A start 1e-7 below the floor is projected: the same start and note either way."""
    q0 = np.array([0.3, -0.2, -1e-7, 0.0, 1.0, 0.25])
    v0 = np.array([1.0, 0.0, -0.5, 0.0, 0.0, 0.0])
    own = consistent_start(_pucks([1.0, 2.0]), q0, v0)
    s = _pucks([1.0, 2.0])
    from lcp.timestepping.assembly import StepAssembly

    asm = StepAssembly(s, 1e-3, 0.5)
    given_rows = consistent_start(s, q0, v0, rows=(asm.H[:s.n_contacts], asm.gap0))
    assert own[2] is not None and own[2] == given_rows[2]
    assert np.array_equal(own[0], given_rows[0]) and np.array_equal(own[1], given_rows[1])
    # and a whole run from it: the bits of the Python loop's own set-up (fast=False)
    a = lcp.simulate(_pucks([1.0, 2.0]), 0.05, h=1e-3, q0=q0, v0=v0)
    b = lcp.simulate(_pucks([1.0, 2.0]), 0.05, h=1e-3, q0=q0, v0=v0, fast=False)
    assert own[2] in a.message and own[2] in b.message
    assert np.array_equal(a.q[0], b.q[0])


class _Counting:
    """A CasADi Function whose evaluations through buffers are counted."""

    def __init__(self, fn):
        self.fn, self.calls = fn, 0

    def buffer(self):
        self.calls += 1
        return self.fn.buffer()

    def __getattr__(self, name):
        return getattr(self.fn, name)


def test_a_constant_run_evaluates_the_step_data_once_and_the_mass_not_at_all():
    s = _pucks([1.0, 2.0])
    s.mass_fn, s.step_data_fn = _Counting(s.mass_fn), _Counting(s.step_data_fn)
    res = lcp.simulate(s, 0.02, h=1e-3, q0=np.zeros(s.n), v0=np.array([1.0, 0, 0, 0, 1.0, 0]))
    assert res.success and res.solver == "auto (compiled)"
    assert (s.mass_fn.calls, s.step_data_fn.calls) == (0, 1)


def test_an_evaluation_at_the_origin_and_through_a_kept_buffer_give_the_same_bits():
    x, t = ca.SX.sym("x", 3), ca.SX.sym("t")
    f = ca.Function("f", [t, x], [ca.vertcat(ca.cos(x[0]) + t, 1 / (1 + x[1] ** 2)), ca.exp(x[2]) * 3.0])
    ref = [np.empty(2), np.empty(1)]
    evaluate_into(f, [np.zeros(1), np.zeros(3)], ref)
    got = [np.empty(2), np.empty(1)]
    evaluate_into(f, [None, None], got)
    assert all(np.array_equal(a, b) for a, b in zip(ref, got))
    rng = np.random.default_rng(0)
    for _ in range(3):
        args = [rng.normal(size=1), rng.normal(size=3)]
        a, b = [np.empty(2), np.empty(1)], [np.empty(2), np.empty(1)]
        evaluate_into(f, args, a)
        evaluate_kept(f, args, b)
        assert all(np.array_equal(x_, y_) for x_, y_ in zip(a, b))


def test_kept_buffers_are_per_thread():
    x = ca.SX.sym("x", 2)
    f = ca.Function("f", [x], [ca.vertcat(x[0] * 2.0, x[1] - 1.0)])
    errors = []

    def work(seed):
        rng = np.random.default_rng(seed)
        for _ in range(2000):
            a = rng.normal(size=2)
            out = np.empty(2)
            evaluate_kept(f, [a], [out])
            if not (out[0] == a[0] * 2.0 and out[1] == a[1] - 1.0):
                errors.append(seed)
                return

    threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert not errors
