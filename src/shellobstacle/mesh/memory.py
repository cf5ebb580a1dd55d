"""Memory: this machine's, and a solve's need per dof by model, degree and linear solver.

The figures per dof were measured on the paper's problem, Koiter's on the cylindrical panel
(peak resident memory, ``docs/perf/koiter/``, ``docs/perf/multigrid/`` and the 1.93 M-dof
runs of ``docs/performance.md``) and rounded up: estimates within a factor of about 1.5. They
serve one purpose: :func:`~shellobstacle.mesh.resources.require_fits` refuses, before any
work, what would not fit this machine, and names what would. They never choose the solver.
"""

from __future__ import annotations

import os

from mpi4py import MPI

__all__ = [
    "BASE_BYTES",
    "BYTES_PER_DOF",
    "BYTES_PER_DOF_MULTIGRID",
    "BYTES_PER_VERTEX_MESH",
    "GIB",
    "MEMORY_SHARE",
    "bytes_per_dof",
    "machine_memory",
    "multigrid_needs_levels",
    "need",
]

#: Peak memory per dof of a solve with a factorization, bytes, by (model, degree).
BYTES_PER_DOF = {("membrane", 1): 3.5e3, ("membrane", 2): 4.0e3, ("koiter", 2): 13.0e3}
#: Peak memory per dof of a solve with multigrid, bytes, by (model, degree): the models whose
#: multigrid was measured (docs/perf/multigrid.md).
BYTES_PER_DOF_MULTIGRID = {("membrane", 1): 2.2e3, ("koiter", 2): 5.0e3}
#: Memory per vertex of a mesh and the assumption checks (no solve), bytes.
BYTES_PER_VERTEX_MESH = 1.0e3
#: The interpreter with DOLFINx, PETSc and the compiled forms, bytes per process.
BASE_BYTES = 0.3e9
#: The share of this machine's memory an estimate may take.
MEMORY_SHARE = 0.8
#: Bytes in a GiB, the one unit of memory in messages.
GIB = 2.0**30


def multigrid_needs_levels(model: str) -> bool:
    """Whether ``model``'s multigrid needs the mesh's coarser levels (Koiter's: algebraic
    multigrid, the fallback without them, took 100–900 CG iterations per Newton step)."""
    return model == "koiter"


def machine_memory() -> float:
    """Physical memory of this machine, bytes."""
    return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))


def bytes_per_dof(model: str, degree: int, linear_solver: str) -> float:
    """Peak bytes per dof of a solve of ``model`` with Lagrange ``degree`` by
    ``linear_solver`` (multigrid's own figure where it was measured, a factorization's else)."""
    if linear_solver == "multigrid" and (model, degree) in BYTES_PER_DOF_MULTIGRID:
        return BYTES_PER_DOF_MULTIGRID[(model, degree)]
    return BYTES_PER_DOF.get((model, degree), BYTES_PER_DOF[("koiter", 2)])


def need(bytes_all: float, comm: MPI.Comm) -> float:
    """The memory this machine needs for its ranks' share of ``bytes_all`` (the run's whole
    need, distributed evenly), with :data:`BASE_BYTES` per rank (collective)."""
    local = comm.Split_type(MPI.COMM_TYPE_SHARED)
    on_node = local.size
    local.Free()
    return bytes_all * on_node / comm.size + BASE_BYTES * on_node
