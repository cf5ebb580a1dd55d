"""The DOLFINx binary wheel's bootstrap, called by the command line.

The wheel ``dolfinx-solver-real`` needs ``mpi4py.MPI`` loaded before its compiled modules; the
package's modules import ``mpi4py`` first for that, as DOLFINx's own demos do, so the import
order of ``shellobstacle``, ``dolfinx`` and ``petsc4py`` in a user's script does not matter.
``import dolfinx_solver`` also refuses a broken environment (a foreign petsc4py, both scalar
variants installed) with a message that says what to uninstall: the command line calls
:func:`bootstrap` before anything else. Other DOLFINx installs (conda-forge, Docker, source
builds) have no such package and need nothing.
"""

from __future__ import annotations

__all__ = ["bootstrap"]


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
