"""The upstream defects that :mod:`shellobstacle.compat` works around are still there, and each
workaround applies only to the releases it names: when one of these fails, upstream has fixed
the defect and its module can go. (That the workarounds work: ``test_readme_commands.py`` for
the start-up file, ``test_jit_cache.py`` for FFCx's lookup.)"""

from __future__ import annotations

import subprocess
import sys
import sysconfig
from pathlib import Path

from mpi4py import MPI

import pytest

import shellobstacle
from shellobstacle.compat import NEEDS_MPI, locate_jit_modules_by_path

pytestmark = pytest.mark.skipif(MPI.COMM_WORLD.size > 1, reason="fresh processes, serially")


def wheel_installed() -> bool:
    import importlib.util

    return importlib.util.find_spec("dolfinx_solver") is not None


@pytest.mark.skipif(not wheel_installed(), reason="not the DOLFINx wheel: nothing to order")
@pytest.mark.skipif(sys.prefix == sys.base_prefix, reason="not in a virtual environment")
@pytest.mark.parametrize("first", ["dolfinx", "petsc4py"])
def test_the_wheel_still_needs_mpi_first(tmp_path: Path, first: str) -> None:
    """Without the start-up file (``-S``: no ``.pth`` runs), importing ``first`` before
    ``mpi4py`` fails as the wheel's README says it does."""
    assert first in NEEDS_MPI
    paths = [str(Path(shellobstacle.__file__).parents[1]), sysconfig.get_paths()["purelib"]]
    code = (
        f"import sys; sys.path[:0] = {paths!r}; sys.prefix = sys.exec_prefix = {sys.prefix!r}; "
        f"import {first}.{'PETSc' if first == 'petsc4py' else 'mesh'}"
    )
    done = subprocess.run(
        [sys.executable, "-S", "-c", code],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode != 0
    assert "libmpi.so.12: cannot open shared object file" in done.stderr


def test_ffcx_s_own_lookup_is_the_one_fixed_upstream() -> None:
    """FFCx 0.11's ``get_cached_module`` lists the folder (an ``importlib`` ``FileFinder``),
    as FFCx issue #886 says; the replacement keeps it at hand."""
    import inspect

    import ffcx.codegeneration.jit as jit

    assert locate_jit_modules_by_path()
    assert "FileFinder" in inspect.getsource(jit.get_cached_module.ffcx)


def test_the_ffcx_lookup_is_left_alone_in_other_releases(monkeypatch) -> None:
    import ffcx
    import ffcx.codegeneration.jit as jit

    assert locate_jit_modules_by_path()  # (FFCx 0.11: replaced, by the bootstrap already)
    own = jit.get_cached_module.ffcx
    monkeypatch.setattr(jit, "get_cached_module", own)
    monkeypatch.setattr(ffcx, "__version__", "0.12.0")
    assert not locate_jit_modules_by_path()
    assert jit.get_cached_module is own
