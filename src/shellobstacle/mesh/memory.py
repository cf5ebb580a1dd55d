"""Memory: this machine's, and a solve's need per dof by model, degree and linear solver;
and what ``solver.linear_solver = "auto"`` stands for (:func:`linear_solver_for`).

The figures per dof were measured on the paper's problem, Koiter's on the cylindrical panel
(peak resident memory, ``docs/perf/koiter/``, ``docs/perf/multigrid/`` and the 1.93 M-dof
runs of ``docs/performance.md``) and rounded up: estimates within a factor of about 1.5. They
decide what "auto" stands for where the direct path does not fit, and what
:func:`~shellobstacle.mesh.resources.require_fits` refuses.
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
    "MULTIGRID_FROM_DOFS",
    "auto_choice",
    "bytes_per_dof",
    "linear_solver_for",
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
#: From this many dofs "auto" takes multigrid for the membrane P1 on a mesh with coarser
#: levels. On the paper's problem, untuned, it was faster than the direct path from about
#: 0.95 M dofs: serially with nested iteration 1.3–1.5× (0.95 M and 1.31 M), on 2 ranks
#: 1.2× (1.31 M); on the four examples at about 0.95 M plain multigrid was on par or faster.
#: At 0.33–0.66 M the two were on par (docs/performance.md).
MULTIGRID_FROM_DOFS = 1.0e6


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


def linear_solver_for(
    requested: str,
    dofs: float,
    model: str,
    degree: int,
    comm: MPI.Comm = MPI.COMM_WORLD,
    levels: bool = True,
) -> str:
    """The linear solver of a request: ``"auto"`` is :func:`auto_choice`'s, any other request
    is itself. Collective."""
    if requested != "auto":
        return requested
    return auto_choice(dofs, model, degree, comm, levels)[0]


def auto_choice(
    dofs: float, model: str, degree: int, comm: MPI.Comm = MPI.COMM_WORLD, levels: bool = True
) -> tuple[str, str]:
    """What ``"auto"`` stands for, and why: for the membrane P1, multigrid from
    :data:`MULTIGRID_FROM_DOFS` dofs on a mesh with coarser ``levels``; for the membrane P1
    and Koiter's model (on a mesh with ``levels``: without them its multigrid is refused),
    multigrid wherever the direct path's estimate does not fit in :data:`MEMORY_SHARE` of this
    machine; the direct path else. Collective: rank 0's machine decides for all."""
    if (model, degree) not in BYTES_PER_DOF_MULTIGRID:
        return "direct", f"multigrid was not measured on the {model} model with degree {degree}"
    if (model, degree) == ("membrane", 1) and levels and dofs >= MULTIGRID_FROM_DOFS:
        size = f"{MULTIGRID_FROM_DOFS / 1e6:g} M"
        return "multigrid", f"from {size} dofs on a refined mesh it is the faster"
    needed = need(dofs * bytes_per_dof(model, degree, "direct"), comm)
    fits = comm.bcast(bool(needed <= MEMORY_SHARE * machine_memory()), root=0)
    if fits:
        return "direct", "the direct path's memory estimate fits this machine"
    if multigrid_needs_levels(model) and not levels:
        return "direct", "Koiter's multigrid needs a refined mesh"
    return "multigrid", "the direct path's memory estimate does not fit this machine"
