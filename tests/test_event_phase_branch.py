"""The event integrator's lean ODE right-hand side: the system evaluated into NumPy buffers
(accel_arrays) and a phase's fixed branch solved without problem objects (PhaseBranch) give the
same bits as the CasADi call and the contact problem of the mode decision."""
import itertools

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from lcp.contact.modes import SLIDE_NEG, SLIDE_POS, STICK
from lcp.events.model import StateData, accel_arrays, accel_function
from lcp.events.modes import AccelProblem, PhaseBranch
from lcp.events.phases import phase_static
from lcp.model.control import ControlSchedule
from studies._ocp_models import EXAMPLES

SYSTEMS = {}


def _system(name):
    """An example's System under a constant control (the box: contacts on a rotating body; the
    cart-pole: a mass matrix that depends on the pole's angle)."""
    if name not in SYSTEMS:
        ex = EXAMPLES[name]()
        sys = ex.system
        SYSTEMS[name] = sys.with_control(ControlSchedule([0.0, 1.0], np.full((1, sys.nu), 3.0)))
    return SYSTEMS[name]


def _state(sys, seed):
    rng = np.random.default_rng(seed)
    return float(rng.uniform(0, 1)), rng.normal(size=sys.n_q), rng.normal(size=sys.n)


def _data(sys, t, q, v):
    n, m, nb = sys.n, sys.n_contacts, sys.n_bilateral
    A, F, G, zeta, H, Hdv, gap = (np.array(x, dtype=float) for x in accel_function(sys)(t, q, v))
    return StateData(A.reshape(n, n), F.ravel(), G.reshape(nb, n), zeta.ravel(), H.reshape(2 * m, n), Hdv.ravel(),
                     gap.ravel())


@settings(max_examples=25, deadline=None)
@given(name=st.sampled_from(["box_tip", "cart_pole"]), seed=st.integers(0, 2 ** 31))
def test_accel_arrays_are_the_casadi_call_bit_for_bit(name, seed):
    sys = _system(name)
    t, q, v = _state(sys, seed)
    ref = [np.array(x, dtype=float) for x in accel_function(sys)(t, q, v)]
    got = accel_arrays(sys, t, q, v)
    assert len(got) == len(ref)
    for a, b in zip(got, ref):
        assert a.flags.c_contiguous and a.shape == b.shape
        assert np.array_equal(a, b)


def _reference(data, idx, slide, modes, mu):
    """The mode decision's route: AccelProblem, solve_branch on its branch modes, forces, qdd."""
    acc = AccelProblem(data, idx, slide, mu)
    p = acc.pb.solve_branch(acc.branch_modes(list(modes)))
    if p is None:
        return None
    N, f = acc.forces(p)
    return acc.qdd(p), N, f


@settings(max_examples=25, deadline=None)
@given(name=st.sampled_from(["box_tip", "cart_pole"]), seed=st.integers(0, 2 ** 31))
def test_a_phase_branch_is_the_mode_decisions_branch_bit_for_bit(name, seed):
    sys = _system(name)
    t, q, v = _state(sys, seed)
    data = _data(sys, t, q, v)
    m, mu = sys.n_contacts, np.asarray(sys.mu, dtype=float)
    tried = 0
    for k in (1, 2):
        for idx in itertools.combinations(range(m), k):
            for modes in itertools.product((STICK, SLIDE_POS, SLIDE_NEG), repeat=k):
                # the closed contacts and slide signs as the integrator derives them for a phase
                _, idx_a, slide, *_ = phase_static(m, idx, modes)
                got = PhaseBranch(m, idx_a, slide, mu)(data)
                ref = _reference(data, idx_a, slide, modes, mu)
                assert (got is None) == (ref is None)
                if ref is not None:
                    tried += 1
                    for a, b in zip(got, ref):
                        assert np.array_equal(a, b)
    assert tried > 0


def test_a_singular_branch_is_none():
    """Two contacts at the same point in the same direction: the branch's matrix is singular."""
    data = StateData(np.eye(2), np.zeros(2), np.zeros((0, 2)), np.zeros(0),
                     np.array([[0.0, 1.0], [0.0, 1.0], [1.0, 0.0], [1.0, 0.0]]), np.zeros(4), np.zeros(2))
    assert PhaseBranch(2, np.array([0, 1]), np.zeros(2), np.array([0.5, 0.5]))(data) is None
