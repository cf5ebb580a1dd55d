"""Phases of making a large mesh: gmsh's coarse mesh, its distribution, the parallel refinements.

For one gmsh target size of the paper's disk and several coarsening levels k (gmsh at 2^k h,
then k uniform refinements of the distributed mesh), one JSON line on rank 0 per k: gmsh
seconds and vertices (rank 0), distribution of the coarse mesh (``model_to_mesh``), the k
refinements, the whole mesh, the fine mesh's cells, dofs (3 per vertex) and h; and, for
comparison, ``create_mesh`` of the fine mesh's cells (what distributing the refined arrays
would cost).

    .venv/bin/python benchmarks/mesh_phases.py --target 0.0029 --steps 1,2,3
    .venv/bin/mpiexec -n 2 .venv/bin/python benchmarks/mesh_phases.py --target 0.0012 --steps 3,4
"""

from __future__ import annotations

import argparse
import contextlib
import time

from mpi4py import MPI

import dolfinx.io.gmsh
import dolfinx.mesh
import numpy as np
from record import PAPER, emit

from shellobstacle.config.loader import load_config
from shellobstacle.mesh import meshing
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.mesh.measures import mesh_size, num_cells_global
from shellobstacle.mesh.refinement import red_refinement


def phases(spec: DomainSpec, steps: int, comm: MPI.Comm) -> dict:
    """Time each phase of ``meshing._gmsh_mesh(spec, comm, steps)``, done step by step."""
    rec: dict = {"target": spec.h, "ranks": comm.size, "steps": steps}
    comm.Barrier()
    t0 = time.perf_counter()
    with contextlib.ExitStack() as stack:
        model = meshing._gmsh_on_rank0(spec, comm, steps, stack)
        rec["gmsh_s"] = time.perf_counter() - t0
        gmsh_nodes = len(model.mesh.getNodes()[0]) if model is not None else 0
        rec["gmsh_vertices"] = comm.bcast(gmsh_nodes, root=0)
        t = time.perf_counter()
        mesh = dolfinx.io.gmsh.model_to_mesh(model, comm, 0, 2, meshing._partitioner()).mesh
        comm.Barrier()
        rec["distribute_s"] = time.perf_counter() - t
    t = time.perf_counter()
    for _ in range(steps):
        mesh = red_refinement(mesh, spec)
    comm.Barrier()
    rec["refine_s"] = time.perf_counter() - t
    rec["mesh_s"] = time.perf_counter() - t0
    rec["cells"] = num_cells_global(mesh)
    rec["dofs"] = 3 * mesh.geometry.index_map().size_global
    rec["h"] = mesh_size(mesh)
    # the fine mesh distributed from arrays, as before: its owned cells and nodes
    n_owned = mesh.topology.index_map(2).size_local
    nodes = mesh.geometry.index_map()
    fine_cells = nodes.local_to_global(mesh.geometry.dofmaps[0][:n_owned].ravel())
    fine_x = mesh.geometry.x[: nodes.size_local, :2]
    comm.Barrier()
    t = time.perf_counter()
    domain = dolfinx.io.gmsh.ufl_mesh(2, 2, dtype=np.float64)  # linear triangles
    dolfinx.mesh.create_mesh(
        comm, fine_cells.reshape(-1, 3), domain, fine_x, meshing._partitioner()
    )
    comm.Barrier()
    rec["create_mesh_fine_s"] = time.perf_counter() - t
    return rec


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--target", type=float, default=0.0029, help="gmsh target mesh size")
    ap.add_argument("--steps", default="1,2,3", help="coarsening levels k to time")
    args = ap.parse_args()
    comm = MPI.COMM_WORLD
    spec = load_config(PAPER, [f"domain.h={args.target}"]).domain
    for steps in (int(k) for k in args.steps.split(",")):
        emit(phases(spec, steps, comm), comm)


if __name__ == "__main__":
    main()
