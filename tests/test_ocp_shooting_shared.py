"""PhaseShooting(like=...): the Runge-Kutta NLP built on the check's symbolic NLP is the same NLP."""
import numpy as np
import pytest

from lcp.ocp.shooting import PhaseShooting, initial_point, phase_plan, plan_keys
from studies._ocp_models import EXAMPLES


@pytest.fixture(scope="module")
def motor_plan():
    """nosnoc's motor at N = 10 solved by the transcription only, and the plan of its event replay."""
    pb = EXAMPLES["motor"]().make(10)
    pb.replay_tol = None
    res = pb.solve(shooting=False)
    plan = phase_plan(res)
    return pb, res, plan, plan_keys(pb, plan, res)


def test_shared_nlp_is_the_nlp_built_alone(motor_plan):
    pb, res, plan, keys = motor_plan
    check = PhaseShooting(pb, plan, check=True, keys=keys)
    shared = PhaseShooting(pb, plan, substeps=4, keys=keys, like=check)
    alone = PhaseShooting(pb, plan, substeps=4, keys=keys)
    assert shared._modes_fns is check._modes_fns  # the symbolic part was not built again
    x = initial_point(check, res)
    p = shared.params(np.linspace(-1e-9, 1e-9, shared.n_corrections))
    for name in ("lbx", "ubx", "lbg", "ubg", "defect_rows"):
        assert np.array_equal(getattr(shared, name), getattr(alone, name))
    assert shared.ix.keys() == alone.ix.keys()
    assert all(np.array_equal(shared.ix[k], alone.ix[k]) for k in alone.ix)
    # the same bits, and the Runge-Kutta integrators (not the check's CVODES) inside
    assert np.array_equal(np.array(shared.g_fn(x, p)), np.array(alone.g_fn(x, p)))
    assert not np.array_equal(np.array(shared.g_fn(x, p)), np.array(check.g_fn(x, p)))


def test_not_shared_where_the_nlps_differ(motor_plan):
    pb, _, plan, keys = motor_plan
    check = PhaseShooting(pb, plan, check=True, keys=keys)
    assert not check.shares_with(pb, plan[:-1] + [plan[0]], check.keys, None, 0.0)  # another plan
    assert not check.shares_with(pb, check.plan, check.keys, None, 1e-10)  # another band on the pairs
    dropped = [[((0,), None)] + row[1:] for row in check.keys]  # a row dropped: the check adds constraints
    assert not check.shares_with(pb, check.plan, dropped, None, 0.0)
    other = EXAMPLES["motor"]().make(10)
    assert not check.shares_with(other, check.plan, check.keys, None, 0.0)
    assert check.shares_with(pb, check.plan, check.keys, None, 0.0)
