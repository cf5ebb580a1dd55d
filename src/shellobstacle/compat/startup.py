"""The start-up file ``./run setup`` writes: the workarounds applied in a user's script that
imports ``dolfinx`` or ``petsc4py`` before this package.

:func:`install_pth` writes :data:`PTH_NAME` into the virtual environment. At start-up it puts
a finder on ``sys.meta_path`` (:func:`order_mpi_first`) that, just before the first of
:data:`~.mpi_first.NEEDS_MPI` is imported, loads MPI as the DOLFINx wheel requires
(:mod:`.mpi_first`) and, for ``dolfinx``, lets FFCx find cached forms by file name
(:mod:`.ffcx_cache_lookup`), then removes itself; nothing is imported at start-up but this
package.
"""

from __future__ import annotations

import contextlib
import importlib.abc
import sys
from typing import TYPE_CHECKING

from shellobstacle.compat.mpi_first import NEEDS_MPI

if TYPE_CHECKING:  # the start-up file imports this module: nothing more than it needs
    from pathlib import Path

__all__ = ["PTH_LINE", "PTH_NAME", "install_pth", "order_mpi_first"]

#: The start-up file ``./run setup`` writes into the environment's site-packages.
PTH_NAME = "shellobstacle-mpi-first.pth"
#: Its one line (a ``.pth`` runs lines that start with ``import``); silent without the package.
PTH_LINE = (
    'import sys; exec("try:\\n from shellobstacle.compat import order_mpi_first\\n'
    'except ImportError:\\n pass\\nelse:\\n order_mpi_first()")'
)


class _MPIFirst(importlib.abc.MetaPathFinder):
    """Applies the workarounds before the first of :data:`NEEDS_MPI` is imported, once."""

    def find_spec(self, name: str, path: object = None, target: object = None) -> None:
        if name in NEEDS_MPI:
            sys.meta_path.remove(self)  # before the bootstrap, which imports them itself
            with contextlib.suppress(ModuleNotFoundError):  # not the wheel: nothing to order
                import dolfinx_solver  # noqa: F401
            if name == "dolfinx":  # which imports FFCx anyway
                from shellobstacle.compat.ffcx_cache_lookup import locate_jit_modules_by_path

                locate_jit_modules_by_path()
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
