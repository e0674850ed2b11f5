"""The spatial sliding study in quick mode: its numbers against the issue's outcomes."""
import numpy as np
import pytest

from studies import spatial_sliding

# the whole quick run takes 15-50 s; tests/test_studies_pieces.py runs a few of its pieces by default
pytestmark = pytest.mark.slow


def test_spatial_sliding_quick(tmp_path):
    res = spatial_sliding.run(tmp_path, quick=True)
    rows = res["work_precision"]
    assert all(r["success"] for r in rows), [r["message"] for r in rows if not r["success"]]

    def err(scene, method, h=0.0):
        return next(r["error"] for r in rows if r["scene"] == scene and r["method"] == method and r["h"] == h)

    # incline with mu = tan(theta), horizontal launch, up to 2 s: against the closed form and the
    # high-accuracy integration of the reduced equations
    assert err("incline", "event") <= 1e-11
    assert err("incline", "lem") <= 1e-9
    assert res["incline"]["event"] <= 1e-11 and res["incline"]["lem"] <= 1e-9
    assert res["incline"]["closed_form"] <= 1e-12
    assert res["invariant"] <= 1e-13
    # Moreau-Jean (theta = 1/2): first order on the curved paths
    for scene in ("incline", "lateral"):
        e1, e2 = err(scene, "moreau-jean", 1e-2), err(scene, "moreau-jean", 1e-3)
        assert np.log10(e1 / e2) >= 0.99
    # the oblique launch: stop time, exact stick afterwards by every method
    assert res["stop_time_error"] <= 1e-13
    assert all(r["max_speed"] == 0.0 and r["success"] for r in res["no_creep"])
    # the spatial Jean-Pratt block launched along x is the planar scene
    assert all(r["success"] and r["max_difference"] <= 1e-14 for r in res["along_x"])
    # launched obliquely: no lift-off, Moreau-Jean converges to the event method
    ob = res["oblique"]
    assert all(r["success"] and r["max_gap"] <= 1e-14 for r in ob)
    assert ob[1]["error_vs_event"] < ob[0]["error_vs_event"]
    for name in ("paths.png", "paths.csv", "speed_incline.png", "work_precision.png", "work_precision.csv",
                 "no_creep.csv", "jean_pratt_along_x.csv", "jean_pratt_oblique.csv", "incline_reference.csv"):
        assert name in res["files"]
