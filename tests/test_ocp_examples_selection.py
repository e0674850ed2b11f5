"""studies.ocp_examples: choosing examples and their N (``--examples name:N``), and nosnoc's BLAS setting."""
import pytest

from studies import ocp_examples as study


def test_selection_parses_names_and_sizes():
    assert study._selection(["motor:30,60", "block_chain2"]) == (["motor", "block_chain2"], {"motor": (30, 60)})
    assert study._selection(None) == (None, None)
    with pytest.raises(ValueError, match="motor:x"):
        study._selection(["motor:x"])


def test_unknown_names_and_options_are_refused_before_any_solve(tmp_path):
    with pytest.raises(ValueError, match="nope"):
        study.run(tmp_path, examples=["nope"])
    with pytest.raises(ValueError, match="cart_pole"):  # sizes for an example not selected
        study.run(tmp_path, examples=["motor"], sizes={"cart_pole": (20,)})
    with pytest.raises(ValueError, match="peer_blas"):
        study.run(tmp_path, examples=["motor"], peer_blas="two")


def test_sizes_choose_the_rows(tmp_path):
    out = study.run(tmp_path, examples=["ball_bounce"], sizes={"ball_bounce": (12,)})
    assert [(r["example"], r["N"]) for r in out["rows"]] == [("ball_bounce", 12)]
    assert out["rows"][0]["ours_success"] and out["rows"][0]["ours_miss"] <= study.REPLAY_TOL
