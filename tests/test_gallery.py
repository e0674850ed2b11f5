"""Every gallery script (docs/gallery/plot_*.py) runs to its end: each asserts its own check
against an exact solution or a reference, so a script that runs is a script whose numbers hold.

The scripts take 2-10 s each (about a minute in all, more on a cold numba/CasADi cache): slow.
The documentation build runs them too (``sphinx-build`` in ``.ci/run``).
"""
from __future__ import annotations

import os
import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
SCRIPTS = sorted((ROOT / "docs" / "gallery").glob("plot_*.py"))


def test_the_gallery_has_its_examples():
    assert len(SCRIPTS) >= 12, [s.name for s in SCRIPTS]
    for script in SCRIPTS:
        text = script.read_text()
        # sphinx-gallery's form: a docstring with a title, and a check that can fail
        assert text.startswith('"""\n') and "\n===" in text.split('"""')[1], script.name
        assert "assert " in text, f"{script.name} checks nothing"


@pytest.mark.slow
@pytest.mark.parametrize("script", SCRIPTS, ids=[s.stem for s in SCRIPTS])
def test_gallery_script_runs_and_its_checks_hold(script, tmp_path):
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-4000:]
