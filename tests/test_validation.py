"""Bad input gets a ValueError that names the parameter."""
import math

import casadi as ca
import numpy as np
import pytest

import lcp
from lcp.scenes import block_chain, jean_pratt
from lcp.model.system import Contact, System
from lem import jean_pratt as jean_pratt_parameters, series


@pytest.mark.parametrize("kw,name", [
    (dict(m=0.0), "m"), (dict(m=-1.0), "m"), (dict(M=-1.0), "M"), (dict(R=-0.1), "R"),
    (dict(alpha=math.pi / 2), "alpha"), (dict(alpha=-math.pi / 2), "alpha"), (dict(alpha=2.0), "alpha"),
    (dict(v0=math.nan), "v0"), (dict(g=math.inf), "g"), (dict(phi=math.nan), "phi"), (dict(g=-1.0), "g"),
    (dict(coordinates="polar"), "coordinates"), (dict(t_end=-1.0), "t_end"),
])
def test_jean_pratt_bad_parameters(kw, name):
    with pytest.raises(ValueError, match=name):
        jean_pratt(**kw)


@pytest.mark.parametrize("kw,name", [
    (dict(h=0.0), "h"), (dict(h=-1e-3), "h"), (dict(h=math.nan), "h"), (dict(theta=0.3), "theta"),
    (dict(theta=1.5), "theta"), (dict(solver="pgs"), "solver"), (dict(method="rk4"), "method"),
    (dict(t_end=0.0), "t_end"), (dict(t_end=-1.0), "t_end"), (dict(t_end=math.inf), "t_end"),
    (dict(solver="osqp", solver_options=dict(eps_abs=-1.0)), "eps_abs"),
    (dict(solver="lemke", solver_options=dict(nonsense=1)), "solver_options"),
    (dict(q0=[0.0, 0.0, 0.0]), "q0"), (dict(v0=[math.nan, 0.0]), "v0"),
])
def test_simulate_bad_options(kw, name):
    with pytest.raises(ValueError, match=name):
        lcp.simulate(jean_pratt(), **{"t_end": 0.1, **kw})


def test_unknown_solver_lists_the_known_ones():
    with pytest.raises(ValueError, match="enum.*lemke.*osqp"):
        lcp.simulate(jean_pratt(), 0.1, solver="siconos")


def test_enum_refuses_several_contacts():
    res = lcp.simulate(block_chain(3), 0.1, h=1e-3, solver="enum")
    assert not res.success and res.status == -1
    assert "does not apply" in res.message and "Step 0" in res.message


def _block(mass, force=None, **kw):
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    force = ca.vertcat(0, -9.81) if force is None else force
    return System(q, v, mass, force, contacts=[Contact(gap=q[1], tangent=q[0], mu=0.3)], **kw), q, v


def test_singular_or_indefinite_mass():
    for mass in (np.zeros((2, 2)), np.diag([1.0, -1.0]), np.array([[1.0, 1.0], [1.0, 1.0]])):
        s, _, _ = _block(mass)
        with pytest.raises(ValueError, match="mass"):
            lcp.simulate(s, 0.1, q0=np.zeros(2), v0=np.zeros(2))


def test_nonsymmetric_mass():
    s, _, _ = _block(np.array([[1.0, 0.5], [0.0, 1.0]]))
    with pytest.raises(ValueError, match="symmetric"):
        lcp.simulate(s, 0.1, q0=np.zeros(2), v0=np.zeros(2))


def test_bad_system_definitions():
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    with pytest.raises(ValueError, match="mass"):
        System(q, v, np.eye(3), ca.vertcat(0, 0))
    with pytest.raises(ValueError, match="force"):
        System(q, v, np.eye(2), ca.vertcat(0, 0, 0))
    with pytest.raises(ValueError, match="mu"):
        Contact(gap=q[1], tangent=q[0], mu=-0.1)
    with pytest.raises(ValueError, match="mu"):
        Contact(gap=q[1], tangent=q[0], mu=math.nan)
    with pytest.raises(ValueError, match="e of"):
        Contact(gap=q[1], tangent=q[0], mu=0.1, e=1.5)
    with pytest.raises(ValueError, match="tangent"):
        Contact(gap=q[1], mu=0.1)
    with pytest.raises(ValueError, match="q must"):
        System(ca.vertcat(q[0] * 2, q[1]), v, np.eye(2), ca.vertcat(0, 0))
    with pytest.raises(ValueError, match="mass"):
        System(q, v, ca.diag(v), ca.vertcat(0, 0))


def test_bare_system_needs_state():
    s, _, _ = _block(np.eye(2))
    with pytest.raises(ValueError, match="q0"):
        lcp.simulate(s, 0.1)
    with pytest.raises(ValueError, match="scene"):
        lcp.simulate("jean_pratt", 0.1)


def test_block_chain_bad_parameters():
    with pytest.raises(ValueError, match="K"):
        block_chain(0)
    with pytest.raises(ValueError, match="m"):
        block_chain(3, m=[1.0, -1.0, 1.0])
    with pytest.raises(ValueError, match="mu"):
        block_chain(3, mu=-0.2)
    with pytest.raises(ValueError, match="v0"):
        block_chain(3, v0=[1.0, 2.0])


def test_series_bad_parameters():
    with pytest.raises(ValueError, match="alpha"):
        jean_pratt_parameters.kappa(1.0, 1.0, math.pi / 2, 0.5)
    with pytest.raises(ValueError, match="R"):
        series.N0_printed(1.0, 1.0, 0.5, -0.5)
    with pytest.raises(ValueError, match="v0"):
        series.series_4_1_printed(0.1, 0.0, 1.0)
    with pytest.raises(ValueError, match="z0"):
        series.series_3_20_printed(0.1, 0.0)


def test_step_larger_than_horizon_is_rejected_unless_asked():
    scene = jean_pratt()
    with pytest.raises(ValueError, match=r"\bh\b"):
        lcp.simulate(scene, 0.3, h=1.0)
    res = lcp.simulate(scene, 0.3, h=1.0, allow_large_step=True)
    assert res.success and res.t[-1] == 1.0


@pytest.mark.parametrize("bad, name", [(dict(h=-1), "h"), (dict(h=float("nan")), "h"),
                                       (dict(theta=2.0), "theta"), (dict(solver="foo"), "solver"),
                                       (dict(save_every=0), "save_every")])
def test_event_method_rejects_invalid_ignored_options(bad, name):
    with pytest.raises(ValueError, match=name):
        lcp.simulate(jean_pratt(), 0.3, method="event", **bad)


def _free_block():
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    return System(q, v, mass=2 * ca.SX.eye(2), force=ca.vertcat(0, -2 * 9.81),
                  contacts=[Contact(gap=q[1], tangent=q[0], mu=0.3)])


@pytest.mark.parametrize("q0, v0, name", [
    ([[0.0, 0.0]], [1.5, 0.0], "q0"), ([0.0], [1.5, 0.0], "q0"), ([0.0, 0.0], [1.5, 0.0, 0.0], "v0"),
    ("0,0", [1.5, 0.0], "q0"), ([0.0, 0.0], ["fast", 0.0], "v0"),
])
def test_newcomer_state_mistakes(q0, v0, name):
    with pytest.raises(ValueError, match=name):
        lcp.simulate(_free_block(), 1.0, h=1e-3, q0=q0, v0=v0)


def test_newcomer_model_mistakes():
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    with pytest.raises(ValueError, match="mu"):
        Contact(gap=q[1], tangent=q[0], mu="0.3")  # a string is a typo, not a number
    with pytest.raises(ValueError, match="mu"):
        Contact(gap=q[1], tangent=q[0], mu=[0.3, 0.4])
    with pytest.raises(ValueError, match="e of"):
        Contact(gap=q[1], tangent=q[0], mu=0.3, e=-0.1)
    with pytest.raises(ValueError, match="mass"):
        System(q, v, mass=[1.0, 1.0], force=ca.vertcat(0, -9.81))
    with pytest.raises(ValueError, match="contacts"):
        System(q, v, mass=np.eye(2), force=ca.vertcat(0, -9.81), contacts=Contact(gap=q[1], tangent=q[0], mu=0.3))


@pytest.mark.parametrize("kw, name", [
    (dict(R=[0.5, 1.0]), "R"), (dict(M="1"), "M"), (dict(alpha=45.0), "alpha"), (dict(m=-1.0), "m"),
])
def test_newcomer_scene_mistakes(kw, name):
    with pytest.raises(ValueError, match=name):
        jean_pratt(**kw)


@pytest.mark.parametrize("args, kw, name", [
    ((0.3,), dict(h="1e-3"), "h"), (("0.3",), {}, "t_end"), ((0.0,), {}, "t_end"), ((0.3,), dict(theta=0), "theta"),
    ((0.3,), dict(tol=1e-6), "tol"), ((0.3,), dict(solver="Lemke"), "solver"),
    ((0.3,), dict(method="events"), "method"),
    ((0.3,), dict(save_every=2.5), "save_every"), ((0.3,), dict(method="event", n_eval=0), "n_eval"),
    ((0.3,), dict(method="event", t_eval=[0.0, 1.0]), "t_eval"),
])
def test_newcomer_simulate_mistakes(args, kw, name):
    with pytest.raises(ValueError, match=name):
        lcp.simulate(jean_pratt(), *args, **kw)


def test_block_chain_count_must_be_an_integer():
    for K in (2.5, "3"):
        with pytest.raises(ValueError, match="K"):
            block_chain(K)
