"""CG iterations with the geometric multigrid V-cycle against h and ε/κ (the paper's problem).

The preconditioner of ``solver.linear_solver = "multigrid"`` (Chebyshev–Jacobi smoothing on
every level, PᵀAP coarser operators that follow the Jacobian, MUMPS on the coarsest mesh) must
not degrade as the mesh is refined nor as the penalty stiffens: the Jacobian
``K + (1/κ) M_Aᵀ D_A⁻¹ M_A`` adds a mass-like term of weight ``ε/κ`` on the active points.
For each gmsh size the shell is solved by continuation down a ladder of κ spanning ε/κ from
10⁻² to 10⁴ (past the paper's κ = h^1.5: ε/κ = 1.4–31 from 82k to 5.2 M dofs), every Newton
direction solved to the same relative tolerance (``--rtol``, fixed forcing: no inexact Newton),
so that the CG iterations per direction measure the V-cycle alone. One JSON line per (size, κ):
dofs, levels, ε/κ, active points, Newton steps, CG iterations per direction (each, mean,
max) and the contraction per iteration they imply, ``rtol^(1/mean)``; a table at the end.

    .venv/bin/python benchmarks/multigrid_robustness.py --sizes 0.0058,0.0029,0.00145
    .venv/bin/mpiexec -n 2 .venv/bin/python benchmarks/multigrid_robustness.py --sizes 0.0058
"""

from __future__ import annotations

import argparse
import time

from mpi4py import MPI

import numpy as np
from record import PAPER, emit, timed_mesh

from shellobstacle.config.loader import load_config
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.linear.multigrid import SMOOTHERS, MultigridStrategy
from shellobstacle.solvers.newton.continuation import continuation
from shellobstacle.solvers.newton.solver import NewtonSolver


def main() -> None:
    """Solve every size down the κ ladder; print JSON lines and a table on rank 0."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", default="0.0058,0.0029,0.00145", help="gmsh target sizes")
    ap.add_argument(
        "--eps-over-kappa",
        default="0.01,0.1,1,10,100,1000,10000",
        help="the ladder, as ε/κ (decreasing κ)",
    )
    ap.add_argument("--rtol", type=float, default=1e-8, help="CG's relative tolerance")
    ap.add_argument(
        "--smoother", default="jacobi", choices=SMOOTHERS, help="Chebyshev's preconditioner"
    )
    args = ap.parse_args()
    comm = MPI.COMM_WORLD
    rows = []
    for size in (float(s) for s in args.sizes.split(",")):
        cfg = load_config(str(PAPER), [f"domain.h={size}"])
        eps = cfg.shell.material.epsilon
        kappas = [eps / float(r) for r in args.eps_over_kappa.split(",")]
        base: dict = {
            "gmsh_h": size, "ranks": comm.size, "rtol": args.rtol, "smoother": args.smoother
        }  # fmt: skip
        mesh, h = timed_mesh(cfg, base)
        problem = PenalizedProblem(cfg.shell, mesh, cfg.discretization, kappa=kappas[0])
        strategy = MultigridStrategy(
            args.rtol, forcing="fixed", smoother=args.smoother, finish=False
        )
        solver = NewtonSolver(problem, linear=strategy)  # (continuation: no nested iteration)
        active = ActivePoints(solver, comm)
        t0 = time.perf_counter()
        steps = continuation(problem, solver, kappas, newton_progress=active)
        base |= {"h": h, "dofs": problem.num_dofs, "levels": strategy.levels}
        base["continuation_s"] = time.perf_counter() - t0
        for step, points in zip(steps, active.counts, strict=True):
            its = step.newton.linear_iterations
            mean = float(np.mean(its))
            rec = base | {
                "kappa": step.kappa,
                "eps_over_kappa": eps / step.kappa,
                "active_points": points,
                "newton": step.newton.iterations,
                "cg_per_direction": its,
                "cg_mean": mean,
                "cg_max": int(max(its)),
                "contraction": args.rtol ** (1.0 / mean),
                "seconds": step.seconds,
            }
            emit(rec, comm)
            rows.append(rec)
        del solver, problem
    if comm.rank == 0:
        _table(rows)


class ActivePoints:
    """Newton's progress callback that counts the active penalty points at each κ's answer."""

    def __init__(self, solver: NewtonSolver, comm: MPI.Comm) -> None:
        self.solver, self.comm, self.counts = solver, comm, []

    def __call__(self, iteration: int, relative_residual: float) -> None:
        """(Nothing after each Newton step.)"""

    def finished(self, result: object) -> None:
        """A κ solved: count the points with ``g < 0`` (collective)."""
        local = int(np.count_nonzero(self.solver.system.g < 0))
        self.counts.append(self.comm.allreduce(local))


def _table(rows: list[dict]) -> None:
    """CG iterations per direction (mean, max) by dofs (rows) and ε/κ (columns)."""
    ratios = sorted({r["eps_over_kappa"] for r in rows})
    print("| dofs (levels) | " + " | ".join(f"ε/κ = {q:g}" for q in ratios) + " |")
    print("|---" * (len(ratios) + 1) + "|")
    for dofs in sorted({r["dofs"] for r in rows}):
        line = [r for r in rows if r["dofs"] == dofs]
        cells = {r["eps_over_kappa"]: f"{r['cg_mean']:.1f}, {r['cg_max']}" for r in line}
        print(
            f"| {dofs:,} ({line[0]['levels']}) | "
            + " | ".join(cells.get(q, "") for q in ratios)
            + " |"
        )


if __name__ == "__main__":
    main()
