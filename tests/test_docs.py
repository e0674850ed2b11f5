"""The repository documents itself: nothing points outside it, and the docs' links resolve."""
from pathlib import Path
import re

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = ("lcp", "lem", "studies", "benchmarks", "docs")
# text that would send a reader to files a clone does not have, or to the project's tracker
OUTSIDE = re.compile(r"shared/|physics\.md|\b[Ii]ssue \d")


def _files():
    yield ROOT / "README.md"
    for folder in FOLDERS:
        for path in (ROOT / folder).rglob("*"):
            if path.suffix in (".py", ".md") and path.name != "test_docs.py":
                yield path


def test_nothing_points_outside_the_repository():
    hits = [f"{p.relative_to(ROOT)}:{i}: {line.strip()}"
            for p in _files() for i, line in enumerate(p.read_text().splitlines(), 1) if OUTSIDE.search(line)]
    assert not hits, "\n".join(hits)


def test_links_between_docs_resolve():
    link = re.compile(r"\]\(([^)#:]+)(?:#[^)]*)?\)")
    missing = []
    for page in [ROOT / "README.md", *(ROOT / "docs").glob("*.md")]:
        for target in link.findall(page.read_text()):
            if not (page.parent / target).exists():
                missing.append(f"{page.relative_to(ROOT)} -> {target}")
    assert not missing, missing
    assert (ROOT / "docs" / "README.md").exists()
