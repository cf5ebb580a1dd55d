"""Multigrid on a mesh without coarser levels: the algebraic fallback (GAMG) measured.

``solver.linear_solver = "multigrid"`` (and ``"auto"`` where only multigrid's memory estimate
fits) uses PETSc's GAMG when the mesh has no known hierarchy (a mesh read from a file, an
adapted mesh). This solves the config's problem (examples/paper.toml by default) at gmsh size
``--size`` with the mesh's levels limited to ``--levels`` (1: none, GAMG), the solver's
other options from the config. One JSON line: dofs, the levels used, Newton steps and CG
iterations per κ, the continuation's seconds and phases, peak RSS, contact area.

    .venv/bin/python benchmarks/gamg_fallback.py --size 0.0029
    .venv/bin/python benchmarks/gamg_fallback.py --size 0.00145 --levels 4
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import resource
import time

from shellobstacle.api import make_mesh
from shellobstacle.config.loader import load_config
from shellobstacle.mesh.measures import mesh_size
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.post.contact import Postprocessor
from shellobstacle.solvers.linear.multigrid import MultigridStrategy
from shellobstacle.solvers.newton.continuation import continuation
from shellobstacle.solvers.newton.solver import NewtonSolver


def main() -> None:
    """One solve, one JSON line."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--config", default="examples/paper.toml", help="the problem's config")
    ap.add_argument("--size", type=float, required=True, help="gmsh target size")
    ap.add_argument("--levels", type=int, default=1, help="the most mesh levels (1: GAMG)")
    args = ap.parse_args()
    cfg = load_config(args.config, [f"domain.h={args.size}"])
    mesh = make_mesh(cfg.domain)
    kappas = cfg.penalty.ladder(mesh_size(mesh))
    t0 = time.perf_counter()
    problem = PenalizedProblem(cfg.shell, mesh, cfg.discretization, kappa=kappas[0])
    options = dataclasses.replace(cfg.solver, linear_solver="multigrid")
    linear = MultigridStrategy(options.linear_rtol, levels=args.levels)
    solver = NewtonSolver(problem, options, linear=linear)
    steps = continuation(problem, solver, kappas)
    seconds = time.perf_counter() - t0
    row = {
        "config": args.config,
        "h": args.size,
        "dofs": problem.num_dofs,
        "levels": linear.levels,
        "newton_per_kappa": [s.iterations for s in steps],
        "krylov_per_kappa": [s.record.linear_iterations for s in steps],
        "solve_s": round(seconds, 2),
        "phases_s": {k: round(v, 2) for k, v in solver.timings.items()},
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024,
        "contact_area": Postprocessor(problem).contact()["contact_area"],
    }
    if mesh.comm.rank == 0:
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
