"""The contact zone of Koiter's hybrid form condensed in ``K`` or in the block matrix ``H``.

On the paper's problem (Koiter P2, hybrid bending form, ε = 10⁻³, κ = h^0.5, h, h^1.5) a
Newton solve leaves its contact zone; that zone is condensed twice, in the stiffness ``K``
(ζ only) and in the block matrix ``H`` in (ζ, t) (the zone with its facets' multipliers,
:mod:`shellobstacle.solvers.zone.multipliers`), and each zone matrix ``S = K_S`` is
factorized with MUMPS' orderings (ICNTL(7): 0 AMD, 2 AMF, 3 SCOTCH, 4 PORD, 5 METIS). One
JSON line per layout and ordering: the sizes (zone unknowns, interface Γ, coupled outside
unknowns I'), the seconds to condense (the factorization of ``K_II`` or ``H_II`` included),
and the fastest of three numeric factorizations of ``S`` with its flops and entries.

    .venv/bin/python benchmarks/koiter_zone.py --h 0.02
"""

from __future__ import annotations

import argparse
import json
import time

from mpi4py import MPI  # noqa: F401  (MPI before DOLFINx and PETSc)

from koiter_cost import paper_shell_and_mesh
from koiter_factor import refactorize


def rows(h: float, orderings: list[int]) -> list[dict]:
    from shellobstacle.mesh.measures import mesh_size
    from shellobstacle.models.problem import PenalizedProblem
    from shellobstacle.penalty.spec import PenaltySpec
    from shellobstacle.solvers.base import direct_solver, factorize
    from shellobstacle.solvers.newton.continuation import continuation
    from shellobstacle.solvers.newton.solver import NewtonSolver
    from shellobstacle.solvers.zone.condensation import Condensation
    from shellobstacle.solvers.zone.multipliers import HybridBlocks
    from shellobstacle.spec import Discretization

    shell, mesh = paper_shell_and_mesh("koiter", h)
    problem = PenalizedProblem(shell, mesh, Discretization(degree=2, bending="hybrid"))
    solver = NewtonSolver(problem)
    continuation(problem, solver, PenaltySpec(exponent=1.5).ladder(mesh_size(mesh)))
    Z = solver.zone.Z
    K = problem.stiffness()
    blocks = HybridBlocks(problem.condensed, problem.V, problem.t.function_space)
    out = []
    for layout, chosen in (("K", None), ("H", blocks)):
        t0 = time.perf_counter()
        cond = Condensation(K, Z, "cholesky", {"factorize": 0.0}, chosen)
        seconds = time.perf_counter() - t0
        S = cond.Ks
        for ordering in orderings:
            ksp = direct_solver(S, "cholesky", "zone_bench", icntl={7: ordering})
            factorize(ksp, "S")
            numeric = [refactorize(ksp, S) for _ in range(3)]
            F = ksp.getPC().getFactorMatrix()
            out.append(
                {
                    "layout": layout,
                    "target_h": h,
                    "dofs": problem.num_dofs,
                    **cond.sizes,
                    "condense_seconds": round(seconds, 3),
                    "ordering": ordering,
                    "factor_seconds": round(min(numeric), 4),
                    "factor_gflop": round(F.getMumpsRinfog(3) / 1e9, 3),
                    "factor_entries": int(F.getMumpsInfog(29)),
                }
            )
            print(json.dumps(out[-1]), flush=True)
            ksp.destroy()
        cond.destroy()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--h", type=float, default=0.02, help="mesh size of the P2 mesh")
    parser.add_argument(
        "--orderings", type=int, nargs="+", default=[0, 2, 3, 4, 5], help="MUMPS ICNTL(7)"
    )
    args = parser.parse_args()
    rows(args.h, args.orderings)


if __name__ == "__main__":
    main()
