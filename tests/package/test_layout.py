"""The package's architecture, read from its imports (no module is imported here).

Three rules hold: a root of at most 12 modules (the rest lives in subpackages by concept), a
numerical library that never imports the application layer (command line, experiments, result
folders, pictures), and no import cycle between modules, counting the imports made inside
functions too.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import shellobstacle

PACKAGE = Path(shellobstacle.__file__).parent

# What runs the library for a user: nothing outside this list may import it.
APPLICATION = (
    "shellobstacle.__main__",
    "shellobstacle.cli",
    "shellobstacle.experiments",
    "shellobstacle.io",
    "shellobstacle.post.pictures",
    "shellobstacle.post.render3d",
    "shellobstacle.post.plotting",
    "shellobstacle.adapt.picture",
)


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports() -> dict[str, set[str]]:
    """Every module of the package with the package's modules it imports (anywhere in it)."""
    paths = {_module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in paths.items():
        targets: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                if not node.module.startswith("shellobstacle"):
                    continue
                for alias in node.names:  # `from pkg import module` names a module
                    full = f"{node.module}.{alias.name}"
                    targets.add(full if full in paths else node.module)
            elif isinstance(node, ast.Import):
                targets |= {a.name for a in node.names if a.name.startswith("shellobstacle.")}
        graph[name] = {t for t in targets if t in paths and t != name}
    return graph


def _in(module: str, layer: tuple[str, ...]) -> bool:
    return any(module == top or module.startswith(top + ".") for top in layer)


def test_the_root_holds_at_most_12_modules() -> None:
    root = sorted(p.name for p in PACKAGE.glob("*.py"))
    assert len(root) <= 12, f"{len(root)} modules at the package root: {root}"


def test_the_library_never_imports_the_application_layer() -> None:
    upward = {
        module: sorted(t for t in targets if _in(t, APPLICATION))
        for module, targets in _imports().items()
        if not _in(module, APPLICATION)
    }
    assert {m: t for m, t in upward.items() if t} == {}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of ``graph`` with more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return cycles


def test_no_import_cycle() -> None:
    cycles = _cycles(_imports())
    # a package's __init__ importing its own modules is no cycle of concepts
    cycles = [c for c in cycles if not all(m.startswith(min(c)) for m in c)]
    assert cycles == []


def _concept(module: str) -> str:
    """The package (``shellobstacle.geometry``) or root module (``shellobstacle.spec``) of
    ``module``."""
    return ".".join(module.split(".")[:2])


def test_no_import_cycle_between_concepts() -> None:
    """The subpackages and root modules form layers: none imports, through any of its
    modules, a concept that imports it back (the theory's checks sit above geometry and the
    obstacle; the penalty's operators on points belong to the solvers)."""
    graph: dict[str, set[str]] = {}
    for module, targets in _imports().items():
        node = graph.setdefault(_concept(module), set())
        node |= {_concept(t) for t in targets} - {_concept(module), "shellobstacle"}
    graph.pop("shellobstacle", None)
    for targets in graph.values():
        targets &= set(graph)
    assert _cycles(graph) == []


@pytest.mark.parametrize(
    "package", ["geometry", "checks", "mesh", "models", "penalty", "config", "cli"]
)
def test_each_concept_is_a_package(package: str) -> None:
    assert (PACKAGE / package / "__init__.py").is_file()
