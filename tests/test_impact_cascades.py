"""Impact cascades and frictionless contacts: a column of beads dropped onto a floor.

Each bead's landing sends impulses up and down the column: at one instant the impacts go round
after round (as Moreau-Jean's steps do in the limit h -> 0) until no contact approaches. Before,
the event method gave up after 8 rounds ("Painleve inconsistency" at t = 0.378, which cannot
happen without friction), and every solver rejected exact frictionless solutions because the cone
projection of the natural-map error let a negative normal through when mu = 0.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import lcp
from lcp import Contact, ContactProblem, System, make_solver
from lcp.contact.law import natural_map_error


def bead_column(K: int, e: float, r: float = 0.1, spacing: float = 0.05, drop: float = 0.5):
    """K beads (point masses, q = (x_i, y_i)) above a floor, frictionless, restitution e."""
    q, v = ca.SX.sym("q", 2 * K), ca.SX.sym("v", 2 * K)
    x, y = q[0::2], q[1::2]
    force = ca.vertcat(*[ca.vertcat(0, -9.81) for _ in range(K)])
    contacts = [Contact(gap=y[0] - r, tangent=x[0], mu=0.0, e=e, name="floor")]
    contacts += [Contact(gap=y[i] - y[i - 1] - 2 * r, tangent=x[i] - x[i - 1], mu=0.0, e=e, name=f"bead{i}")
                 for i in range(1, K)]
    system = System(q, v, ca.SX.eye(2 * K), force, contacts=contacts)
    q0 = np.zeros(2 * K)
    q0[1::2] = r + drop + np.arange(K) * (2 * r + spacing)
    return system, q0, np.zeros(2 * K)


def test_frictionless_natural_map_error_of_a_separating_contact_is_zero():
    # contact 2 separates (u_N = 0.039 > 0, no impulse): the exact solution has zero error
    W, q = 2 * np.eye(4), np.array([-0.455, 0.039, 0.1, 0.0])
    p = np.array([0.2275, 0.0, -0.05, 0.0])  # contact 1's tangent impulse cancels u_T with mu > 0 ...
    assert natural_map_error(W, q, np.array([0.0, 0.0]), np.array([0.2275, 0, 0, 0])) == 0.0
    # ... but with mu = 0 no tangent impulse is allowed: the error says so
    assert natural_map_error(W, q, np.array([0.0, 0.0]), p) > 1e-3
    pb = ContactProblem(W, q, np.array([0.0, 0.0]))
    assert pb.error(np.array([0.2275, 0, 0, 0])) == 0.0


@pytest.mark.parametrize("solver", ["auto", "lemke", "nsgs", "newton", "osqp"])
def test_every_solver_solves_frictionless_contacts(solver):
    W, q = 2 * np.eye(4), np.array([-0.455, 0.039, 0.1, 0.0])
    sol = make_solver(solver).solve(ContactProblem(W, q, np.zeros(2)))
    assert sol.success, sol.message
    np.testing.assert_allclose(sol.p, [0.2275, 0, 0, 0], atol=1e-12)


@settings(max_examples=40, deadline=None)
@given(k=st.integers(1, 6), seed=st.integers(0, 10_000), frictionless=st.lists(st.booleans(), min_size=6, max_size=6))
def test_lemke_meets_the_error_target_with_some_contacts_frictionless(k, seed, frictionless):
    rng = np.random.default_rng(seed)
    H = rng.standard_normal((2 * k, 2 * k + 2))
    W = H @ H.T + 1e-3 * np.eye(2 * k)
    q = H @ rng.standard_normal(2 * k + 2)
    mu = np.where(frictionless[:k], 0.0, rng.uniform(0.1, 1.0, k))
    pb = ContactProblem(W, q, mu)
    sol = make_solver("lemke").solve(pb)
    assert sol.success, sol.message
    assert pb.error(sol.p) <= 1e-10


@pytest.mark.parametrize("K,e", [(10, 0.5), (5, 0.9), (3, 0.0)])
def test_the_event_method_reaches_t_end_on_a_bead_column(K, e):
    system, q0, v0 = bead_column(K, e)
    res = lcp.simulate(system, 3.0, method="event", q0=q0, v0=v0)
    assert res.success and res.status == 0, res.message
    # at rest at the end, stacked bead on bead
    np.testing.assert_allclose(res.q[-1, 1::2], 0.1 + 0.2 * np.arange(K), atol=1e-9)
    assert np.all(system.gaps(res.q[-1]) >= -1e-9)


def test_bead_column_moreau_jean_converges_to_the_event_method():
    # three beads: the column's motion through its cascades, Moreau-Jean h -> 0 against events
    system, q0, v0 = bead_column(3, 0.5)
    ts = np.round(np.linspace(0.0, 1.5, 31), 10)
    ev = lcp.simulate(system, 1.5, method="event", q0=q0, v0=v0, t_eval=ts)
    assert ev.success, ev.message
    errors = []
    for h in (1e-3, 1e-4, 1e-5):
        mj = lcp.simulate(system, 1.5, h=h, q0=q0, v0=v0)
        assert mj.success, mj.message
        errors.append(float(np.abs(mj.q[np.round(ts / h).astype(int)] - ev.q).max()))
    assert errors[2] < 1e-4 and errors[2] < errors[0] / 20, errors
