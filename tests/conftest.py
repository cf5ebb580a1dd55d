"""Test configuration: the DOLFINx wheel's MPI bootstrap is loaded before any test module."""

from shellobstacle import compat  # noqa: F401  (orders mpi4py ahead of dolfinx/petsc4py)
