"""The event method's mode enumeration split by the components of W's coupling
(:func:`lcp.events.modes.enumerate_branches`): the same solutions, in the same order and with the
same forces, accelerations and flags, as the enumeration of the whole problem."""
from types import SimpleNamespace
from unittest import mock

import casadi as ca
import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import lcp
from lcp.contact.problem import OPEN, SLIDE_NEG, SLIDE_POS, STICK, ContactProblem
from lcp.events import modes
from lcp.events.model import StateData
from lcp.events.modes import AccelProblem, coupling_components, enumerate_branches
from lcp.model.forces import point_force
from lcp.model.system import Contact, System
from lcp.scenes.classical import BoxReference

G = 9.81


def plain(acc, allowed=None):
    """The enumeration of the whole problem (one component), as before the split."""
    with mock.patch.object(modes, "coupling_components", lambda a: [np.arange(a.k)]):
        return enumerate_branches(acc, allowed)


def spying(calls):
    """modes._enumerate_components recording whether it split (True) or fell back (False)."""
    split = modes._enumerate_components

    def spy(*a, **kw):
        out = split(*a, **kw)
        calls.append(out[0] is not None)
        return out

    return spy


def expected_split(acc, comps):
    """What enumerate_branches does with the components: [] (not split: one component or few
    branches), [True] (split) or [False] (would not save branch solves)."""
    n = [2 if x else 4 for x in acc.slide]
    whole = int(np.prod(n))
    if len(comps) == 1 or whole <= modes.SPLIT_MIN_BRANCHES:
        return []
    return [sum(int(np.prod([n[j] for j in J])) for J in comps) + 2 * len(comps) < whole]


def assert_same(got, ref):
    sols, _ = got
    ref_sols, _ = ref
    assert [s.modes for s in sols] == [s.modes for s in ref_sols]
    for s, r in zip(sols, ref_sols):
        assert [type(x) for x in s.modes] == [type(x) for x in r.modes]
        # each combination is solved again on the whole problem: not rounding, the same numbers
        np.testing.assert_array_equal(s.p, r.p)
        np.testing.assert_array_equal(s.qdd, r.qdd)
        assert (s.nullity, s.motion_depends) == (r.nullity, r.motion_depends)


def ground_rows(n, dof, rx, ry):
    """Normal and tangent rows of a floor contact at offset (rx, ry) from the centre of the
    planar body whose (x, y, theta) are dof, dof + 1, dof + 2."""
    hn, ht = np.zeros(n), np.zeros(n)
    hn[dof + 1], hn[dof + 2] = 1.0, rx
    ht[dof], ht[dof + 2] = 1.0, -ry
    return hn, ht


def accel_problem(masses, contacts, slide, mu, F, Hdv, coupling=0.0):
    """The AccelProblem of planar bodies with the given masses (inertia = mass / 6) and contacts
    [(body, rx, ry, other_body or None)]: a contact on another body is the difference of the two
    bodies' rows (one stacked on the other). ``coupling`` adds a symmetric off-diagonal term to
    the mass matrix that links every body."""
    nb = len(masses)
    n = 3 * nb
    M = np.diag(np.repeat(masses, 3) * np.tile([1.0, 1.0, 1.0 / 6.0], nb))
    if coupling:
        C = np.zeros((n, n))
        C[0, 3:] = C[3:, 0] = coupling
        M = M + C
    HN, HT = [], []
    for b, rx, ry, other in contacts:
        hn, ht = ground_rows(n, 3 * b, rx, ry)
        if other is not None:
            gn, gt = ground_rows(n, 3 * other, rx, -ry)
            hn, ht = hn - gn, ht - gt
        HN.append(hn)
        HT.append(ht)
    H = np.array(HN + HT)
    m = len(contacts)
    data = StateData(M, np.asarray(F, dtype=float), np.zeros((0, n)), np.zeros(0), H,
                     np.asarray(Hdv, dtype=float), np.zeros(m))
    return AccelProblem(data, np.arange(m), np.asarray(slide, dtype=float), np.asarray(mu, dtype=float),
                        flush=True)


@st.composite
def scenes_(draw, coupled=None):
    nb = draw(st.integers(2, 3))
    masses = draw(st.lists(st.floats(0.5, 2.0), min_size=nb, max_size=nb))
    contacts = []
    for b in range(nb):
        # one or two floor contacts per body: two are a table's legs (redundant rows: 4 in 3 dof)
        ry = draw(st.floats(-0.3, -0.05))
        for side in range(draw(st.integers(1, 2))):  # the legs on either side of the centre
            rx = draw(st.floats(-0.5, 0.1)) if side == 0 else draw(st.floats(-0.1, 0.5))
            contacts.append((b, rx, draw(st.sampled_from([ry, ry - 0.1])), None))
    if draw(st.booleans()):  # body 1 resting on body 0: their contacts are one component
        contacts.append((1, draw(st.floats(-0.3, 0.3)), -0.1, 0))
    contacts = contacts[:5]
    b_used = sorted({c[0] for c in contacts})
    m = len(contacts)
    # per body, as its legs would have them (a stacked contact takes the upper body's)
    body_mu = [draw(st.sampled_from([0.0, 0.3, 0.8, 0.8])) for _ in range(nb)]
    body_slide = [draw(st.sampled_from([0.0, 0.0, 1.0, -1.0])) for _ in range(nb)]
    mu = [body_mu[c[0]] for c in contacts]
    slide = [body_slide[c[0]] for c in contacts]
    n = 3 * nb
    # mostly pressed down, pushed and turned less than friction and the legs hold (rest, redundant)
    F = np.array([draw(st.floats(-3.0, 3.0)), draw(st.floats(-2.0, 2.0)), draw(st.floats(-0.5, 0.5))] * nb)
    F[1::3] -= np.asarray(masses) * G * draw(st.floats(0.0, 1.5))
    Hdv = np.array([draw(st.sampled_from([0.0, 0.0, draw(st.floats(-1.0, 1.0))])) for _ in range(2 * m)])
    cpl = draw(st.sampled_from([0.0, 0.0, 0.05])) if coupled is None else coupled
    return accel_problem(masses, contacts, slide, mu, F, Hdv, cpl), contacts, b_used, cpl


def _split_against_whole(acc):
    """The split enumeration of ``acc`` checked against the whole one: (the whole enumeration,
    the coupling components, which components the split enumerated on their own)."""
    split = []
    with mock.patch.object(modes, "_enumerate_components", spying(split)):
        got = enumerate_branches(acc)
    ref = plain(acc)
    assert_same(got, ref)
    return ref, coupling_components(acc), split


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenes_())
def test_split_enumeration_is_the_whole_enumeration(case):
    acc, contacts, _, cpl = case
    ref, comps, split = _split_against_whole(acc)
    event(f"k={acc.k} components={len(comps)} solutions={min(len(ref[0]), 3)}"
          f" redundant={any(s.nullity for s in ref[0])} sliding={bool(np.any(acc.slide))}")
    # a component never spans bodies that do not touch (body 1 stacked on body 0 joins them; the
    # coupled mass matrix joins all)
    stacked = any(c[3] is not None for c in contacts)
    group = [0 if cpl or (stacked and b in (0, 1)) else b for b, _, _, _ in contacts]
    for J in comps:
        assert len({group[j] for j in J.tolist()}) == 1
    exp = expected_split(acc, comps)
    # the split may give up (and enumerate the whole problem) where a component's loads or offsets
    # are rounding beside another's (hypothesis draws 1e-78): its own consistency cut then differs
    assert split == exp or (exp == [True] and split == [False])
    event(f"split={split}")


@st.composite
def tables_(draw):
    """Two or three tables on two legs each (4 rows in 3 dof: singular branches), loaded below
    what makes them tip or slip, some sliding (folded columns, and the friction of two legs
    depends on their squeeze: motion_depends), some frictionless."""
    nb = draw(st.integers(2, 3))
    masses = draw(st.lists(st.floats(0.5, 2.0), min_size=nb, max_size=nb))
    contacts, mu, slide = [], [], []
    F = np.zeros(3 * nb)
    for b in range(nb):
        ry = draw(st.floats(-0.3, -0.05))
        mub = draw(st.sampled_from([0.0, 0.3, 0.8, 0.8]))
        sb = draw(st.sampled_from([0.0, 0.0, 0.0, 1.0, -1.0]))
        for rx in (draw(st.floats(-0.5, -0.1)), draw(st.floats(0.1, 0.5))):
            contacts.append((b, rx, draw(st.sampled_from([ry, ry - 0.1])), None))
            mu.append(mub)
            slide.append(sb)
        F[3 * b:3 * b + 3] = [draw(st.floats(-2.0, 2.0)), -masses[b] * G * draw(st.floats(0.5, 1.5)),
                              draw(st.floats(-0.3, 0.3))]
    return accel_problem(masses, contacts, slide, mu, F, np.zeros(2 * len(contacts)))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(tables_())
def test_split_enumeration_of_redundant_tables(acc):
    ref, comps, split = _split_against_whole(acc)
    assert [J.tolist() for J in comps] == [[2 * b, 2 * b + 1] for b in range(acc.k // 2)]
    assert split == expected_split(acc, comps)
    event(f"k={acc.k} solutions={min(len(ref[0]), 3)} redundant={any(s.nullity for s in ref[0])}"
          f" moves={any(s.motion_depends for s in ref[0])} sliding={bool(np.any(acc.slide))}")


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scenes_(coupled=0.0), st.integers(0, 2 ** 32 - 1), st.booleans())
def test_split_enumeration_keeps_the_allowed_sets(case, seed, as_int):
    acc = case[0]
    rng = np.random.default_rng(seed)
    every = [s.modes for s in plain(acc)[0]]
    choices = [(OPEN, SLIDE_POS if s > 0 else SLIDE_NEG) if s else (OPEN, STICK, SLIDE_POS, SLIDE_NEG)
               for s in acc.slide]
    import itertools

    allowed = {md for md in itertools.product(*choices) if rng.random() < 0.6}
    allowed |= {md for md in every if rng.random() < 0.5}
    allowed.add(tuple([OPEN] * (acc.k + 1)))  # a wrong length: ignored, as before
    if as_int:
        allowed = {tuple(int(x) for x in md) for md in allowed}
    assert_same(enumerate_branches(acc, allowed), plain(acc, allowed))


def test_table_legs_and_a_slider_split_exactly():
    # body 0 on two legs (redundant: nullity 1), body 1 sliding on one contact, body 2 on one
    acc = accel_problem([1.0, 2.0, 0.7], [(0, -0.4, -0.2, None), (0, 0.4, -0.2, None), (1, 0.1, -0.1, None),
                                           (2, 0.0, -0.1, None)],
                        [0.0, 0.0, 1.0, 0.0], [0.5, 0.5, 0.3, 0.0], [0.0, -G, 0.0, 1.0, -2 * G, 0.0, 0.0, -0.7 * G, 0.0],
                        np.zeros(8))
    comps = coupling_components(acc)
    assert [J.tolist() for J in comps] == [[0, 1], [2], [3]]
    got, ref = enumerate_branches(acc), plain(acc)
    assert_same(got, ref)
    # every combination of the components' admissible branches was admissible here: the
    # components' 16 + 2 + 4 branches, then one whole solve per solution (plain: 128)
    assert ref[1] == 4 * 4 * 2 * 4 and got[1] == 16 + 2 + 4 + len(got[0])
    # legs: stick-stick (nullity 1) and the four one-leg slips of no friction force; the slider
    # slides; the frictionless contact's three closed labels are one motion
    assert len(got[0]) == 7 * 3
    resting = [s for s in got[0] if s.modes[:2] == (STICK, STICK)]
    assert len(resting) == 3 and all(s.nullity == 1 for s in resting)
    k = acc.k
    N, f = resting[0].p[:k], resting[0].p[k:]
    # the legs share the weight (least-norm forces), the slider's friction is -mu N
    np.testing.assert_allclose(N[:2], [G / 2, G / 2], rtol=1e-12)
    assert np.max(np.abs(f[:2])) <= 1e-14 * G
    np.testing.assert_allclose(acc.forces(resting[0].p)[1][2], -0.3 * N[2], rtol=1e-15)
    np.testing.assert_allclose(N[3], 0.7 * G, rtol=1e-12)


def test_scales_far_apart_fall_back_to_the_whole_problem():
    # a 1e12 kg block lifted at 1e-9 m/s^2 beside a 1 kg table: the whole problem cuts ranks at
    # 1e-10 of its largest singular value (the table's, ~1), below which are all of the heavy
    # contact's (~1e-12), so its stick and slip branches have forces 0 and are admissible to the
    # whole problem; the heavy block's own problem solves them (N < 0: lifting) and rejects them.
    # The split must not decide otherwise: it gives up and the whole problem is enumerated.
    acc = accel_problem([1e12, 1.0], [(0, 0.0, -0.1, None), (1, -0.3, -0.1, None), (1, 0.3, -0.1, None)],
                        [0.0, 0.0, 0.0], [0.5, 0.5, 0.5], [0.0, 1e3, 0.0, 0.5, -G, 0.0], np.zeros(6))
    assert [J.tolist() for J in coupling_components(acc)] == [[0], [1, 2]]
    ref = plain(acc)
    with mock.patch.object(modes, "_decided_as_whole", lambda infos: True):
        unguarded = enumerate_branches(acc)
    assert len(unguarded[0]) < len(ref[0])  # what the split alone would have missed
    split = []
    with mock.patch.object(modes, "_enumerate_components", spying(split)):
        got = enumerate_branches(acc)
    assert_same(got, ref)
    assert split == [False] and got[1] == 4 + 16 + 64  # the components tried, then the whole problem


def test_coupling_is_any_nonzero_entry():
    def comps(W):
        pb = ContactProblem(W, np.zeros(4), np.array([0.3, 0.3]))
        return [J.tolist() for J in coupling_components(SimpleNamespace(k=2, pb=pb))]

    W = np.diag([1.0, 2.0, 3.0, 4.0])
    assert comps(W) == [[0], [1]]
    for i, j in ((0, 1), (0, 3), (2, 1), (3, 2), (1, 2)):
        Wc = W.copy()
        Wc[i, j] = 1e-300  # however small, a coupling is kept
        assert comps(Wc) == [[0, 1]]
    Wc = W.copy()
    Wc[3, 0] = np.nan
    assert comps(Wc) == [[0, 1]]
    Wc = W.copy()
    Wc[2, 0] = -0.0  # a signed zero is a zero
    assert comps(Wc) == [[0], [1]]


def two_boxes(ramp=5.0, mu=0.3, w=1.0, H=0.5, m=1.0, hp=0.1):
    """Two boxes on their bottom corners, 3 m apart: the first pushed by P = ramp t at height hp
    on its back face, the second left at rest (its two corners: redundant contacts)."""
    q, v = ca.SX.sym("q", 6), ca.SX.sym("v", 6)
    t = ca.SX.sym("t")
    contacts, F = [], []
    for b in range(2):
        x, y, th = q[3 * b], q[3 * b + 1], q[3 * b + 2]
        c, s = ca.cos(th), ca.sin(th)

        def point(a, d, x=x, y=y, c=c, s=s):
            return ca.vertcat(x + a * c - d * s, y + a * s + d * c)

        for nm, a in (("back", -w / 2), ("front", w / 2)):
            p = point(a, -H / 2)
            contacts.append(Contact(gap=p[1], tangent=p[0], mu=mu, e=0.0, name=f"{nm}{b}"))
        Fb = ca.vertcat(0, -m * G, 0)
        if b == 0:
            f = point_force(q, point(-w / 2, -H / 2 + hp), ca.vertcat(ramp * t, 0))
            Fb = Fb + f[0:3]
        F.append(Fb)
    I = m * (w * w + H * H) / 12
    system = System(q, v, ca.diag(ca.DM([m, m, I, m, m, I])), ca.vertcat(*F), contacts=contacts, t=t)
    return system, np.array([0.0, H / 2, 0.0, 3.0, H / 2, 0.0])


def test_event_method_on_separate_bodies_is_unchanged_by_the_split():
    ramp, mu, w, H, m, hp = 5.0, 0.3, 1.0, 0.5, 1.0, 0.1
    system, q0 = two_boxes(ramp, mu, w, H, m, hp)
    T = 0.9
    t_eval = np.linspace(0.0, T, 31)
    calls = []
    with mock.patch.object(modes, "_enumerate_components", spying(calls)):
        ev = lcp.simulate(system, T, method="event", q0=q0, v0=np.zeros(6), t_eval=t_eval)
    with mock.patch.object(modes, "coupling_components", lambda a: [np.arange(a.k)]):
        ref = lcp.simulate(system, T, method="event", q0=q0, v0=np.zeros(6), t_eval=t_eval)
    assert ev.success and ref.success, (ev.message, ref.message)
    assert any(calls)  # the split ran
    for name in ("t", "q", "v", "force_N", "force_T"):
        np.testing.assert_array_equal(getattr(ev, name), getattr(ref, name))
    # and the motion is the right one: the pushed box slides from mu m g / ramp as x = c dt^3 / 6m,
    # the other stays at rest with half its weight on each corner
    sol = BoxReference(w, H, m, G, mu, ramp, hp)
    assert sol.regime == "slide" and sol.t_valid > T
    np.testing.assert_allclose(ev.q[:, 0], sol(t_eval)["x"], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ev.q[:, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(ev.q[:, 3:], np.tile(q0[3:], (t_eval.size, 1)), rtol=1e-15, atol=1e-14)
    np.testing.assert_allclose(ev.force_N[:, 2:], m * G / 2, rtol=1e-12)
