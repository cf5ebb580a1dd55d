"""MUMPS' Cholesky factor of the stiffness: Koiter P2 at 2h against membrane P1 at h.

The meshes, shell and load of ``koiter_cost.py`` (equal dofs). Factorized: membrane P1's
``K``; Koiter's ``K`` with the C⁰ interior penalty; for the hybrid bending form, the block
matrix in ``(ζ, t)`` (as the contact zone factorizes it; ``unknowns`` counts the
multipliers too), as it is and with each mesh node's three displacements one block of
MUMPS' analysis (``"node_blocks"``, ICNTL(15) = 1, as the contact zone orders it). For each
and each MUMPS ordering (ICNTL(7): 5 METIS, the default here; 3 SCOTCH; 4 PORD; 2 AMF; 0 AMD;
6 QAMD) one JSON line: dofs, the matrix' nonzeros and assembly seconds, the fastest of two
factorizations (analysis included) and of two numeric factorizations after them (the
difference is the analysis), the factor's entries (INFOG(29)) and flops (RINFOG(3)).

    .venv/bin/python benchmarks/koiter_factor.py --h 0.01,0.005 --orderings 5,3,4,2
"""

from __future__ import annotations

import argparse
import itertools
import json
import time

from mpi4py import MPI  # noqa: F401  (MPI before DOLFINx and PETSc)

import numpy as np
from koiter_cost import paper_shell_and_mesh


def refactorize(ksp, A) -> float:
    """Seconds of a numeric factorization of ``A`` by ``ksp`` (its analysis kept): ``A``
    gets a new state with the same entries."""
    from shellobstacle.solvers.base import factorize

    A.setValue(0, 0, 0.0, addv=True)
    A.assemble()
    ksp.setOperators(A)
    t0 = time.perf_counter()
    factorize(ksp, "the matrix")
    return time.perf_counter() - t0


def rows(h: float, orderings: list[int]) -> list[dict]:
    from petsc4py import PETSc

    from shellobstacle.models.problem import PenalizedProblem
    from shellobstacle.solvers.base import direct_solver, factorize
    from shellobstacle.solvers.zone.multipliers import HybridBlocks
    from shellobstacle.solvers.zone.mumps import in_blocks
    from shellobstacle.spec import Discretization

    out = []
    for model, degree, size, bending in (
        ("membrane", 1, h, None),
        ("koiter", 2, 2 * h, "c0ip"),
        ("koiter", 2, 2 * h, "hybrid"),
    ):
        shell, mesh = paper_shell_and_mesh(model, size)
        disc = Discretization(degree=degree, bending=bending or "hybrid")
        problem = PenalizedProblem(shell, mesh, disc)
        t0 = time.perf_counter()
        K = problem.stiffness()
        variants: list[np.ndarray | None] = [None]
        if bending == "hybrid":  # the block matrix in (ζ, t), as the contact zone has it
            blocks = HybridBlocks(problem.condensed, problem.V, problem.t.function_space)
            K = blocks.H
            variants.append(blocks.variable_blocks(np.arange(K.getSize()[0])))
        assemble = time.perf_counter() - t0
        for ordering, node_blocks in itertools.product(orderings, variants):
            seconds, numeric = [], []
            for _ in range(2):
                ksp = direct_solver(K, "cholesky", "factor", icntl={7: ordering})
                prepare = None if node_blocks is None else in_blocks(node_blocks, ordering)
                t0 = time.perf_counter()
                factorize(ksp, "K", prepare=prepare)
                seconds.append(time.perf_counter() - t0)
                numeric.append(refactorize(ksp, K))
                F = ksp.getPC().getFactorMatrix()
                entries, flops = F.getMumpsInfog(29), F.getMumpsRinfog(3)
                ksp.destroy()
            out.append(
                {
                    "model": model,
                    "degree": degree,
                    "bending": bending,
                    "unknowns": K.getSize()[0],
                    "target_h": size,
                    "dofs": problem.num_dofs,
                    "nonzeros": int(K.getInfo(PETSc.Mat.InfoType.GLOBAL_SUM)["nz_used"]),
                    "assemble_seconds": round(assemble, 3),
                    "ordering": ordering,
                    "node_blocks": node_blocks is not None,
                    "factor_seconds": round(min(seconds), 3),
                    "numeric_seconds": round(min(numeric), 3),
                    "factor_entries": int(entries),
                    "factor_gflop": round(flops / 1e9, 3),
                }
            )
            print(json.dumps(out[-1]), flush=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--h", default="0.01,0.005", help="membrane P1 mesh sizes")
    parser.add_argument("--orderings", default="5", help="MUMPS ICNTL(7) values")
    args = parser.parse_args()
    orderings = [int(v) for v in args.orderings.split(",")]
    for h in (float(v) for v in args.h.split(",")):
        rows(h, orderings)


if __name__ == "__main__":
    main()
