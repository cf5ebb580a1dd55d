"""Batch 1 of the paper (docs/model.md §7) end to end, timed by phase: the issue's headline figure.

Mesh (gmsh), geometry checks, compilation and solver set-up, then the κ-sweep κ = h^q,
q = 0.5, 1.0, …, q_max (each κ warm-started from the previous one, with the Cauchy
differences of batch 1 computed as the experiment does), for one penalty quadrature.
Prints one JSON line on rank 0: phase seconds, Newton steps, factorizations and CG
iterations per κ, dofs, h, peak RSS.

    .venv/bin/python benchmarks/batch1.py --target 0.0029
    .venv/bin/mpiexec -n 2 .venv/bin/python benchmarks/batch1.py --target 0.0029
"""

from __future__ import annotations

import argparse
import time

from mpi4py import MPI

from record import PAPER, add_solver_arguments, emit, solver_options, timed_mesh

from shellobstacle.config.loader import load_config
from shellobstacle.experiments.penalty import PenaltyStudyOptions, penalty_study
from shellobstacle.spec import Discretization


def main() -> None:
    """Run batch 1 once and print a JSON line on rank 0."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--target", type=float, default=0.0029, help="gmsh target mesh size")
    ap.add_argument("--qmax", type=float, default=2.0)
    ap.add_argument("--quadrature", default="gauss", choices=("gauss", "vertex"))
    add_solver_arguments(ap, strategies=False)
    args = ap.parse_args()
    comm = MPI.COMM_WORLD
    t_all = time.perf_counter()
    cfg = load_config(PAPER, [f"domain.h={args.target}"])
    rec: dict = {"benchmark": "batch1", "target": args.target, "ranks": comm.size}
    rec["quadrature"] = args.quadrature
    newton, _ = solver_options(args, rec)
    mesh, h = timed_mesh(cfg, rec)
    t = time.perf_counter()
    study = penalty_study(
        cfg.shell,
        mesh,
        Discretization(penalty_quadrature=args.quadrature),
        PenaltyStudyOptions(q_max=args.qmax),
        newton,
    )
    rec["study_s"] = time.perf_counter() - t  # compile + set-up + sweep + differences
    rec["total_s"] = time.perf_counter() - t_all
    rec["h"], rec["dofs"] = h, study.dofs
    rec["q"] = [s["q"] for s in study.solves]
    rec["newton"] = [s["newton"] for s in study.solves]
    rec["newton_mean_after_first"] = study.mean_newton()
    for key in ("factorizations", "linear_iterations", "seconds"):
        rec[key] = [s.get(key) for s in study.solves]
    rec["timings"] = study.timings
    rec["error_VM"] = [r["error_VM"] for r in study.rows]
    emit(rec, comm)


if __name__ == "__main__":
    main()
