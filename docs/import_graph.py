"""The import graph of the ``lcp`` package, its layers, and the architecture figure.

Run ``python docs/import_graph.py`` from the repository's root to redraw
``docs/architecture.png`` from the source (the layers and the imports between subpackages);
``tests/test_architecture.py`` checks the same graph: no cycles, imports downward only, no private
names across modules, rooms of a readable size.

Every ``import`` and ``from ... import`` of an ``lcp`` module counts, at module level or inside a
function (a deferred import is still a dependency).
"""
from __future__ import annotations

import ast
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "lcp"

#: the layers, bottom to top: a module may import its own unit and the units of lower layers
LAYERS: list[tuple[str, ...]] = [
    ("lcp.numerics",),
    ("lcp.model", "lcp.contact", "lcp.plotting"),
    ("lcp.io", "lcp.result"),
    ("lcp.timestepping",),
    ("lcp.events",),
    ("lcp.scenes",),
    ("lcp.simulation",),
    ("lcp.sweeps", "lcp.ocp"),
    ("lcp.fclib", "lcp.batch", "lcp.classical", "lcp"),
]

#: private names that are part of Python's protocols, not of a module's internals
DUNDER_OK = ("__all__", "__version__", "__doc__")


def module_name(path: pathlib.Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def modules() -> dict[str, pathlib.Path]:
    """Every module of the package, by dotted name."""
    return {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def unit(mod: str) -> str:
    """The unit a module belongs to: its subpackage (lcp.X) or the top-level module itself."""
    parts = mod.split(".")
    if len(parts) == 1:
        return "lcp"
    return ".".join(parts[:2])


def layer(mod: str) -> int:
    u = unit(mod)
    for i, units in enumerate(LAYERS):
        if u in units:
            return i
    raise KeyError(f"{mod}: its unit {u} has no layer in docs/import_graph.py")


def _resolve(mod: str, is_pkg: bool, node: ast.ImportFrom) -> str:
    if node.level == 0:
        return node.module or ""
    base = mod.split(".")
    if not is_pkg:
        base = base[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def imports(mods: dict[str, pathlib.Path] | None = None):
    """(importer, imported module, imported name or None, line) for every import of an lcp module."""
    mods = modules() if mods is None else mods
    out = []
    for mod, path in mods.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        is_pkg = path.name == "__init__.py"
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                for a in node.names:
                    if a.name == "lcp" or a.name.startswith("lcp."):
                        out.append((mod, a.name, None, node.lineno))
            elif isinstance(node, ast.ImportFrom):
                target = _resolve(mod, is_pkg, node)
                if not (target == "lcp" or target.startswith("lcp.")):
                    continue
                for a in node.names:
                    sub = f"{target}.{a.name}"
                    if sub in mods:  # a submodule imported by name
                        out.append((mod, sub, None, node.lineno))
                    else:
                        out.append((mod, target, a.name, node.lineno))
    return out


def edges(mods=None) -> set[tuple[str, str]]:
    return {(a, b) for a, b, _, _ in imports(mods) if a != b}


def cycles(graph: set[tuple[str, str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    adj: dict[str, list[str]] = {}
    for a, b in graph:
        adj.setdefault(a, []).append(b)
        adj.setdefault(b, [])
    index, low, stack, on, out = {}, {}, [], set(), []
    sys.setrecursionlimit(10000)

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in adj[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(adj):
        if v not in index:
            visit(v)
    return out


def upward(mods=None) -> list[str]:
    """Imports from a higher layer, or between two units of one layer."""
    bad = []
    for a, b, _, line in imports(mods):
        ua, ub = unit(a), unit(b)
        if ua == ub or b == "lcp" and a.startswith("lcp."):
            if b == "lcp" and ua != "lcp":
                bad.append(f"{a}:{line} imports the package's top level")
            continue
        la, lb = layer(a), layer(b)
        if lb > la or (lb == la and ua != ub):
            bad.append(f"{a}:{line} ({ua}, layer {la}) imports {b} ({ub}, layer {lb})")
    return bad


def private_names(mods=None) -> list[str]:
    """Names with a leading underscore imported from another module."""
    return [f"{a}:{line} imports {name} from {b}" for a, b, name, line in imports(mods)
            if name is not None and name.startswith("_") and name not in DUNDER_OK and a != b]


def unit_graph(mods=None) -> set[tuple[str, str]]:
    return {(unit(a), unit(b)) for a, b in edges(mods) if unit(a) != unit(b)}


def transitive_reduction(graph: set[tuple[str, str]]) -> set[tuple[str, str]]:
    """The edges of an acyclic graph that no longer path implies (the arrows worth drawing)."""
    adj: dict[str, set[str]] = {}
    for a, b in graph:
        adj.setdefault(a, set()).add(b)

    def reachable(start, skip):
        seen, todo = set(), [w for w in adj.get(start, ()) if (start, w) != skip]
        while todo:
            w = todo.pop()
            if w not in seen:
                seen.add(w)
                todo.extend(adj.get(w, ()))
        return seen

    return {(a, b) for a, b in graph if b not in reachable(a, (a, b))}


def draw(path: pathlib.Path = ROOT / "docs" / "architecture.png") -> pathlib.Path:
    """Draw the units in their layers, with an arrow for each import between units that no chain
    of other imports already implies (the transitive reduction of the graph)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mods = modules()
    counts: dict[str, int] = {}
    for m in mods:
        counts[unit(m)] = counts.get(unit(m), 0) + 1
    pos = {}
    for i, units in enumerate(LAYERS):
        for j, u in enumerate(units):
            pos[u] = ((j - (len(units) - 1) / 2) * 3.2, i * 1.25)
    fig, ax = plt.subplots(figsize=(10, 10), dpi=150)
    for a, b in sorted(transitive_reduction(unit_graph(mods))):
        (xa, ya), (xb, yb) = pos[a], pos[b]
        ax.annotate("", xy=(xb, yb + 0.22), xytext=(xa, ya - 0.22),
                    arrowprops=dict(arrowstyle="-|>", color="0.55", lw=0.8, shrinkA=2, shrinkB=2,
                                    connectionstyle="arc3,rad=0.08"))
    for u, (x, y) in pos.items():
        label = u if u != "lcp" else "lcp (__init__)"
        n = counts.get(u, 0)
        ax.text(x, y, f"{label}\n{n} module{'s' if n != 1 else ''}", ha="center", va="center", fontsize=9,
                bbox=dict(boxstyle="round,pad=0.35", fc="#eef3fb", ec="#3b6db3"))
    for i in range(len(LAYERS)):
        ax.text(-7.2, i * 1.25, f"layer {i}", ha="left", va="center", fontsize=8, color="0.4")
    ax.set_xlim(-7.5, 6.5)
    ax.set_ylim(-0.8, (len(LAYERS) - 1) * 1.25 + 0.8)
    ax.axis("off")
    ax.set_title("lcp: subpackages by layer\n(arrow: imports; an import implied by a chain of arrows is not drawn)", fontsize=11)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


if __name__ == "__main__":
    mods = modules()
    problems = (["cycle: " + " <-> ".join(c) for c in cycles(edges(mods))] + upward(mods)
                + private_names(mods))
    print("\n".join(problems) if problems else "no cycles, no upward imports, no private names")
    print(f"wrote {draw()}")
