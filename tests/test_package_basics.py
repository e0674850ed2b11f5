"""What a package carries beside its code: version, licence, type markers, progress of long studies."""
import importlib.metadata
import re
import tomllib
from pathlib import Path

import pytest

import lcp
import lem

ROOT = Path(__file__).resolve().parents[1]


def test_one_version_for_both_packages_and_the_changelog():
    assert re.fullmatch(r"\d+\.\d+\.\d+", lcp.__version__)
    assert lem.__version__ == lcp.__version__
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert "version" in meta["project"]["dynamic"]
    assert meta["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "lem._version.__version__"}
    assert f"## {lcp.__version__} - " in (ROOT / "CHANGELOG.md").read_text()
    try:  # an installed copy must be this version (the package is also run from a checkout)
        installed = importlib.metadata.version("lcp-lem")
    except importlib.metadata.PackageNotFoundError:
        return
    if Path(importlib.metadata.distribution("lcp-lem").locate_file("lcp")).resolve() == (ROOT / "lcp"):
        assert installed == lcp.__version__


def test_licence_and_type_markers_are_shipped():
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert meta["project"]["license"] == "MIT" and "MIT License" in (ROOT / "LICENSE").read_text()
    data = meta["tool"]["setuptools"]["package-data"]
    for pkg in ("lcp", "lem"):
        assert (ROOT / pkg / "py.typed").exists() and "py.typed" in data[pkg]


def test_tqdm_is_a_dependency_where_progress_is_promised():
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert any(d.startswith("tqdm") for d in meta["project"]["dependencies"])


def test_a_long_serial_sweep_prints_its_estimate_first(monkeypatch, capsys):
    from studies import _cluster

    monkeypatch.setattr(_cluster, "ESTIMATE_FROM", 0.0)
    assert _cluster.pieces(abs, [-1, 2, -3], None, desc="demo") == [1, 2, 3]
    err = capsys.readouterr().err
    assert re.search(r"demo: 3 pieces, about \d+ s in all", err), err
    monkeypatch.setattr(_cluster, "ESTIMATE_FROM", float("inf"))
    assert _cluster.pieces(abs, [-4], None, desc="short") == [4]
    assert _cluster.pieces(abs, [], None) == []
    assert "about" not in capsys.readouterr().err


@pytest.mark.parametrize("seconds, text", [(5.2, "5 s"), (119.4, "119 s"), (600.0, "10 min"), (9000.0, "2.5 h")])
def test_durations_are_said_in_a_readable_unit(seconds, text):
    from studies._cluster import _duration

    assert _duration(seconds) == text
