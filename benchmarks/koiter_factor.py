"""MUMPS' Cholesky factor of the stiffness: Koiter P2 at 2h against membrane P1 at h.

The meshes, shell and load of ``koiter_cost.py`` (equal dofs). Factorized: membrane P1's
``K``; Koiter's ``K`` with the C⁰ interior penalty; for the hybrid bending form, the block
matrix in ``(ζ, t)`` (as the contact zone factorizes it; ``unknowns`` counts the
multipliers too). For each and each MUMPS ordering (ICNTL(7): 5 METIS, the default here;
3 SCOTCH; 4 PORD; 2 AMF; 0 AMD; 6 QAMD) one JSON line: dofs, the matrix' nonzeros and
assembly seconds, the fastest of two factorizations (analysis included), the factor's
entries (INFOG(29)) and flops (RINFOG(3)).

    .venv/bin/python benchmarks/koiter_factor.py --h 0.01,0.005 --orderings 5,3,4,2
"""

from __future__ import annotations

import argparse
import json
import time

from mpi4py import MPI  # noqa: F401  (MPI before DOLFINx and PETSc)

from koiter_cost import paper_shell_and_mesh


def rows(h: float, orderings: list[int]) -> list[dict]:
    from petsc4py import PETSc

    from shellobstacle.model import Discretization
    from shellobstacle.problem import PenalizedProblem
    from shellobstacle.solvers.base import direct_solver, factorize
    from shellobstacle.solvers.zone.multipliers import block_matrix

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
        if bending == "hybrid":  # the block matrix in (ζ, t), as the contact zone has it
            K, _, _ = block_matrix(problem.condensed)
        assemble = time.perf_counter() - t0
        for ordering in orderings:
            seconds = []
            for _ in range(2):
                ksp = direct_solver(K, "cholesky", "factor", icntl={7: ordering})
                t0 = time.perf_counter()
                factorize(ksp, "K")
                seconds.append(time.perf_counter() - t0)
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
                    "factor_seconds": round(min(seconds), 3),
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
