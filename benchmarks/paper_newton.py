"""Newton on the paper's problem (docs/model.md §7): κ = h^q, q = 0.5, 1.0, …, q_max, warm-started.

Prints one JSON line per κ (Newton steps, line-search evaluations, stop reason, relative
residual, seconds, contact area, the active set: its points, how many switched on and off
since the previous κ, the cells counted by how many of their points are active, and over the
cells in contact the medians of the deepest penetration and of the part of the gap that no
affine function matches at the cell's points) and one line of phase timings, for each penalty
quadrature.

    .venv/bin/python benchmarks/paper_newton.py --h 0.0058 --qmax 8
    .venv/bin/mpiexec -n 2 .venv/bin/python benchmarks/paper_newton.py --h 0.0058

``--h`` is gmsh's target size; the largest cell diameter obtained is printed as ``h``.
"""

from __future__ import annotations

import argparse
import json
import resource
import time

from mpi4py import MPI

import numpy as np

from shellobstacle.api import make_mesh
from shellobstacle.config.loader import load_config
from shellobstacle.mesh.measures import mesh_size
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.contact import Postprocessor
from shellobstacle.solvers.newton.solver import NewtonOptions, NewtonSolver
from shellobstacle.solvers.quadrature_penalty import penalty_rule
from shellobstacle.spec import Discretization

PAPER = "src/shellobstacle/configs/paper.toml"


def _switched(
    previous: np.ndarray | None, active: np.ndarray, comm: MPI.Comm
) -> tuple[int | None, int | None]:
    """Points that became active and inactive since ``previous`` (global counts)."""
    if previous is None:
        return None, None
    on = comm.allreduce(int(np.count_nonzero(active & ~previous)), op=MPI.SUM)
    off = comm.allreduce(int(np.count_nonzero(previous & ~active)), op=MPI.SUM)
    return on, off


def _cells_by_active_points(solver: NewtonSolver, active: np.ndarray, comm: MPI.Comm) -> list[int]:
    """Entry ``k``: the cells with exactly ``k`` active penalty points, for ``k ≥ 1``
    (entry 0, the cells without contact, is left at 0)."""
    per_cell = solver.penalty.by_cell(active)
    counts = np.bincount(per_cell.sum(axis=1), minlength=per_cell.shape[1] + 1)
    counts[0] = 0
    return [int(n) for n in comm.allreduce(counts, op=MPI.SUM)]


def _contact_cell_gaps(
    solver: NewtonSolver, problem: PenalizedProblem, comm: MPI.Comm
) -> tuple[float, float]:
    """Over the cells with an active point: the medians of ``max_k (−g_k)`` (the deepest
    penetration, ≈ κλ) and of ``max_k |g_k − a(x_k)|`` with ``a`` the least-squares affine fit
    of the gap at the cell's points (0 for the vertex rule; for Gauss points the curvature of
    the gap within a cell, which P1 displacements cannot remove). NaN without contact."""
    points, _ = penalty_rule(problem)
    V = np.column_stack([np.ones(len(points)), points])
    nonaffine = np.eye(len(points)) - V @ np.linalg.pinv(V)
    g = solver.penalty.by_cell(solver.penalty_gaps)
    g = g[(g < 0).any(axis=1)]
    penetration = np.concatenate(comm.allgather(-g.min(axis=1)))
    curvature = np.concatenate(comm.allgather(np.abs(g @ nonaffine.T).max(axis=1)))
    if penetration.size == 0:
        return float("nan"), float("nan")
    return float(np.median(penetration)), float(np.median(curvature))


def main() -> None:
    """Run the sweep and print JSON lines on rank 0."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--h", type=float, default=0.0058, help="gmsh target mesh size")
    ap.add_argument("--qmax", type=float, default=8.0)
    ap.add_argument("--quadratures", default="gauss,vertex")
    ap.add_argument("--linear-solver", default="direct", choices=("direct", "iterative"))
    args = ap.parse_args()
    comm = MPI.COMM_WORLD

    def emit(record: dict) -> None:
        if comm.rank == 0:
            print(json.dumps(record), flush=True)

    cfg = load_config(PAPER, [f"domain.h={args.h}"])
    t0 = time.perf_counter()
    mesh = make_mesh(cfg.domain)
    h = mesh_size(mesh)
    t_mesh = time.perf_counter() - t0
    for quadrature in args.quadratures.split(","):
        t0 = time.perf_counter()
        disc = Discretization(penalty_quadrature=quadrature)
        problem = PenalizedProblem(cfg.shell, mesh, disc)
        solver = NewtonSolver(problem, NewtonOptions(linear_solver=args.linear_solver))
        post = Postprocessor(problem)
        t_compile = time.perf_counter() - t0
        total = 0.0
        previous = None
        for q in np.arange(0.5, args.qmax + 1e-9, 0.5):
            problem.set_kappa(h**q)
            t0 = time.perf_counter()
            r = solver.solve()
            seconds = time.perf_counter() - t0
            total += seconds
            c = post.contact()
            active = solver.active_points
            on, off = _switched(previous, active, comm)
            previous = active
            penetration, nonaffine = _contact_cell_gaps(solver, problem, comm)
            emit(
                {
                    "quadrature": quadrature,
                    "q": float(q),
                    "kappa": h**q,
                    "newton": r.iterations,
                    "line_search_evals": r.line_search_evaluations,
                    "reason": r.reason,
                    "relative_residual": r.relative_residual,
                    "seconds": round(seconds, 3),
                    "round_off_limited": r.round_off_limited,
                    "linear_iterations": r.linear_iterations,
                    "contact_area": c["contact_area"],
                    "max_violation": c["max_violation"],
                    "active_points": comm.allreduce(int(active.sum()), op=MPI.SUM),
                    "switched_on": on,
                    "switched_off": off,
                    "cells_by_active_points": _cells_by_active_points(solver, active, comm),
                    "contact_cells_penetration_median": penetration,
                    "contact_cells_gap_nonaffine_median": nonaffine,
                }
            )
        emit(
            {
                "quadrature": quadrature,
                "h": h,
                "dofs": problem.num_dofs,
                "ranks": comm.size,
                "mesh_s": round(t_mesh, 2),
                "compile_s": round(t_compile, 2),
                "sweep_s": round(total, 2),
                **{f"{k}_s": round(v, 2) for k, v in solver.timings.items()},
                "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024,
            }
        )


if __name__ == "__main__":
    main()
