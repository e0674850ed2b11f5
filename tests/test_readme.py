"""The README is tested: its Python blocks run as written, and the numbers it states are recomputed."""
from pathlib import Path
import os
import re
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import lcp

README = Path(__file__).resolve().parents[1] / "README.md"


def python_blocks(text: str) -> list[str]:
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def _guarded(block: str) -> bool:
    """A script of its own (``if __name__ == "__main__":``): it starts worker processes, which
    import the script again, so it cannot share one with the other blocks."""
    return block.lstrip().startswith('if __name__ == "__main__":')


def _run_script(tmp_path, name, script):
    (tmp_path / name).write_text(script)
    env = dict(os.environ, MPLBACKEND="Agg")
    out = subprocess.run([sys.executable, name], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, textwrap.shorten(out.stderr[-3000:], 3000)


def test_readme_python_blocks_run_in_order_in_one_fresh_interpreter(tmp_path):
    blocks = [b for b in python_blocks(README.read_text()) if not _guarded(b)]
    assert len(blocks) >= 3
    script = "\n".join(f"# --- README block {i}\n{b}" for i, b in enumerate(blocks, 1))
    _run_script(tmp_path, "readme_blocks.py", script)


def test_readme_cluster_blocks_run_as_scripts_of_their_own(tmp_path):
    pytest.importorskip("dask.distributed")
    blocks = [b for b in python_blocks(README.read_text()) if _guarded(b)]
    assert blocks, "the README lost its cluster example"
    for i, b in enumerate(blocks):
        _run_script(tmp_path, f"readme_cluster_{i}.py", b)


def _readme_error_table():
    """Rows of the README's Moreau-Jean table: h -> (max|x - exact|, B h^2/8)."""
    rows = {}
    for line in README.read_text().splitlines():
        m = re.match(r"\|\s*(1e-\d)\s*\|\s*([0-9.e+-]+)\s*\|\s*([0-9.e+-]+)\s*\|", line)
        if m:
            rows[float(m.group(1))] = (float(m.group(2)), float(m.group(3)))
    return rows


@pytest.mark.parametrize("h", [1e-2, 1e-3])
def test_readme_error_table_is_what_the_package_computes(h):
    rows = _readme_error_table()
    assert h in rows, "the README's Moreau-Jean error table lost its row"
    stated_err, stated_bound = rows[h]
    scene = lcp.scenes.jean_pratt()
    res = lcp.simulate(scene, 0.3, h=h)
    err = float(np.max(np.abs(res.q[:, 0] - scene.exact(res.t)["x"])))
    assert err == pytest.approx(stated_err, rel=5e-3)  # stated to three digits
    assert scene.B * h * h / 8 == pytest.approx(stated_bound, rel=5e-3)


def test_readme_per_step_timings_are_the_recorded_run():
    import csv
    rec = {r["path"]: float(r["us_per_step"]) for r in
           csv.DictReader(open(README.parent / "benchmarks" / "recorded" / "per_step.csv"))}
    text = README.read_text()
    stated = {"compiled (auto, fast=True)": r"compiled exact path costs ([0-9.]+) µs",
              "osqp (general path)": r"general OSQP path\s+costs ([0-9.]+) µs"}
    for path, pattern in stated.items():
        m = re.search(pattern, text)
        assert m, pattern
        assert float(m.group(1)) == pytest.approx(rec[path], rel=0.02), path
