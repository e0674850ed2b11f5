"""The paths that run from a scene's numbers alone (no CasADi work per parameter set) agree with
the general ones: the closed-form single-contact event path and the compiled Moreau-Jean step."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import lcp
from lcp.timestepping.constant_model import ConstantModel
from lcp.events import event_driven
from lcp.timestepping.moreau_jean import MoreauJeanOptions, moreau_jean

params = st.fixed_dictionaries({
    # (M below 1e-6 but nonzero, e.g. 1e-158: the general path's QR underflows and it raises
    # "singular iteration matrix" while the closed form gives numbers; not a physical parameter)
    "m": st.floats(0.2, 3.0), "M": st.one_of(st.just(0.0), st.floats(1e-6, 3.0)),
    # (slopes below 1e-6 rad: tan^2 alpha in the subnormal range makes the CasADi path's iteration
    # matrix non-finite, a limitation of the general path, not of the parameters)
    "alpha": st.one_of(st.just(0.0), st.floats(1e-6, 1.4), st.floats(-1.4, -1e-6)),
    # speeds below 1e-6 m/s against rounding-level accelerations (R = 0, 1e-16 g over 1 s) make the
    # stop/no-stop decision a matter of rounding in both paths: not compared
    "R": st.floats(0.0, 3.0), "v0": st.one_of(st.just(0.0), st.floats(1e-6, 3.0), st.floats(-3.0, -1e-6)),
    # (loads below 1e-6 of the weight: the general integrator's mode decision takes a load of 1e-12
    # of the normal force for zero and sticks; see the frictionless test below)
    "phi": st.one_of(st.just(0.0), st.floats(1e-6, 30.0), st.floats(-30.0, -1e-6)),
})


def _close(a, b, rtol=1e-12, scale=None):
    if scale is None:
        scale = max(1.0, float(np.nanmax(np.abs(b)))) if np.size(b) else 1.0
    np.testing.assert_allclose(a, b, rtol=0, atol=rtol * scale)


def _scales(res):
    """Rounding scales of a result: a force is compared with the forces, an impulse with the impulses."""
    big = lambda *xs: max([1.0] + [float(np.nanmax(np.abs(x))) for x in xs if np.size(x)])  # noqa: E731
    forces, impulses = big(res.force_N, res.force_T), big(res.p_N, res.p_T)
    return {"q": big(res.q), "v": big(res.v), "p_N": impulses, "p_T": impulses, "force_N": forces, "force_T": forces}


@settings(deadline=None)
@given(params)
def test_closed_form_event_path_equals_the_general_integrator(p):
    sc = lcp.scenes.jean_pratt(**p)
    fast = lcp.simulate(sc, 1.0, method="event", n_eval=64)
    general = event_driven(sc.system, sc.q0, sc.v0, 1.0, n_eval=64)
    assert (fast.status, fast.mode_sequence) == (general.status, general.mode_sequence)
    assert len(fast.t_events) == len(general.t_events)
    # a stop time is -u/a with a a difference of terms of size g and result R g: its rounding is
    # amplified by about 1/R in both paths alike
    _close(fast.t_events, general.t_events, 1e-14 * max(1.0, 1.0 / max(p["R"], 1e-300)))
    scales = _scales(general)
    for name in ("q", "v", "p_N", "p_T", "force_N", "force_T"):
        _close(getattr(fast, name), getattr(general, name), scale=scales[name])
    np.testing.assert_array_equal(fast.modes, general.modes)
    # (where several motions are consistent, the exact solution is one of them, not necessarily the
    # one a vanishing Moreau-Jean step selects: not compared)
    if sc.solution is not None and fast.success and "non-unique" not in fast.message:
        ex = sc.exact(fast.t)
        _close(fast.q[:, 0], ex["x"], 1e-13)


@settings(deadline=None, max_examples=25)
@given(params, st.sampled_from([1e-2, 1e-3]))
def test_moreau_jean_from_the_numbers_equals_the_system_path(p, h):
    sc = lcp.scenes.jean_pratt(**p)
    fast = lcp.simulate(sc, 0.5, h=h)
    general = moreau_jean(sc.system, sc.q0, sc.v0, 0.5, MoreauJeanOptions(h=h))
    assert fast.status == general.status and fast.solver == general.solver
    for name in ("q", "v", "p_N", "p_T"):
        _close(getattr(fast, name), getattr(general, name), 1e-12)
    np.testing.assert_array_equal(fast.modes, general.modes)


def test_the_fast_paths_build_no_casadi_system_and_do_not_depend_on_it():
    a = lcp.scenes.jean_pratt(R=0.7, phi=4.0, v0=-1.0)
    ra, ma = lcp.simulate(a, 1.0, method="event"), lcp.simulate(a, 1.0, h=1e-3)
    assert not a.system_built
    b = lcp.scenes.jean_pratt(R=0.7, phi=4.0, v0=-1.0)
    b.system  # built: the scene still takes the same path, so the numbers are the same bits
    rb, mb = lcp.simulate(b, 1.0, method="event"), lcp.simulate(b, 1.0, h=1e-3)
    for x, y in ((ra, rb), (ma, mb)):
        for name in ("q", "v", "p_N", "p_T"):
            assert np.array_equal(getattr(x, name), getattr(y, name))
    # paths the numbers do not serve still work, building the System on demand
    c = lcp.scenes.jean_pratt(R=0.7)
    assert lcp.simulate(c, 0.3, h=1e-3, solver="lemke").success and c.system_built


def test_the_general_path_takes_over_where_the_closed_form_does_not_apply():
    sc = lcp.scenes.jean_pratt(R=2.5)  # kappa > 1: the tangential impact at t = 0
    res = lcp.simulate(sc, 0.3, method="event")
    assert res.success and len(res.impulses) == 1 and sc.system_built
    lifted = lcp.scenes.jean_pratt(phi=200.0)  # the load lifts the block: a flight phase
    assert lcp.simulate(lifted, 0.3, method="event").mode_sequence[-1] == ("open",)


def test_constant_model_validates_its_numbers():
    H = np.array([[0.0, 1.0], [1.0, 0.0]])
    good = dict(A=np.eye(2), F0=np.zeros(2), H=H, gap0=np.zeros(1), mu=np.array([0.5]), e=np.zeros(1),
                names=("x", "y"), contact_names=("P",))
    assert ConstantModel(**good).constant_forces
    for key, val, word in (("A", np.array([[1.0, 0.0], [0.0, 0.0]]), "singular"),
                           ("A", np.array([[1.0, 2.0], [0.0, 1.0]]), "symmetric"),
                           ("F0", np.array([np.nan, 0.0]), "F0 must be finite"),
                           ("mu", np.array([-0.1]), "mu must be >= 0"),
                           ("names", ("x",), "names")):
        with pytest.raises(ValueError, match=word):
            ConstantModel(**{**good, key: val})
    cm = ConstantModel.from_system(lcp.scenes.jean_pratt(R=0.3).system)
    ref = lcp.scenes.jean_pratt(R=0.3).model
    for name in ("A", "F0", "H", "gap0", "mu", "e"):
        np.testing.assert_array_equal(getattr(cm, name), getattr(ref, name))


def test_a_tiny_load_without_friction_sets_the_block_in_motion():
    """R = 0 and a load 1e-11 N: the block slides, x = phi t^2 / (2 (m + M tan^2 alpha)) (exact)."""
    sc = lcp.scenes.jean_pratt(R=0.0, v0=0.0, phi=1e-11, M=0.0)
    res = lcp.simulate(sc, 1.0, method="event", n_eval=11)
    assert res.mode_sequence == [("slide+",)] == [(sg.mode,) for sg in sc.solution.segments]
    np.testing.assert_allclose(res.q[:, 0], 1e-11 * res.t ** 2 / 2, rtol=1e-14, atol=0)
