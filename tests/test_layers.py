"""The package's layers: data flows one way, and its import graph has no circles.

The layers are an import-linter contract in ``pyproject.toml`` (``[tool.importlinter]``):
files and schemas, numerics and standards, physics, core, scene, outputs, study and
calibration, then the CLI. A module may import its own layer and those below it.

The graph is read from the source (every ``import`` and ``from ... import``, including those
inside functions and under ``TYPE_CHECKING``: an import deferred for speed is still a
dependency). The package's ``__init__`` is the public surface and may import anything.
"""

from __future__ import annotations

import ast
import importlib
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import vtm_pin

PACKAGE = Path(vtm_pin.__file__).parent
PROJECT = PACKAGE.parent
#: The subpackages, bottom layer first, as the contract lists them.
SUBPACKAGES = (
    "files",
    "numerics",
    "standards",
    "physics",
    "core",
    "scene",
    "outputs",
    "study",
    "calibration",
)


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


def lint_imports(package_parent: Path, tmp_path: Path) -> subprocess.CompletedProcess[str]:
    """Run the project's import-linter contract on the package found in ``package_parent``."""
    pytest.importorskip("importlinter", reason="import-linter is in the test and dev extras")
    shutil.copy(PROJECT / "pyproject.toml", tmp_path / "contract.toml")
    code = (
        "import sys; from importlinter.cli import lint_imports; "
        f"sys.exit(lint_imports(config_filename={str(tmp_path / 'contract.toml')!r}, "
        "no_cache=True, no_logo=True))"
    )
    return subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={"PYTHONPATH": str(package_parent), "PATH": "/usr/bin:/bin"},
        timeout=120,  # grimp builds the graph of 70 modules in well under a second
    )


def test_no_module_imports_from_a_layer_above(tmp_path: Path) -> None:
    result = lint_imports(PROJECT, tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "1 kept, 0 broken" in result.stdout


def test_an_upward_import_breaks_the_contract(tmp_path: Path) -> None:
    """A friction law (physics) that imports the study runner (a layer above) is refused."""
    copy = tmp_path / "src"
    shutil.copytree(PACKAGE, copy / "vtm_pin", ignore=shutil.ignore_patterns("__pycache__"))
    friction = copy / "vtm_pin" / "physics" / "friction.py"
    friction.write_text(
        friction.read_text() + "\n\ndef _upward():\n    from ..study import runner\n"
    )
    result = lint_imports(copy, tmp_path)
    assert result.returncode == 1, result.stdout + result.stderr
    assert "BROKEN" in result.stdout
    assert "vtm_pin.physics.friction -> vtm_pin.study.runner" in result.stdout


def test_each_subpackage_says_what_it_owns_and_may_import() -> None:
    for name in SUBPACKAGES:
        doc = importlib.import_module(f"vtm_pin.{name}").__doc__ or ""
        assert doc.splitlines()[0].endswith("."), name
        assert "May import:" in doc, name
    assert sorted(p.parent.name for p in PACKAGE.glob("*/__init__.py")) == sorted(
        (*SUBPACKAGES, "schemas")
    )
