"""The package's shape, checked from its source: layers, cycles, private names, room sizes.

The import graph comes from ``docs/import_graph.py`` (the same code draws docs/architecture.png),
so the figure and this test cannot disagree.
"""
from __future__ import annotations

import ast
import importlib.util
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("import_graph", ROOT / "docs" / "import_graph.py")
graph = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(graph)

MAX_MODULE_LINES = 800
MAX_CLASS_LINES = 300
MAX_TOP_LEVEL_MODULES = 8


@pytest.fixture(scope="module")
def mods():
    return graph.modules()


def test_every_module_has_a_layer(mods):
    for m in mods:
        graph.layer(m)  # raises KeyError naming the module


def test_no_import_cycles(mods):
    assert graph.cycles(graph.edges(mods)) == []


def test_imports_go_downward_only(mods):
    assert graph.upward(mods) == []


def test_no_private_names_across_modules(mods):
    assert graph.private_names(mods) == []


def test_the_top_level_holds_few_modules():
    top = sorted(p.name for p in (ROOT / "lcp").glob("*.py"))
    assert len(top) <= MAX_TOP_LEVEL_MODULES, top


def test_every_subpackage_module_opens_with_a_docstring(mods):
    missing = [m for m, p in mods.items() if ast.get_docstring(ast.parse(p.read_text())) is None]
    assert missing == []


def test_rooms_fit_in_ones_head(mods):
    big_modules = []
    big_classes = []
    for m, p in mods.items():
        text = p.read_text()
        n = text.count("\n")
        if n > MAX_MODULE_LINES:
            big_modules.append((m, n))
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ClassDef):
                size = node.end_lineno - node.lineno + 1
                if size > MAX_CLASS_LINES:
                    big_classes.append((f"{m}.{node.name}", size))
    assert big_modules == [] and big_classes == [], (big_modules, big_classes)


def test_the_checks_catch_what_they_claim(tmp_path):
    # a two-module package with a cycle, an upward import and a private name: each is found
    pkg = tmp_path / "lcp"
    (pkg / "model").mkdir(parents=True)
    (pkg / "contact").mkdir()
    (pkg / "__init__.py").write_text('"""top"""\n')
    (pkg / "model" / "__init__.py").write_text('"""m"""\n')
    (pkg / "contact" / "__init__.py").write_text('"""c"""\n')
    (pkg / "model" / "a.py").write_text('"""a"""\nfrom lcp.model.b import _hidden\nfrom lcp.simulation import x\n')
    (pkg / "model" / "b.py").write_text('"""b"""\ndef f():\n    from lcp.model import a\n')
    (pkg / "simulation.py").write_text('"""s"""\nx = 1\n')
    old_root = graph.ROOT
    try:
        graph.ROOT = tmp_path
        mods = {graph.module_name(p): p for p in sorted(pkg.rglob("*.py"))}
        assert graph.cycles(graph.edges(mods)) == [["lcp.model.a", "lcp.model.b"]]
        assert any("imports lcp.simulation" in u for u in graph.upward(mods))
        assert graph.private_names(mods) == ["lcp.model.a:2 imports _hidden from lcp.model.b"]
    finally:
        graph.ROOT = old_root
