"""The DOLFINx binary wheel's bootstrap: MPI loaded before DOLFINx, in any import order.

The wheel ``dolfinx-solver-real`` needs ``mpi4py.MPI`` loaded before its compiled modules:
``import dolfinx_solver`` does that (and refuses a broken environment, a foreign petsc4py or
both scalar variants installed, with a message that says what to uninstall). The package's
modules import ``mpi4py`` first, as DOLFINx's own demos do, and the command line calls
:func:`bootstrap` before anything else.

A user's script that imports ``dolfinx`` or ``petsc4py`` *first* would fail with
``libmpi.so.12: cannot open shared object file``. ``./run setup`` therefore writes
:data:`PTH_NAME` into the virtual environment (:func:`install_pth`): at start-up it puts a
finder on ``sys.meta_path`` (:func:`order_mpi_first`) that imports ``dolfinx_solver`` just
before the first of :data:`NEEDS_MPI` and then removes itself; nothing is imported at
start-up but this module. Other DOLFINx installs (conda-forge, Docker, source builds) have no
such package and need nothing.
"""

from __future__ import annotations

import contextlib
import importlib.abc
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the start-up file imports this module: nothing more than it needs
    from pathlib import Path

__all__ = ["NEEDS_MPI", "PTH_LINE", "PTH_NAME", "bootstrap", "install_pth", "order_mpi_first"]

#: Top-level modules whose compiled parts link the wheel's MPI library.
NEEDS_MPI = ("dolfinx", "petsc4py", "slepc4py")
#: The start-up file ``./run setup`` writes into the environment's site-packages.
PTH_NAME = "shellobstacle-mpi-first.pth"
#: Its one line (a ``.pth`` runs lines that start with ``import``); silent without the package.
PTH_LINE = (
    'import sys; exec("try:\\n from shellobstacle.compat import order_mpi_first\\n'
    'except ImportError:\\n pass\\nelse:\\n order_mpi_first()")'
)


def bootstrap() -> str:
    """Check the DOLFINx wheel's environment and load MPI; returns how DOLFINx is installed.

    Raises:
        ImportError: the wheel's own message for an environment that cannot work.
    """
    try:
        import dolfinx_solver
    except ModuleNotFoundError:
        from mpi4py import MPI  # noqa: F401  (what the wheel's bootstrap would load)

        return "not from the dolfinx-solver wheel (conda-forge, Docker or a source build)"
    return f"the {dolfinx_solver.__name__.replace('_', '-')} wheel {dolfinx_solver.__version__}"


class _MPIFirst(importlib.abc.MetaPathFinder):
    """Imports the wheel's bootstrap before the first of :data:`NEEDS_MPI`, once."""

    def find_spec(self, name: str, path: object = None, target: object = None) -> None:
        if name in NEEDS_MPI:
            sys.meta_path.remove(self)  # before the bootstrap, which imports them itself
            with contextlib.suppress(ModuleNotFoundError):  # not the wheel: nothing to order
                import dolfinx_solver  # noqa: F401
        return None  # the module itself is found by the usual finders


def order_mpi_first() -> None:
    """Put the finder of the module docstring on ``sys.meta_path`` (once per process)."""
    if "dolfinx_solver" not in sys.modules and not any(
        isinstance(f, _MPIFirst) for f in sys.meta_path
    ):
        sys.meta_path.insert(0, _MPIFirst())


def install_pth(site_packages: str | Path | None = None) -> Path:
    """Write :data:`PTH_NAME` into ``site_packages`` (default: this environment's) unless it
    holds :data:`PTH_LINE` already; returns its path."""
    import sysconfig
    from pathlib import Path

    folder = Path(site_packages or sysconfig.get_paths()["purelib"])
    path = folder / PTH_NAME
    text = PTH_LINE + "\n"
    if not path.is_file() or path.read_text() != text:
        path.write_text(text)
    return path
