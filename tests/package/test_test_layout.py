"""The tests' own layout, read from their files (none is imported here): test files sit in a
folder by concept, never at tests/ itself; a test module never imports another test module
(shared helpers live in conftest.py or a helper module that is not a ``test_*.py``); no two
test files share a name (without ``__init__.py`` files pytest imports each by its name).
"""

from __future__ import annotations

import ast
from collections import Counter
from pathlib import Path

TESTS = Path(__file__).parents[1]


def _test_files() -> list[Path]:
    return sorted(TESTS.rglob("test_*.py"))


def _imported_modules(path: Path) -> set[str]:
    """Every module ``path`` imports, anywhere in it (``a.b`` for ``from a.b import c``, and
    ``a.b.c`` too, which may name a module)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
            names |= {f"{node.module}.{alias.name}" for alias in node.names}
    return names


def _test_module_imports(path: Path) -> list[str]:
    """The test modules ``path`` imports, by module name (``test_newton``) or by path
    (``tests.solvers.test_newton``)."""
    return sorted(
        name
        for name in _imported_modules(path)
        if name.split(".")[-1].startswith("test_")
        and (name.count(".") == 0 or name.startswith("tests."))
    )


def test_no_test_module_imports_another() -> None:
    imports = {str(p.relative_to(TESTS)): _test_module_imports(p) for p in _test_files()}
    assert {path: names for path, names in imports.items() if names} == {}


def test_no_test_file_at_the_root_of_tests() -> None:
    assert sorted(p.name for p in TESTS.glob("test_*.py")) == []


def test_test_file_names_are_unique() -> None:
    counts = Counter(p.name for p in _test_files())
    assert sorted(name for name, n in counts.items() if n > 1) == []


def test_the_check_finds_an_import_of_a_test_module(tmp_path: Path) -> None:
    """Each form of the import is found: by name, by path, inside a function; a helper
    module's and a library's are not."""
    path = tmp_path / "test_example.py"
    path.write_text(
        "from test_newton import square\n"
        "import tests.solvers.test_active_set\n"
        "from conftest import ball\n"
        "from cli_helpers import run\n"
        "from shellobstacle.testing import x\n"
        "def f():\n"
        "    from test_multigrid import ladder\n"
    )
    assert _test_module_imports(path) == [
        "test_multigrid",
        "test_newton",
        "tests.solvers.test_active_set",
    ]
