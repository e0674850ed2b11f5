"""Messages name the real cause: an option that is not a bool, a friction vector of the wrong
length, a time symbol the System was not given, an optimal-control problem without control
bounds, a contact that is singular only at the configuration it is checked at."""
from __future__ import annotations

import warnings

import casadi as ca
import numpy as np
import pytest

import lcp
from lcp.contact.problem import ContactProblem
from lcp.model.system import Contact, System


@pytest.mark.parametrize("method", ["moreau-jean", "event"])
@pytest.mark.parametrize("name, value", [("fallback", "no"), ("fallback", 0), ("fast", "False")])
def test_bool_options_must_be_bools(method, name, value):
    with pytest.raises(ValueError, match=f"{name} must be True or False, got {value!r}"):
        lcp.simulate(lcp.scenes.jean_pratt(), 0.1, h=1e-3, method=method, **{name: value})


def test_bool_options_accept_numpy_bools():
    r = lcp.simulate(lcp.scenes.jean_pratt(), 0.1, h=1e-2, fallback=np.bool_(False))
    assert r.success


def test_a_wrong_length_mu_is_blamed_on_mu():
    W, q = np.eye(4), np.array([-1.0, 0.0, -1.0, 0.5])
    with pytest.raises(ValueError, match=r"mu must hold one friction coefficient per contact.*2 contacts.*\(3,\)"):
        ContactProblem(W, q, [0.3, 0.3, 0.3])
    with pytest.raises(ValueError, match=r"W must be \(4, 4\) and q \(4,\)"):  # W and q disagree: as before
        ContactProblem(np.eye(6), q, [0.3, 0.3])
    with pytest.raises(ValueError, match="mu must be a vector"):
        ContactProblem(W, q, [[0.3, 0.3]])
    assert ContactProblem(W, q, [0.3, 0.5]).k == 2


def test_a_time_symbol_not_given_to_system_is_named():
    q, v, t = ca.SX.sym("q", 1), ca.SX.sym("v", 1), ca.SX.sym("t")
    with pytest.raises(ValueError, match=r"the force uses the symbol 't'.*pass it to System as t=t") as err:
        System(q, v, mass=1.0, force=ca.sin(t))
    assert "allow_free" not in str(err.value)
    # a second symbol named t is another symbol
    with pytest.raises(ValueError, match=r"symbol 't'.*given as t="):
        System(q, v, mass=1.0, force=ca.sin(ca.SX.sym("t")), t=t)
    with pytest.raises(ValueError, match=r"the mass uses the symbol 'k'"):
        System(q, v, mass=1.0 + ca.SX.sym("k") ** 2, force=0.0)
    s = System(q, v, mass=1.0, force=ca.sin(t), t=t)  # given: fine
    assert s.force_depends_on_t


def test_ocp_without_control_bounds_warns_nothing_and_does_not_contradict_itself():
    from lcp.ocp import OptimalControlProblem, tangential_push
    from lcp.ocp.options import OCP_STATUS_MESSAGES

    start = lcp.scenes.jean_pratt(v0=0.0)
    ocp = OptimalControlProblem(start, 4, control_matrix=tangential_push(start.system), T=0.5, free_time=True,
                                T_bounds=(0.05, 2.0), steps="free", terminal_cost=lambda T, q, v: T,
                                terminal_constraints=lambda q, v: ca.vertcat(q[0] - 0.2, v[0]))
    assert np.isinf(ocp.u_min).all() and np.isinf(ocp.u_max).all()
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        r = ocp.solve()
    if r.status == -3:  # the replay disproved the solve: the message must not claim it passed
        assert r.message.startswith(OCP_STATUS_MESSAGES[-3])
        assert "replay miss are within tolerance" not in r.message and "within replay_tol" not in r.message
        assert "no bound" in r.message
    else:
        assert r.replay is not None and r.replay.ok


def _double_pendulum(tangent_like_normal=False):
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    x = ca.sin(q[0]) + ca.sin(q[1])
    y = -ca.cos(q[0]) - ca.cos(q[1])
    tangent = ca.jacobian(y, q) if tangent_like_normal else ca.jacobian(x, q)
    return System(q, v, mass=ca.DM.eye(2), force=ca.vertcat(-9.81 * ca.sin(q[0]), -9.81 * ca.sin(q[1])),
                  contacts=[Contact(gap=y + 2.5, tangent_jacobian=tangent, mu=0.3, name="tip")])


def test_a_configuration_singular_for_a_contact_is_called_so_at_q0():
    s = _double_pendulum()
    with pytest.raises(ValueError) as err:
        s.check_state([0.0, 0.0], [0.0, 0.0])  # hanging straight down: the gap's gradient is zero
    msg = str(err.value)
    assert "at q0 = [0. 0.]" in msg and "normal row H_N" in msg and "Only this configuration" in msg
    q0, _ = _double_pendulum().check_state([0.3, -0.2], [0.0, 0.0])  # elsewhere: fine
    assert q0.tolist() == [0.3, -0.2]
    with pytest.raises(ValueError, match="nearby configuration too"):  # dependent everywhere
        _double_pendulum(tangent_like_normal=True).check_state([0.3, -0.2], [0.0, 0.0])
