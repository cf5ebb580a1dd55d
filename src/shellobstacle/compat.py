"""The one place that orders the DOLFINx wheel's MPI bootstrap ahead of dolfinx/petsc4py.

It also gives NumPy's BLAS one thread per rank under ``mpiexec`` unless ``OMP_NUM_THREADS``
or ``OPENBLAS_NUM_THREADS`` is set, warns when ``OPENBLAS_CORETYPE`` forces kernels known to
crash it (:mod:`shellobstacle.threads`), keeps freed memory in
the process unless the user tuned malloc (:mod:`shellobstacle.memory`), faults the heap's new
pages in on a spare core (:mod:`shellobstacle.prefault`), and gives MUMPS a DGEMMT made of
DGEMM blocks before PETSc is loaded (:mod:`shellobstacle.blas`).
"""

import contextlib
import warnings

with contextlib.suppress(ImportError):
    import dolfinx_solver  # noqa: F401  (binary wheel: loads mpi4py.MPI first)

from mpi4py import MPI

from shellobstacle.blas import block_gemmt
from shellobstacle.memory import keep_freed_memory
from shellobstacle.prefault import start_prefault
from shellobstacle.threads import coretype_warning, limit_blas_threads

start_prefault(MPI.COMM_WORLD.size, keep_freed_memory())
limit_blas_threads(MPI.COMM_WORLD.size)
block_gemmt()
if (_message := coretype_warning()) and MPI.COMM_WORLD.rank == 0:
    warnings.warn(_message, RuntimeWarning, stacklevel=2)
