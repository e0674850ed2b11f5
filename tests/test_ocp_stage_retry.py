"""The homotopy's retry of a failed relaxation stage (lcp.ocp.complementarity.STAGE_RETRIES).

IPOPT's failures are injected: the real solvers are wrapped so that a chosen stage reports a chosen
return status, and the homotopy must react to the status as documented (a smaller relaxation step
after an infeasible stage or a failed step, none after the iteration limit)."""
import numpy as np
import pytest

from lcp.ocp.complementarity import RETRIED, STAGE_RETRIES, ipopt_solver, run_homotopy
from lcp.ocp.guess import x0_from_guess
from lcp.ocp.options import HomotopyOptions
from lcp.ocp.transcription import Transcription
from studies._ocp_models import motor


class Failing:
    """An IPOPT Function that reports ``status`` (and returns its start) in the stages at the
    relaxations ``fail(sigma)`` (not in the polishing solve: it has its own variable bounds)."""

    def __init__(self, solver, fail, status, tr):
        self.solver, self.fail, self.status, self.failed, self.tr = solver, fail, status, [], tr

    def __call__(self, **kw):
        sigma = float(np.asarray(kw["p"]).ravel()[0])
        if kw["lbx"] is self.tr.lbx and self.fail(sigma):
            self.failed.append(sigma)
            self._stats = {"return_status": self.status, "iter_count": 7, "success": False}
            return {"x": kw["x0"], "f": 0.0, "lam_x": kw.get("lam_x0", 0.0), "lam_g": kw.get("lam_g0", 0.0)}
        out = self.solver(**kw)
        self._stats = self.solver.stats()
        return out

    def stats(self):
        return self._stats


@pytest.fixture(scope="module")
def motor_problem():
    ex = motor()
    pb = ex.make(30)
    tr = Transcription(pb)
    gs = pb.guess()
    return pb, tr, x0_from_guess(pb, tr, gs)


def solve(motor_problem, fail, status, polish=True):
    pb, tr, x0 = motor_problem
    opts = HomotopyOptions(polish=polish)
    cache = {}
    # the real solvers, built and cached as run_homotopy asks for them, each replaced in the cache by its wrapper
    built = {id(ipopt_solver(tr, opts, warm, cache, False)) for warm in (False, True)}
    wrapped = {}
    for key, solver in list(cache.items()):
        if id(solver) in built:
            cache[key] = wrapped[key] = Failing(solver, fail, status, tr)
    P0 = np.concatenate([[0.0], pb.q0, pb.v0])
    out = run_homotopy(tr, x0.copy(), P0, opts, cache, regularized=False)
    return out, sorted(s for w in wrapped.values() for s in w.failed)


def test_reference_homotopy_has_several_stages(motor_problem):
    (_, _, diag, status, message, history), failed = solve(motor_problem, lambda s: False, "")
    assert status == 0, message
    assert not failed
    assert [h.sigma for h in history[:3]] == pytest.approx([1e-4, 1e-5, 1e-6])


@pytest.mark.parametrize("status_name", RETRIED)
def test_a_failed_stage_is_retried_at_the_midpoint(motor_problem, status_name):
    (x, cost, diag, status, message, history), failed = solve(
        motor_problem, lambda s: s == pytest.approx(1e-5, rel=1e-12), status_name)
    assert failed == pytest.approx([1e-5])
    sig = [h.sigma for h in history]
    # 1e-4 converged, 1e-5 failed, then 10^-4.5 from 1e-4's solution, then down by the factor again
    assert sig[:4] == pytest.approx([1e-4, 1e-5, 10 ** -4.5, 10 ** -5.5])
    assert [h.success for h in history[:3]] == [True, False, True]
    assert history[1].return_status == status_name
    assert status == 0, message
    assert diag["residual"] <= HomotopyOptions().tol


def test_the_retries_are_bounded_and_the_message_says_so(motor_problem):
    (_, _, diag, status, message, history), failed = solve(
        motor_problem, lambda s: s < 0.99e-4, "Infeasible_Problem_Detected", polish=False)
    # 1e-5, then the midpoints towards 1e-4: 10^-4.5, 10^-4.25
    assert failed == pytest.approx(sorted([1e-5, 10 ** -4.5, 10 ** -4.25]))
    assert len(failed) == 1 + STAGE_RETRIES
    assert status == -1
    assert "Stage 1 (sigma = 5.62e-05): IPOPT returned Infeasible_Problem_Detected" in message
    assert f"after {STAGE_RETRIES} smaller relaxation steps from sigma = 0.0001" in message


def test_the_iteration_limit_is_not_retried(motor_problem):
    (_, _, diag, status, message, history), failed = solve(
        motor_problem, lambda s: s < 0.99e-4, "Maximum_Iterations_Exceeded", polish=False)
    assert failed == pytest.approx([1e-5])
    assert status == -1
    assert "Stage 1 (sigma = 1e-05): IPOPT returned Maximum_Iterations_Exceeded;" in message \
        or "Stage 1 (sigma = 1e-05): IPOPT returned Maximum_Iterations_Exceeded." in message
    assert "smaller relaxation step" not in message


def test_a_first_stage_failure_is_not_retried(motor_problem):
    # there is no converged stage to step from
    (_, _, diag, status, message, history), failed = solve(
        motor_problem, lambda s: True, "Infeasible_Problem_Detected", polish=False)
    assert failed == pytest.approx([1e-4])
    assert status == -1


def test_a_late_stage_is_not_retried(motor_problem):
    # sigma = 1e-8 is the geometric mean of the default sigma0 (1e-4) and sigma_min (1e-12)
    (_, _, diag, status, message, history), failed = solve(
        motor_problem, lambda s: s < 1.01e-8, "Infeasible_Problem_Detected", polish=False)
    assert failed == pytest.approx([1e-8])
    assert status == -1
    assert "smaller relaxation step" not in message
    assert [h.sigma for h in history] == pytest.approx([1e-4, 1e-5, 1e-6, 1e-7, 1e-8])
