"""The one place that orders the DOLFINx wheel's MPI bootstrap ahead of dolfinx/petsc4py."""

import contextlib

with contextlib.suppress(ImportError):
    import dolfinx_solver  # noqa: F401  (binary wheel: loads mpi4py.MPI first)
