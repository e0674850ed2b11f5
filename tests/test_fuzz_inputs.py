"""Fuzz (hypothesis) the inputs a user types: simulate's options and the System builder.

Whatever is passed, the answer is a result or a ValueError that names what is wrong; never a
TypeError, an IndexError, a CasADi RuntimeError or a crash from deep inside. The default profile
draws a few dozen cases per test; HYPOTHESIS_PROFILE=thorough draws a thousand.
"""
from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import lcp
from lcp import Contact, System

JUNK = st.one_of(st.none(), st.booleans(), st.integers(-3, 3), st.floats(allow_nan=True, allow_infinity=True),
                 st.text(max_size=4), st.lists(st.floats(-1, 1), max_size=3), st.just(object()))
SCENE = lcp.scenes.jean_pratt()
CHAIN = lcp.scenes.block_chain(2)

OPTIONS = {
    "h": st.one_of(JUNK, st.floats(1e-4, 0.1)),
    "theta": st.one_of(JUNK, st.floats(0.5, 1.0)),
    "solver": st.one_of(JUNK, st.sampled_from(["auto", "enum", "lemke", "osqp", "nsgs", "newton", "nope"])),
    "method": st.one_of(JUNK, st.sampled_from(["moreau-jean", "event", "rk4"])),
    "save_every": st.one_of(JUNK, st.integers(1, 5)),
    "fast": st.one_of(JUNK, st.booleans()),
    "fallback": st.one_of(JUNK, st.booleans()),
    "projection": st.one_of(JUNK, st.sampled_from(["auto", True, False, "always"])),
    "projection_tol": st.one_of(JUNK, st.floats(1e-14, 1e-3)),
    "t_end": st.one_of(JUNK, st.floats(0.01, 0.2)),
}


def _call(scene, kw):
    try:
        res = lcp.simulate(scene, **kw)
    except ValueError as exc:
        assert str(exc), "a ValueError must say what is wrong"
        return None
    assert isinstance(res.status, int) and isinstance(res.message, str) and res.message
    return res


@settings(deadline=None)
@given(st.fixed_dictionaries({}, optional=OPTIONS))
def test_simulate_options_give_a_result_or_a_clear_value_error(kw):
    kw.setdefault("t_end", 0.05)
    for scene in (SCENE, CHAIN):
        _call(scene, dict(kw))


@pytest.mark.parametrize("name,value", [("fallback", "no"), ("fast", "yes"), ("fallback", 0.5), ("fast", None)])
def test_boolean_options_are_booleans(name, value):
    # "no" is truthy: accepting it as True would do the opposite of what the user wrote
    with pytest.raises(ValueError, match=name):
        lcp.simulate(SCENE, 0.05, **{name: value})


ARRAYISH = st.one_of(JUNK, st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=4),
                     st.floats(-2, 2))
# mostly valid, sometimes not: a draw that fails at its first argument tests nothing after it
MASS = st.one_of(st.just("eye"), st.floats(0.1, 10), st.lists(st.floats(-1, 3), min_size=4, max_size=4), ARRAYISH)
FORCE = st.one_of(st.just("gravity"), st.lists(st.floats(-10, 10), min_size=2, max_size=2), ARRAYISH)
STATE = st.one_of(st.lists(st.floats(-1, 1), min_size=2, max_size=2), ARRAYISH)


@settings(deadline=None)
@given(mass=MASS, force=FORCE, mu=st.one_of(st.floats(0, 1), JUNK), e=st.one_of(st.floats(0, 1), JUNK),
       name=st.one_of(st.text(max_size=3), JUNK), q0=STATE, v0=STATE)
def test_the_system_builder_gives_a_system_or_a_clear_value_error(mass, force, mu, e, name, q0, v0):
    q, v = ca.SX.sym("q", 2), ca.SX.sym("v", 2)
    if isinstance(mass, str):
        mass = ca.SX.eye(2)
    elif isinstance(mass, list) and len(mass) == 4:
        mass = np.reshape(mass, (2, 2))
    if isinstance(force, str):
        force = ca.vertcat(0.1 * q[0], -9.81)
    try:
        contact = Contact(gap=q[1], tangent=q[0], mu=mu, e=e, name=name)
        system = System(q, v, mass, force, contacts=[contact])
    except ValueError as exc:
        assert str(exc)
        return
    try:
        res = lcp.simulate(system, 0.02, q0=q0, v0=v0, h=1e-2)
    except ValueError as exc:
        assert str(exc)
        return
    assert res.message and (res.success or res.status < 0)
    if res.success:
        assert np.all(np.isfinite(res.q)) and math.isfinite(float(res.t[-1]))
