"""``import shellobstacle`` changes nothing in the process; every module imports on its own."""

from __future__ import annotations

import json
import os
import pkgutil
import subprocess
import sys
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


#: Imports each module named in argv[1] (JSON) in a child forked from a process that holds
#: the third-party libraries but no module of the package; prints {name: [code, error]}
FORKED = """
import importlib, json, os, sys, traceback
from mpi4py import MPI
import basix, dolfinx, numpy, petsc4py.PETSc, sympy, ufl
names, running, results = json.loads(sys.argv[1]), {}, {}
def reap():
    pid, status = os.wait()
    name, r = running.pop(pid)
    with os.fdopen(r, "rb") as f:
        results[name] = [os.waitstatus_to_exitcode(status), f.read().decode()[-400:]]
for name in names:
    if len(running) >= int(sys.argv[2]):
        reap()
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.close(r)
        for mine in [m for m in sys.modules if m.partition(".")[0] == "shellobstacle"]:
            del sys.modules[mine]
        try:
            importlib.import_module(name)
        except BaseException:
            os.write(w, traceback.format_exc().encode())
            os._exit(1)
        os._exit(0)
    os.close(w)
    running[pid] = (name, r)
while running:
    reap()
print(json.dumps(results))
"""


def test_every_module_imports_alone() -> None:
    """Each module's own imports are complete and in an order that works when it is the first
    module of the package a script imports (no cycle that only one entry point reveals).

    The third-party libraries are loaded once and each module is imported in a process forked
    from there: the package's modules are what differs between entry points. That MPI comes
    before DOLFINx and PETSc whichever of them a script imports first is the start-up file's
    job, tested in ``test_readme_commands.py``.
    """
    modules = _modules()
    assert (
        "shellobstacle.solvers.newton.solver" in modules and "shellobstacle.cli.doctor" in modules
    )
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    workers = str(max(1, min(4, os.cpu_count() or 1)))
    out = subprocess.run(
        [sys.executable, "-c", FORKED, json.dumps(modules), workers], capture_output=True,
        text=True, env=env, timeout=600, check=True,
    )  # fmt: skip
    results = json.loads(out.stdout)
    assert sorted(results) == modules
    failed = {name: err for name, (code, err) in results.items() if code != 0}
    assert failed == {}


def test_a_module_that_cannot_import_is_reported() -> None:
    """The forked check sees a failing import (and a module that imports fine)."""
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
    names = ["shellobstacle.spec", "shellobstacle.no_such_module"]
    out = subprocess.run(
        [sys.executable, "-c", FORKED, json.dumps(names), "2"], capture_output=True, text=True,
        env=env, timeout=300, check=True,
    )  # fmt: skip
    results = json.loads(out.stdout)
    assert results["shellobstacle.spec"] == [0, ""]
    code, err = results["shellobstacle.no_such_module"]
    assert code == 1 and "ModuleNotFoundError" in err


def test_every_exported_name_resolves() -> None:
    for name in shellobstacle.__all__:
        assert getattr(shellobstacle, name) is not None, name
    with pytest.raises(AttributeError, match="no attribute 'Nonexistent'"):
        _ = shellobstacle.Nonexistent
