"""No loaded contact is ever inactive: two stacked blocks in seven regimes, on every path of
Moreau-Jean (the Python loop with each planar solver that applies to two contacts, the compiled loop), for h = 1e-2 ... 1e-6.

The contact between the blocks carries the upper block's weight in every regime, so its normal
impulse must be > 0 in every step after the first, and the gap must stay closed to rounding (an
inactive step lets the upper block fall by g h^2 / 2 and never recover)."""
import numpy as np
import pytest

import lcp
from lcp.classical import stacked_blocks

MU = (0.5, 0.3)
G = 9.81
M = 2.0
SLIP = M * G * (MU[0] + MU[1])  # above this push the upper block slips on the lower one
#: (push on the lower block, its initial velocity, theta)
REGIMES = {
    "rest": (0.0, 0.0, 0.5),
    "together": (0.5 * (MU[0] * M * G + SLIP), 0.0, 0.5),
    "just below slip": (SLIP * (1 - 1e-3), 0.0, 0.5),
    "just above slip": (SLIP * (1 + 1e-3), 0.0, 0.5),
    "top slips": (1.5 * SLIP, 0.0, 0.5),
    "launched theta 1/2": (0.0, 2.0, 0.5),
    "launched theta 1": (0.0, 2.0, 1.0),
}
PATHS = [("auto", False), ("nsgs", False), ("newton", False), ("lemke", False), ("osqp", False),
         ("auto", True), ("nsgs", True)]
HS = [1e-2, 1e-3, 1e-4, 1e-5, 1e-6]


def _check(regime, solver, fast, h, steps):
    push, v_launch, theta = REGIMES[regime]
    sc = stacked_blocks(2, mu=list(MU), push=push)
    v0 = np.zeros(4)
    v0[0] = v_launch
    res = lcp.simulate(sc, steps * h, h=h, theta=theta, solver=solver, fast=fast, v0=v0)
    assert res.success, res.message
    assert res.stats.steps == steps
    pN = res.p_N[1:, 1]
    assert np.all(pN > 0), f"inter-block contact unloaded in {int(np.sum(pN <= 0))} steps, first {int(np.argmax(pN <= 0)) + 1}"
    gap = res.q[:, 3] - res.q[:, 1] - sc.params["height"]
    assert gap.min() >= -64 * np.finfo(float).eps * 0.2, gap.min()
    # the weight of the upper block, to the solver's tolerance (theta = 1/2 and 1 alike)
    np.testing.assert_allclose(pN / h, G, rtol=1e-6)


@pytest.mark.parametrize("regime", list(REGIMES))
@pytest.mark.parametrize("solver,fast", PATHS)
@pytest.mark.parametrize("h", [1e-3, 1e-6])
def test_loaded_contact_stays_active(regime, solver, fast, h):
    _check(regime, solver, fast, h, 40)


@pytest.mark.slow
@pytest.mark.parametrize("regime", list(REGIMES))
@pytest.mark.parametrize("solver,fast", PATHS)
@pytest.mark.parametrize("h", HS)
def test_loaded_contact_stays_active_grid(regime, solver, fast, h):
    _check(regime, solver, fast, h, 300)
