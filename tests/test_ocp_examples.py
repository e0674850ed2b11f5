"""studies.ocp_examples: the examples of optimal control through contacts that open and close, their replay checks and the nosnoc peer."""
import numpy as np
import pytest

from studies import _nosnoc_examples as peers
from studies import ocp_examples as study
from studies._ocp_models import EXAMPLES


def test_point_on_plane_example_is_a_success_at_the_discrete_closed_form():
    ex = EXAMPLES["point_on_plane"]()
    row, _ = study._ours(ex, 20)
    assert row["ours_success"] and row["ours_method"] == "event" and row["ours_miss"] <= 1e-9
    d, T = np.hypot(1.0, 0.5), ex.T
    discrete = 12 * d ** 2 * 400 / (T ** 3 * 399) + (0.3 * 9.81) ** 2 * T
    assert row["ours_cost"] == pytest.approx(discrete, rel=1e-8)
    assert ex.reference < row["ours_cost"]
    # the effort of a control is its exact integral: the replay score repeats the objective
    assert row["ours_J_replay"] == pytest.approx(row["ours_cost"], rel=1e-9)


def test_block_chain_replay_misses_are_reported_not_hidden():
    """With uniform steps the stick-slip switches fall inside steps (and the springs make the theta = 1/2
    step second order between them): the event replay misses by O(h) (measured under the gap law, the
    default: 1.18e-2 at N = 20; 9.95e-3 and 4.86e-3 at N = 20, 40 under the velocity law), so the
    solve is not a success."""
    ex = EXAMPLES["block_chain2"]()
    ex.solve_kw = {**ex.solve_kw, "shooting": False}  # the transcription's own result
    r20, res20 = study._ours(ex, 20)
    r40, _ = study._ours(ex, 40)
    for r in (r20, r40):
        assert not r["ours_success"] and r["ours_miss"] > study.REPLAY_TOL
        assert "replay" in r["ours_message"] and r["ours_method"] == "event"
    assert r20["ours_miss"] == pytest.approx(1.18e-2, rel=2e-2)
    assert 1.6 < r20["ours_miss"] / r40["ours_miss"] < 2.6
    assert res20.complementarity_residual <= 1e-8  # the NLP itself is solved: the miss is the step's


def test_every_example_builds_and_has_a_peer_or_a_reason():
    for name, build in EXAMPLES.items():
        ex = build()
        assert ex.make(4).N == 4
        assert (name in peers.PEERS) != (name in peers.NO_PEER)


@pytest.mark.slow
@pytest.mark.skipif(not peers.available(), reason="nosnoc (optional peer) not installed")
def test_quick_study_with_nosnoc(tmp_path):
    out = study.run(out=tmp_path, quick=True)
    rows = {r["example"]: r for r in out["rows"]}
    assert set(rows) == set(study.QUICK)
    for r in out["rows"]:
        # never a success on an answer whose replay misses
        assert not r["ours_success"] or r["ours_miss"] <= study.REPLAY_TOL
    assert rows["point_on_plane"]["ours_success"]
    ps = rows["point_stick_slide"]
    assert ps["ours_success"] and ps["ours_miss"] <= 1e-12
    n, c, d = 9, 0.3 * 9.81, np.hypot(1.0, 0.5)
    assert ps["ours_cost"] == pytest.approx(4 / 3 * c * c * (36 * d * d * n * n / ((n * n - 1) * c * c)) ** 0.25,
                                            rel=1e-10)
    chain = rows["block_chain2"]
    assert chain["nosnoc_status"].startswith("SUCCESS")
    # nosnoc's chain control replayed by the event method: it ends where nosnoc says within 1e-3
    assert chain["nosnoc_method"] == "event" and chain["nosnoc_miss"] < 1e-3
    assert (tmp_path / "examples.csv").exists() and (tmp_path / "summary.png").exists()
