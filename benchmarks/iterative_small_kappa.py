"""The iterative solver far below the paper's penalty range: κ = 1e-1 … 1e-12 on a square.

The paper's shell (its configuration's surface, material, load and plane) over
[-0.25, 0.25]² (as the tests use), a continuation over twelve decades of
κ with the iterative solver, for both split sweeps and both penalty quadratures: per κ whether
Newton converged, its steps and the Krylov iterations, and how often GAMG was built. One JSON
line per (sweep, quadrature) on rank 0.

    .venv/bin/python benchmarks/iterative_small_kappa.py
    .venv/bin/python benchmarks/iterative_small_kappa.py --cells 48
"""

from __future__ import annotations

import argparse
import json
import time

import shellobstacle.compat  # noqa: F401  (must precede dolfinx / petsc4py)

# isort: split
import dolfinx
from mpi4py import MPI
from record import PAPER

from shellobstacle.config import load_config
from shellobstacle.pipeline import continuation
from shellobstacle.problem import Discretization, PenalizedProblem
from shellobstacle.solvers.newton import NewtonOptions, NewtonSolver


def main() -> None:
    """Run the four continuations and print a JSON line for each."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--cells", type=int, default=24, help="cells per side of the square")
    args = ap.parse_args()
    comm = MPI.COMM_WORLD
    shell = load_config(PAPER).shell
    kappas = [10.0**-k for k in range(1, 13)]
    for sweep, keep in (("forward", True), ("symmetric", False)):
        for quadrature in ("gauss", "vertex"):
            mesh = dolfinx.mesh.create_rectangle(
                comm, [[-0.25, -0.25], [0.25, 0.25]], [args.cells, args.cells]
            )
            problem = PenalizedProblem(shell, mesh, Discretization(penalty_quadrature=quadrature))
            options = NewtonOptions(
                linear_solver="iterative", split_sweep=sweep, keep_multigrid=keep
            )
            solver = NewtonSolver(problem, options)
            t = time.perf_counter()
            steps = continuation(problem, solver, kappas)
            rec = {
                "cells": args.cells,
                "ranks": comm.size,
                "split_sweep": sweep,
                "keep_multigrid": keep,
                "quadrature": quadrature,
                "kappa": kappas,
                "converged": [s.newton.converged for s in steps],
                "newton": [s.newton.iterations for s in steps],
                "iterations": [sum(s.newton.linear_iterations) for s in steps],
                "multigrid_builds": solver.multigrid_builds,
                "seconds": round(time.perf_counter() - t, 3),
            }
            if comm.rank == 0:
                print(json.dumps(rec), flush=True)


if __name__ == "__main__":
    main()
