"""Phase timings of one solve of the paper's problem over a ladder of mesh sizes.

For each gmsh target size: mesh, geometry checks, compilation, the continuation to
κ = h^1.5 (Newton steps; assembly, linear solves, line search), post-processing and output
(ParaView + figure), dofs and peak RSS. One JSON line per size on rank 0.

    .venv/bin/python benchmarks/ladder.py --sizes 0.02,0.01,0.005,0.0035
    .venv/bin/mpiexec -n 2 .venv/bin/python benchmarks/ladder.py --sizes 0.01,0.005
    .venv/bin/python benchmarks/ladder.py --linear-solver iterative --sizes 0.01,0.005

``compile_s`` includes the solver's set-up (``newton_setup_s``: the membrane stiffness K and
the penalty's point matrix M, assembled once per mesh).
"""

from __future__ import annotations

import argparse
import gc
import tempfile
import time
from pathlib import Path

from mpi4py import MPI

from record import PAPER, add_solver_arguments, emit, solver_options, timed_mesh

from shellobstacle.config.loader import load_config
from shellobstacle.io.paraview import write_paraview
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.contact import Postprocessor
from shellobstacle.post.plotting import plot_cross_section
from shellobstacle.solvers.newton.continuation import continuation
from shellobstacle.solvers.newton.solver import NewtonSolver


def main() -> None:
    """Run the ladder and print JSON lines on rank 0."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--sizes", default="0.02,0.01,0.005")
    add_solver_arguments(ap)
    ap.add_argument("--exponent", type=float, default=1.5)
    ap.add_argument("--no-output", action="store_true", help="skip ParaView/figure output")
    args = ap.parse_args()
    comm = MPI.COMM_WORLD
    for size in (float(s) for s in args.sizes.split(",")):
        emit(run_size(size, args, comm), comm)
        # free the previous size's solver (MUMPS factors, meshes) before the next size: its
        # objects hold reference cycles that only the collector frees. The largest size's
        # peak RSS is still 1.0-1.5 GB above that of a run of that size alone (the heap of
        # the earlier sizes): one-solve figures come
        # from single-size runs.
        gc.collect()


def run_size(size: float, args: argparse.Namespace, comm: MPI.Comm) -> dict:
    """One rung of the ladder: mesh, set-up, continuation, post-processing and output."""
    cfg = load_config(PAPER, [f"domain.h={size}"])
    rec: dict = {"target": size, "ranks": comm.size}
    options, linear = solver_options(args, rec)
    mesh, h = timed_mesh(cfg, rec)
    t = time.perf_counter()
    problem = PenalizedProblem(cfg.shell, mesh, cfg.discretization)
    solver = NewtonSolver(problem, options, linear)
    rec["compile_s"] = time.perf_counter() - t
    kappas = [h**q for q in (0.5, 1.0, args.exponent)]
    t = time.perf_counter()
    steps = continuation(problem, solver, kappas)
    rec["continuation_s"] = time.perf_counter() - t
    rec |= {f"newton_{k}_s": v for k, v in solver.timings.items()}
    rec["newton"] = [s.iterations for s in steps]
    rec["factorizations"] = [s.newton.factorizations for s in steps]
    rec["zone_steps"] = [s.newton.zone_steps for s in steps]
    rec["zone"] = solver.zone.sizes if solver.zone is not None else None
    rec["linear_iterations"] = [s.newton.linear_iterations for s in steps]
    rec["multigrid_builds"] = getattr(solver.linear, "multigrid_builds", None)
    t = time.perf_counter()
    post = Postprocessor(problem)
    summary = post.summary()
    rec["postprocess_s"] = time.perf_counter() - t
    if not args.no_output:
        t = time.perf_counter()
        folder = Path(comm.bcast(tempfile.mkdtemp() if comm.rank == 0 else None))
        write_paraview(problem, post, folder)
        plot_cross_section([("κ", post.cross_section())], problem.q, folder / "x.png")
        rec["output_s"] = time.perf_counter() - t
    rec |= {"h": h, "dofs": problem.num_dofs, "contact_area": summary["contact_area"]}
    return rec


if __name__ == "__main__":
    main()
