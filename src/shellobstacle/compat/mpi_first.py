"""The DOLFINx binary wheel needs MPI loaded before DOLFINx, petsc4py or slepc4py.

Upstream: the wheel ``dolfinx-solver-real`` (github.com/benvial/dolfinx-solver) links its
compiled modules to the ``libmpi.so.12`` that ``mpi4py.MPI`` loads, and its README makes the
import order a requirement: ``import dolfinx_solver`` first, which loads ``mpi4py.MPI`` (and
refuses a broken environment, a foreign petsc4py or both scalar variants installed, with a
message that says what to uninstall). No upstream issue asks for another behaviour, and no
release changes it: this applies wherever the wheel is installed (0.11.0.post0 today).
``import dolfinx`` first fails with ``libmpi.so.12: cannot open shared object file``
(``tests/cli/test_readme_commands.py`` checks that it still does, and that the start-up file of
:mod:`.startup` makes it work). Other DOLFINx installs (conda-forge, Docker, source builds)
have no such package and need nothing.
"""

from __future__ import annotations

__all__ = ["NEEDS_MPI", "load_mpi_first"]

#: Top-level modules whose compiled parts link the wheel's MPI library.
NEEDS_MPI = ("dolfinx", "petsc4py", "slepc4py")


def load_mpi_first() -> str:
    """Load MPI as the DOLFINx wheel requires (any install: ``mpi4py.MPI``); returns how
    DOLFINx is installed.

    Raises:
        ImportError: the wheel's own message for an environment that cannot work.
    """
    try:
        import dolfinx_solver
    except ModuleNotFoundError:
        from mpi4py import MPI  # noqa: F401  (what the wheel's bootstrap would load)

        return "not from the dolfinx-solver wheel (conda-forge, Docker or a source build)"
    name = dolfinx_solver.__name__.replace("_", "-")
    return f"the {name} wheel {dolfinx_solver.__version__}"
