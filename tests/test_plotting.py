"""lcp.plotting: what the figures hold (axes, lines, labels), not their pixels."""
from __future__ import annotations

import dataclasses
import numpy as np
import pytest

matplotlib = pytest.importorskip("matplotlib")
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import lcp  # noqa: E402
from lcp.plotting import MODE_NAMES, animate, contact_points, plot_result  # noqa: E402


@pytest.fixture(autouse=True)
def _close_figures():
    yield
    plt.close("all")


@pytest.fixture(scope="module")
def jean_pratt():
    scene = lcp.scenes.jean_pratt(v0=1.0)
    return scene, lcp.simulate(scene, 0.3, h=1e-2)


def test_result_plot_draws_coordinates_velocities_forces_and_modes(jean_pratt):
    scene, res = jean_pratt
    fig = res.plot(scene.system)
    ax_q, ax_v, ax_f, ax_m = fig.axes
    assert [a.get_ylabel() for a in fig.axes] == ["q", "v", "force", "mode"]
    assert [l.get_label() for l in ax_q.lines] == list(scene.system.names)
    np.testing.assert_array_equal(ax_q.lines[0].get_ydata(), res.q[:, 0])
    np.testing.assert_array_equal(ax_v.lines[1].get_ydata(), res.v[:, 1])
    # one contact: its normal force (solid) and its friction force (dashed), the mean over each step
    assert len(ax_f.lines) == 2 and ax_f.lines[1].get_linestyle() == "--"
    np.testing.assert_allclose(ax_f.lines[0].get_ydata(), res.p_N[:, 0] / np.diff(res.t))
    # the slide then the stop: the modes axis names the modes that occur
    ticks = [t.get_text() for t in ax_m.get_yticklabels()]
    assert {MODE_NAMES[int(c)] for c in np.unique(res.modes)} <= set(ticks)
    assert len(ax_m.lines) == 1


def test_exact_curves_and_names_and_failed_runs_are_shown(jean_pratt):
    scene, res = jean_pratt
    fig = plot_result(res, names=["a", "b"], exact={"t": res.t, "a": scene.exact(res.t)["x"]})
    labels = [l.get_label() for l in fig.axes[0].lines]
    assert labels == ["a", "b", "a exact"]
    with pytest.raises(ValueError, match="names"):
        plot_result(res, names=["only one"])
    # a failed run is drawn as far as it went, with its message in the title
    failed = dataclasses.replace(res, status=-1, message="The one-step contact solver failed.")
    assert "failed: The one-step contact solver failed." in plot_result(failed)._suptitle.get_text()


def test_event_result_plot_uses_the_forces_at_the_output_times():
    scene = lcp.classical.bouncing_ball(e=0.5)
    res = lcp.simulate(scene, method="event", t_eval=np.linspace(0.0, scene.t_end, 101))
    fig = res.plot(scene.system)
    ax_f = fig.axes[2]
    np.testing.assert_array_equal(ax_f.lines[0].get_ydata(), res.force_N[:, 0])
    impacts = [l for l in ax_f.lines if l.get_linestyle() == ":"]
    assert len(impacts) == len(res.impacts) > 3  # one dotted line per impact


def test_animate_draws_each_frame_and_saves_a_gif(tmp_path):
    scene = lcp.classical.box_on_corners()
    res = lcp.simulate(scene, 0.2, h=1e-2)
    gif = tmp_path / "box.gif"
    anim = animate(res, scene, path=gif, every=5)
    assert gif.stat().st_size > 0
    line = anim._fig.axes[0].lines[1]  # lines[0]: the floor
    # the System draws its two contact points (the bottom corners) in the floor's frame
    np.testing.assert_allclose(line.get_xydata(), contact_points(scene)(res.q[-1])[0])  # saved: the last frame
    pts = contact_points(scene.system)(res.q[-1])[0]
    np.testing.assert_allclose(pts[:, 1], 0.0, atol=1e-9)  # both corners on the floor


def test_animate_refuses_what_it_cannot_do(tmp_path):
    scene = lcp.classical.box_on_corners()
    res = lcp.simulate(scene, 0.05, h=1e-2)
    with pytest.raises(ValueError, match="every"):
        animate(res, scene, every=0)
    with pytest.raises(ValueError, match=r"\.gif or \.mp4"):
        animate(res, scene, path=tmp_path / "x.avi")
    with pytest.raises(ValueError, match="shapes"):
        animate(res, 3.0)
    with pytest.raises(ValueError, match="tangent coordinate"):
        contact_points(lcp.classical.pendulum())
