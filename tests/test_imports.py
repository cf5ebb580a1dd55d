"""``import shellobstacle`` changes nothing in the process; every module imports on its own."""

from __future__ import annotations

import json
import os
import pkgutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from mpi4py import MPI

import pytest

import shellobstacle

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="fresh processes, serially")

PACKAGE = Path(shellobstacle.__file__).parent
HEAVY = ("mpi4py", "numpy", "dolfinx", "petsc4py", "ufl", "basix", "sympy")

PROBE = f"""
HEAVY = {HEAVY!r}
import json, os, sys, threading
def tasks():
    return len(os.listdir("/proc/self/task"))
def maps():
    with open("/proc/self/maps") as f:
        return sorted({{l.split()[-1] for l in f if l.rstrip().endswith(".so")}})
environ, before_tasks, before_maps = dict(os.environ), tasks(), maps()
import shellobstacle
print(json.dumps({{
    "loaded": sorted(m for m in sys.modules if m.split(".")[0] in HEAVY),
    "threads": threading.active_count(),
    "tasks": [before_tasks, tasks()],
    "new_libraries": sorted(set(maps()) - set(before_maps)),
    "environ_changed": sorted(k for k in set(environ) | set(os.environ)
                              if environ.get(k) != os.environ.get(k)),
}}))
"""


def test_importing_the_package_changes_nothing_in_the_process() -> None:
    out = subprocess.run(
        [sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=60, check=True
    )
    got = json.loads(out.stdout)
    assert got["loaded"] == []
    assert got["threads"] == 1
    assert got["tasks"][0] == got["tasks"][1]
    assert got["new_libraries"] == []
    assert got["environ_changed"] == []


def _modules() -> list[str]:
    names = ["shellobstacle"]
    for info in pkgutil.walk_packages([str(PACKAGE)], prefix="shellobstacle."):
        names.append(info.name)
    return sorted(names)


def _import_alone(name: str) -> tuple[str, int, str]:
    env = {**os.environ, "SHELLOBSTACLE_TUNING": "off"}
    out = subprocess.run(
        [sys.executable, "-c", f"import {name}"], capture_output=True, text=True, env=env,
        timeout=300,
    )  # fmt: skip
    return name, out.returncode, out.stderr.strip().splitlines()[-1:] and out.stderr[-400:]


def test_every_module_imports_alone_in_a_fresh_interpreter() -> None:
    """Each module loads MPI before DOLFINx and PETSc itself (the wheel needs it first), so
    a script may import any of them first."""
    modules = _modules()
    assert "shellobstacle.solvers.newton" in modules and "shellobstacle.tuning.gemmt" in modules
    with ThreadPoolExecutor(max_workers=4) as pool:
        results = list(pool.map(_import_alone, modules))
    failed = {name: err for name, code, err in results if code != 0}
    assert failed == {}


def test_every_exported_name_resolves() -> None:
    for name in shellobstacle.__all__:
        assert getattr(shellobstacle, name) is not None, name
    with pytest.raises(AttributeError, match="no attribute 'Nonexistent'"):
        _ = shellobstacle.Nonexistent
