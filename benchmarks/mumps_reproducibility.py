"""Whether MUMPS repeats itself: the same matrix factorized several times, the same solve.

The membrane stiffness K of the tests' unit-square problem (the paper's shell, ``--n`` cells
per side) is factorized ``--repeats`` times by MUMPS (Cholesky and LU, each a fresh KSP) and
solved for one right-hand side. One JSON line per factorization type: whether every solution
equals the first to the last bit on every rank, and the largest difference relative to the
solution's norm. Run it under ``mpiexec -n 1 … 4``: serially and on 2 ranks the solutions are
bitwise equal; on 3 or more MUMPS' dynamic scheduling (the processes that help with a front
are chosen at run time by load) changes the order of floating-point sums from run to run.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from mpi4py import MPI

# isort: split
from petsc4py import PETSc

import numpy as np

sys.path.insert(0, str(Path(__file__).parents[1] / "tests"))
from conftest import make_paper_shell as paper_shell
from conftest import square

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.newton.solver import NewtonOptions, NewtonSolver


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--n", type=int, default=32, help="cells per side of the unit square")
    ap.add_argument("--repeats", type=int, default=4)
    args = ap.parse_args()
    comm = MPI.COMM_WORLD
    problem = PenalizedProblem(paper_shell(), square(n=args.n))
    K = NewtonSolver(problem, NewtonOptions()).K
    b = K.createVecLeft()
    b.setRandom()
    for factorization in ("cholesky", "lu"):
        solutions = []
        for _ in range(args.repeats):
            ksp = PETSc.KSP().create(comm)
            ksp.setOperators(K)
            ksp.setType("preonly")
            ksp.getPC().setType(factorization)
            ksp.getPC().setFactorSolverType("mumps")
            x = K.createVecRight()
            ksp.solve(b, x)
            solutions.append(x)
            ksp.destroy()
        first = solutions[0]
        bitwise = all(np.array_equal(x.array_r, first.array_r) for x in solutions[1:])
        relative = []
        for x in solutions[1:]:
            d = x.copy()
            d.axpy(-1.0, first)
            relative.append(d.norm() / first.norm())
        rec = {
            "benchmark": "mumps_reproducibility", "ranks": comm.size, "n": args.n,
            "dofs": problem.num_dofs, "factorization": factorization,
            "repeats": args.repeats, "bitwise_equal": comm.allreduce(bitwise, MPI.LAND),
            "max_relative_difference": max(relative),
        }  # fmt: skip
        if comm.rank == 0:
            print(json.dumps(rec), flush=True)


if __name__ == "__main__":
    main()
