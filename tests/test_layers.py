"""The package's import graph has no circles: data flows one way through the modules.

The graph is read from the source (every ``import`` and ``from ... import``, including those
inside functions and under ``TYPE_CHECKING``: an import deferred for speed is still a
dependency). The package's ``__init__`` is the public surface and may import anything.
"""

from __future__ import annotations

import ast
from pathlib import Path

import vtm_pin

PACKAGE = Path(vtm_pin.__file__).parent


def import_graph(root: Path, package: str) -> dict[str, set[str]]:
    """Module -> the package's modules it imports (``__init__`` files left out)."""
    modules = {
        ".".join((package, *path.relative_to(root).with_suffix("").parts)): path
        for path in root.rglob("*.py")
        if path.name != "__init__.py"
    }
    packages = {
        ".".join((package, *path.parent.relative_to(root).parts)) for path in root.rglob("*.py")
    }
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        here = name.rsplit(".", 1)[0]
        found: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                found.update(alias.name for alias in node.names)
            elif isinstance(node, ast.ImportFrom):
                base = _absolute(node, here)
                found.add(base)
                found.update(f"{base}.{alias.name}" for alias in node.names)
        graph[name] = {m for m in found if m in modules and m != name}
        graph[name] |= {m for m in found if m in packages and m != package} - {here}
    return graph


def _absolute(node: ast.ImportFrom, here: str) -> str:
    if not node.level:
        return node.module or ""
    parts = here.split(".")
    base = ".".join(parts[: len(parts) - node.level + 1])
    return f"{base}.{node.module}" if node.module else base


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import circles: strongly connected groups of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for other in sorted(graph.get(node, ())):
            if other not in index:
                visit(other)
                low[node] = min(low[node], low[other])
            elif other in stack:
                low[node] = min(low[node], index[other])
        if low[node] == index[node]:
            group = []
            while True:
                member = stack.pop()
                group.append(member)
                if member == node:
                    break
            if len(group) > 1:
                found.append(sorted(group))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_the_package_has_no_import_circles() -> None:
    graph = import_graph(PACKAGE, "vtm_pin")
    assert len(graph) > 40  # the walk found the modules
    assert circles(graph) == []


def test_a_circle_is_found(tmp_path: Path) -> None:
    """The check fails on a deliberate circle, through a deferred import in a subpackage."""
    root = tmp_path / "pkg"
    (root / "sub").mkdir(parents=True)
    (root / "__init__.py").write_text("")
    (root / "sub" / "__init__.py").write_text("")
    (root / "low.py").write_text("def f():\n    from .sub.high import g\n")
    (root / "sub" / "high.py").write_text("from ..low import f\n")
    (root / "alone.py").write_text("import os\n")
    graph = import_graph(root, "pkg")
    assert graph["pkg.low"] == {"pkg.sub.high"} and graph["pkg.sub.high"] == {"pkg.low"}
    assert circles(graph) == [["pkg.low", "pkg.sub.high"]]
