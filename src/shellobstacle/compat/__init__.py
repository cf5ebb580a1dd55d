"""Workarounds of upstream defects, one module each: the defect, its upstream issue where one
is known, the releases it applies to, and the test that fails without it.

* :mod:`.mpi_first`: the DOLFINx binary wheel (``dolfinx-solver-real``) needs MPI loaded
  before DOLFINx or petsc4py.
* :mod:`.ffcx_cache_lookup`: FFCx 0.11 lists its whole JIT cache folder at every cache hit.
* :mod:`.startup`: the start-up file ``./run setup`` writes, which applies both in a script
  that imports ``dolfinx`` or ``petsc4py`` before this package.
* :mod:`.exit_in_c`: no Python code runs inside a long call into C, and a signal's default
  death reads as a crash to PETSc and ``mpiexec`` (used by the command line's Ctrl-C).

:func:`bootstrap` applies them (the command line, the tests and the benchmarks call it first).
This package imports nothing heavy on import: the start-up file imports it in every process.
"""

from __future__ import annotations

from shellobstacle.compat.ffcx_cache_lookup import locate_jit_modules_by_path
from shellobstacle.compat.mpi_first import NEEDS_MPI, load_mpi_first
from shellobstacle.compat.startup import PTH_LINE, PTH_NAME, install_pth, order_mpi_first

__all__ = [
    "NEEDS_MPI",
    "PTH_LINE",
    "PTH_NAME",
    "bootstrap",
    "install_pth",
    "locate_jit_modules_by_path",
    "order_mpi_first",
]


def bootstrap() -> str:
    """Check the DOLFINx wheel's environment, load MPI and apply the workarounds; returns how
    DOLFINx is installed.

    Raises:
        ImportError: the wheel's own message for an environment that cannot work.
    """
    how = load_mpi_first()
    locate_jit_modules_by_path()
    return how
