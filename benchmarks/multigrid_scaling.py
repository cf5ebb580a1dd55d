"""The paper's problem (κ = h^1.5 continuation) by the direct path and by multigrid, as h halves.

For each gmsh size and each linear solver: one solve from the config (examples/paper.toml, or
``--config``, with ``domain.h`` and ``solver.linear_solver`` set), then one JSON line with the
dofs, the mesh levels multigrid used, Newton steps (per κ and in all), Krylov iterations per
Newton step (mean and max over the steps; the direct path's are the CG iterations with a kept
factorization or on the contact zone), the continuation's seconds and phases (``solve.*``:
set-up, multigrid's part of it, assembly, linear solves, line searches, ...), the process' CPU
seconds end to end (less sensitive than the wall clock to other jobs on the cores), the
contact area and its relative difference to the direct path's, peak RSS of the process so far
and the load average before and after (the machine may be shared: the times are as noisy as
that). A table follows at the end. A solver named with ``+nested`` (``multigrid+nested``) sets
``solver.nested_iteration``: its Newton steps are the finest level's, the coarser levels'
in ``nested_levels``. The peak RSS is the process' high-water mark: put the
solver that needs less memory first (``--solvers multigrid,direct``) for both figures to be
each solver's own.

    .venv/bin/python benchmarks/multigrid_scaling.py --sizes 0.0058,0.0029,0.00145
    .venv/bin/mpiexec -n 2 .venv/bin/python benchmarks/multigrid_scaling.py --sizes 0.0058
    .venv/bin/python benchmarks/multigrid_scaling.py --sizes 0.0012 \
        --solvers multigrid+nested,multigrid,direct
    .venv/bin/python benchmarks/multigrid_scaling.py --sizes 0.0006 --solvers multigrid
    .venv/bin/python benchmarks/multigrid_scaling.py --config examples/ellipsoid.toml \
        --sizes 0.00125 --solvers multigrid
    .venv/bin/python benchmarks/multigrid_scaling.py --config examples/cylinder_koiter.toml \
        --sizes 0.02 --refinements 1,2,3 --solvers multigrid,direct
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time

from mpi4py import MPI

import numpy as np

from shellobstacle.api import solve
from shellobstacle.config.loader import load_config
from shellobstacle.mesh.domains import coarsening_steps
from shellobstacle.post.contact import Postprocessor
from shellobstacle.solvers.newton.options import LINEAR_SOLVERS

PAPER = "examples/paper.toml"


def run(
    h: float,
    linear_solver: str,
    force: bool = False,
    config: str = PAPER,
    refinements: int | None = None,
) -> dict:
    """One solve of ``config``'s problem at gmsh size ``h`` with ``linear_solver`` (``force``:
    without the check of the machine's memory, whose estimate is the direct path's;
    ``refinements``: uniform refinements of that mesh, else the config's)."""
    comm = MPI.COMM_WORLD
    solver, nested = linear_solver.removesuffix("+nested"), linear_solver.endswith("+nested")
    refine = [] if refinements is None else [f"domain.refinements={refinements}"]
    cfg = load_config(
        config,
        [
            f"domain.h={h}",
            f'solver.linear_solver="{solver}"',
            f'solver.nested_iteration="{"on" if nested else "off"}"',
            *refine,
        ],
    )
    load = os.getloadavg()[0]
    t0, c0 = time.perf_counter(), time.process_time()
    result = solve(cfg, force=force)
    seconds, cpu = time.perf_counter() - t0, time.process_time() - c0
    area = Postprocessor(result.problem).contact()["contact_area"]
    newton = [s.iterations for s in result.steps]
    krylov = [n for s in result.steps for n in s.record.linear_iterations]
    return {
        "config": config,
        "h": h,
        "linear_solver": linear_solver,
        "ranks": comm.size,
        "dofs": result.problem.num_dofs,
        "mesh_levels": coarsening_steps(cfg.domain) + cfg.domain.refinements + 1,
        "converged": result.converged,
        "newton_per_kappa": newton,
        "newton": sum(newton),
        "krylov_per_step_mean": round(float(np.mean(krylov)), 2),
        "krylov_per_step_max": int(max(krylov)),
        "krylov_per_kappa": [s.record.linear_iterations for s in result.steps],
        "solve_s": round(result.timings.get("solve", float("nan")), 2),
        "end_to_end_s": round(seconds, 2),
        "end_to_end_cpu_s": round(cpu, 2),
        "phases_s": {k: round(v, 2) for k, v in result.timings.items() if k.startswith("solve.")},
        "contact_area": area,
        "nested_levels": [
            {k: round(v, 2) if isinstance(v, float) else v for k, v in level.items()}
            for level in result.extra.get("nested_iteration", {}).get("levels", [])
        ],
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024,
        "load_before": round(load, 2),
        "load_after": round(os.getloadavg()[0], 2),
    }


def main() -> None:
    """Run the sizes and solvers, print JSON lines and a table on rank 0."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--config", default=PAPER, help="the problem's config file")
    ap.add_argument("--sizes", default="0.0058,0.0029,0.00145", help="gmsh target sizes")
    ap.add_argument(
        "--refinements",
        default=None,
        help="uniform refinements of each size's mesh, comma-separated (a rectangle's levels; "
        "default: the config's)",
    )
    ap.add_argument(
        "--solvers",
        default="direct,multigrid",
        help=f"of {LINEAR_SOLVERS}, each with +nested for nested iteration (multigrid+nested)",
    )
    ap.add_argument(
        "--force",
        action="store_true",
        help="solve even where the memory estimate of the linear solver exceeds 80 %% of this "
        "machine's memory",
    )
    args = ap.parse_args()
    comm = MPI.COMM_WORLD
    rows = []
    refinements = [None] if args.refinements is None else args.refinements.split(",")
    sizes = [
        (float(h), None if n is None else int(n))
        for h in args.sizes.split(",")
        for n in refinements
    ]
    for h, refine in sizes:
        solvers = args.solvers.split(",")
        pair = [run(h, solver, args.force, args.config, refine) for solver in solvers]
        direct = [r["contact_area"] for r in pair if r["linear_solver"].startswith("direct")]
        for row in pair:
            if direct:
                row["area_vs_direct"] = abs(row["contact_area"] - direct[0]) / direct[0]
            if comm.rank == 0:
                print(json.dumps(row), flush=True)
        rows += pair
    if comm.rank == 0:
        print(
            "| dofs | solver | Newton steps (per κ) | Krylov its/step (mean, max) | solve s "
            "| contact area | peak RSS GB |"
        )
        print("|---:|---|---:|---:|---:|---:|---:|")
        for r in rows:
            per_kappa = "/".join(str(n) for n in r["newton_per_kappa"])
            print(
                f"| {r['dofs']:,} | {r['linear_solver']} | {r['newton']} ({per_kappa}) | "
                f"{r['krylov_per_step_mean']:.1f}, {r['krylov_per_step_max']} | "
                f"{r['solve_s']:.1f} | {r['contact_area']:.7f} | {r['peak_rss_mb'] / 1024:.2f} |"
            )


if __name__ == "__main__":
    main()
