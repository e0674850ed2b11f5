"""Sphinx configuration of the documentation site.

Build from the repository's root (warnings are errors, as in CI)::

    pip install ".[docs]"
    sphinx-build -W --keep-going -b html docs docs/_build/html

The API reference comes from the NumPy-style docstrings (napoleon), the pages are the Markdown files
of this folder (myst-parser), and the gallery is built from ``docs/gallery/plot_*.py``
(sphinx-gallery). ``-D sphinx_gallery_conf.plot_gallery=0`` builds the site without running the
gallery's scripts (they are run by ``tests/test_gallery.py``).
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the packages are documented from this checkout, installed or not
os.environ.setdefault("MPLBACKEND", "Agg")

from lem._version import __version__  # noqa: E402

project = "lcp-lem"
author = "lcp-lem contributors"
copyright = "lcp-lem contributors, MIT licence"
release = version = __version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "myst_parser",
    "sphinx_gallery.gen_gallery",
]

root_doc = "index"
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "gallery/README.rst", "auto_examples/*.ipynb", "auto_examples/*.py",
                    "auto_examples/*.zip", "auto_examples/*.md5", "auto_examples/*.json"]

# --- API reference: NumPy-style docstrings ---------------------------------------------------------
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False
napoleon_use_ivar = True
autosummary_generate = True
autosummary_imported_members = False
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_typehints_format = "short"
autodoc_mock_imports = ["mujoco", "nosnoc"]

templates_path = ["_templates"]
nitpicky = False

# --- Markdown pages -----------------------------------------------------------------------------------
myst_enable_extensions = ["dollarmath", "amsmath"]
myst_heading_anchors = 3

# --- gallery ------------------------------------------------------------------------------------------
sphinx_gallery_conf = {
    "examples_dirs": "gallery",
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "within_subsection_order": "FileNameSortKey",
    "download_all_examples": False,
    "remove_config_comments": True,
    "abort_on_example_error": True,
    "matplotlib_animations": False,
}

html_theme = "alabaster"
html_title = f"lcp-lem {release}"
html_static_path: list[str] = []


# --- plain-text formulas in docstrings -------------------------------------------------------------
# The docstrings write absolute values and norms as |x| and ||r||, as plain text; reStructuredText
# would read |x| as a substitution. The package defines no substitutions, so a bar outside inline
# literals, roles, literal blocks and doctests is a bar: escape it.
import re  # noqa: E402

_LITERAL = re.compile(r"(``.+?``|:[\w:]+:`[^`]+`|`[^`]+`_?)")


def _escape_bars(line: str) -> str:
    parts = _LITERAL.split(line)
    return "".join(p if i % 2 else p.replace("|", r"\|") for i, p in enumerate(parts))


def escape_bars(app, what, name, obj, options, lines):
    literal_indent = None  # indentation of the paragraph that opened a literal block with '::'
    for i, line in enumerate(lines):
        stripped = line.lstrip()
        indent = len(line) - len(stripped)
        if literal_indent is not None:
            if not stripped or indent > literal_indent:
                continue
            literal_indent = None
        if stripped.startswith((">>>", "...")) or "|" not in line:
            pass
        else:
            lines[i] = _escape_bars(line)
        if stripped.endswith("::"):
            literal_indent = indent


# A type such as "ndarray, shape (N, m)" names the array's shape with the symbols of the text, not
# with Python objects: Sphinx would look each word up (N, m, k, ...) as a cross-reference and find
# the attributes of that name on other classes. The shape is written as a literal instead.
_TYPE_FIELD = re.compile(r"^(\s*:(?:vartype|type|rtype)(?: [^:]+)?: )(.*\bshape\b.*)$")


def literal_shapes(app, what, name, obj, options, lines):
    for i, line in enumerate(lines):
        m = _TYPE_FIELD.match(line)
        if m and "`" not in m.group(2):
            lines[i] = m.group(1) + "``" + m.group(2) + "``"


def setup(app):
    app.connect("autodoc-process-docstring", escape_bars)
    app.connect("autodoc-process-docstring", literal_shapes)
    app.connect("builder-inited", _draw_architecture)


def _draw_architecture(app):
    """Redraw docs/architecture.png from the import graph of this checkout, so the page that
    shows it can never show an older layout (docs/import_graph.py)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("import_graph", Path(__file__).parent / "import_graph.py")
    graph = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(graph)
    graph.draw()
