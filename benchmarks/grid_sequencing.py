"""Grid sequencing (nested iteration) on the mesh levels, a trial: does the coarser level's
solution give the finer level's Newton a good start?

The meshes are those ``solver.linear_solver = "multigrid"`` uses (gmsh's mesh and its uniform
refinements). The level ``--first`` is solved by the config's continuation (κ = h^0.5, h,
h^1.5 for the paper's problem); every finer level ℓ then solves its own target κ_ℓ = h_ℓ^q
once, starting from the coarser level's solution interpolated by the multigrid transfer
(``mesh.hierarchy.prolongation``; zero at the Dirichlet dofs). Levels below
``--direct-below`` dofs (150,000) use the direct path, the others ``--linear-solver``.

One JSON line per level: dofs, h, the κ solved, Newton steps and CG iterations per κ,
relative residuals ``‖R‖/‖R(0)‖`` and step lengths of every step, the start's residual
(``‖R‖``, the elastic part ``Kζ − f`` by component and the penalty part, each over ``‖f‖``),
the start's active points (``g < 0`` at the penalty's points) against the solution's (how
many, how many of either not in the other), seconds, contact area. ``--relax`` first solves
the tangential components of the interpolated start again with ζ_3 held (one Newton step
on ζ_1, ζ_2 alone, MUMPS' Cholesky of that block). ``--plain`` adds the finest level's own
continuation from ζ = 0.

    .venv/bin/python benchmarks/grid_sequencing.py --size 0.0058 --plain
    .venv/bin/python benchmarks/grid_sequencing.py --size 0.0058 --relax --direct-below 0
    .venv/bin/python benchmarks/grid_sequencing.py --size 0.00145 --first 2
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

from mpi4py import MPI
from petsc4py import PETSc

import numpy as np

from shellobstacle.api import make_mesh
from shellobstacle.config.loader import load_config
from shellobstacle.mesh.hierarchy import coarser_meshes
from shellobstacle.mesh.measures import mesh_size
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.contact import Postprocessor
from shellobstacle.solvers.base import direct_solver
from shellobstacle.solvers.newton.continuation import continuation
from shellobstacle.solvers.newton.nested import interpolate
from shellobstacle.solvers.newton.solver import NewtonSolver


def count(mask: np.ndarray, comm: MPI.Comm) -> int:
    """Global number of true entries of an owned-points mask."""
    return comm.allreduce(int(np.count_nonzero(mask)))


def residual_split(solver: NewtonSolver) -> dict:
    """``‖R‖``, ``‖(Kζ − f)_i‖`` for each component ``i`` and the penalty part's norm at the
    current iterate, over ``‖f‖``."""
    system = solver.system
    f = system.load()
    system.residual()
    elastic = system.Kz.copy()
    elastic.axpy(-1.0, system.f)
    penalty = system.R.copy()
    penalty.axpy(-1.0, elastic)
    parts = elastic.array_r.reshape(-1, 3)
    comm = solver.problem.mesh.comm
    by_component = [comm.allreduce(float(parts[:, i] @ parts[:, i])) ** 0.5 / f for i in range(3)]
    out = {
        "residual": system.residual_norm() / f,
        "elastic_by_component": [float(f"{v:.3g}") for v in by_component],
        "penalty": penalty.norm() / f,
    }
    elastic.destroy()
    penalty.destroy()
    return {k: float(f"{v:.3g}") if isinstance(v, float) else v for k, v in out.items()}


def relax_tangential(solver: NewtonSolver) -> None:
    """One Newton step on ζ_1, ζ_2 with ζ_3 held: ``J_ττ δ_τ = −R_τ`` by MUMPS' Cholesky."""
    system, problem = solver.system, solver.problem
    system.load()
    system.residual()
    A = system.jacobian()
    lo, hi = A.getOwnershipRange()
    rows = np.arange(lo, hi, dtype=PETSc.IntType)
    tangential = PETSc.IS().createGeneral(rows[rows % 3 != 2], comm=A.getComm())
    block = A.createSubMatrix(tangential, tangential)
    R = system.R.getSubVector(tangential)
    b = R.copy()
    system.R.restoreSubVector(tangential, R)
    b.scale(-1.0)
    ksp = direct_solver(block, "cholesky", "tangential")
    x = b.duplicate()
    ksp.solve(b, x)
    zeta = problem.zeta.x.petsc_vec
    part = zeta.getSubVector(tangential)
    part.axpy(1.0, x)
    zeta.restoreSubVector(tangential, part)
    problem.zeta.x.scatter_forward()
    for obj in (ksp, block, b, x, tangential):
        obj.destroy()


def level(
    cfg, mesh, kappas, coarse, linear_solver: str, relax: bool = False, direct_below: int = 150_000
):
    """Solve ``kappas`` on ``mesh`` from ``coarse``'s solution interpolated (ζ = 0 if None;
    ``relax``: its tangential components solved again first, :func:`relax_tangential`)."""
    t0 = time.perf_counter()
    comm = mesh.comm
    problem = PenalizedProblem(cfg.shell, mesh, cfg.discretization, kappa=kappas[0])
    if coarse is not None:
        interpolate(coarse, problem)
    chosen = "direct" if problem.num_dofs < direct_below else linear_solver
    solver = NewtonSolver(problem, dataclasses.replace(cfg.solver, linear_solver=chosen))
    split = residual_split(solver)
    if coarse is not None and relax:
        relax_tangential(solver)
        split["relaxed"] = residual_split(solver)
    start = solver.penalty.gap(problem.zeta.x.petsc_vec) < 0
    steps = continuation(problem, solver, list(kappas))
    end = np.zeros_like(start)
    end[solver.active_points] = True
    return problem, {
        "dofs": problem.num_dofs,
        "h": mesh_size(mesh),
        "kappas": list(kappas),
        "linear_solver": chosen,
        "newton": [s.iterations for s in steps],
        "cg": [s.record.linear_iterations for s in steps],
        "relative_residuals": [
            [float(f"{r / s.record.reference:.2e}") for r in s.record.residual_norms] for s in steps
        ],
        "step_lengths": [[float(f"{t:.2g}") for t in s.record.step_lengths] for s in steps],
        "start_residual": split,
        "start_active": count(start, comm),
        "solution_active": count(end, comm),
        "start_not_solution": count(start & ~end, comm),
        "solution_not_start": count(end & ~start, comm),
        "seconds": round(time.perf_counter() - t0, 2),
        "contact_area": Postprocessor(problem).contact()["contact_area"],
    }


def main() -> None:
    """Solve the levels coarse to fine and print a JSON line per level on rank 0."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--config", default="examples/paper.toml", help="the problem's config")
    ap.add_argument("--size", type=float, required=True, help="gmsh target size of the finest")
    ap.add_argument("--first", type=int, default=0, help="the level solved by continuation")
    ap.add_argument("--linear-solver", default="multigrid", help="from --direct-below dofs")
    ap.add_argument("--direct-below", type=int, default=150_000, help="direct below these dofs")
    ap.add_argument("--relax", action="store_true", help="relax the start's ζ_1, ζ_2 first")
    ap.add_argument("--plain", action="store_true", help="the finest's own continuation too")
    args = ap.parse_args()
    cfg = load_config(args.config, [f"domain.h={args.size}"])
    mesh = make_mesh(cfg.domain)
    meshes = [*coarser_meshes(mesh), mesh][args.first :]
    coarse = None
    for k, m in enumerate(meshes):
        h = mesh_size(m)
        kappas = cfg.penalty.ladder(h) if k == 0 else [cfg.penalty.target(h)]
        coarse, row = level(
            cfg, m, kappas, coarse, args.linear_solver, args.relax, args.direct_below
        )
        row["variant"] = "continuation" if k == 0 else "from the coarser level"
        if m.comm.rank == 0:
            print(json.dumps(row), flush=True)
    if args.plain:
        ladder = cfg.penalty.ladder(mesh_size(mesh))
        _, row = level(cfg, mesh, ladder, None, args.linear_solver, False, args.direct_below)
        row["variant"] = "continuation (plain)"
        if mesh.comm.rank == 0:
            print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
