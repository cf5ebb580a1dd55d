"""Shared parts of the benchmark scripts: solver arguments, peak memory, one JSON line."""

from __future__ import annotations

import argparse
import json
import os
import resource
import time
from typing import Any

import dolfinx
from mpi4py import MPI

from shellobstacle.checks import check_assumptions
from shellobstacle.config import Config
from shellobstacle.domains import mesh_size
from shellobstacle.pipeline import make_mesh
from shellobstacle.solvers.newton import NewtonOptions


def emit(rec: dict[str, Any], comm: MPI.Comm) -> None:
    """Add the peak RSS (largest rank and sum over ranks) and print ``rec`` on rank 0.

    Floats keep 6 significant digits.
    """
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    rec["peak_rss_mb_per_rank_max"] = comm.allreduce(rss, op=MPI.MAX)
    rec["peak_rss_mb_total"] = comm.allreduce(rss, op=MPI.SUM)
    if comm.rank == 0:
        values = {k: float(f"{v:.6g}") if isinstance(v, float) else v for k, v in rec.items()}
        print(json.dumps(values), flush=True)


def add_solver_arguments(ap: argparse.ArgumentParser) -> None:
    """The linear-solver choices shared by the benchmarks."""
    ap.add_argument("--linear-solver", default="direct", choices=("direct", "iterative"))
    ap.add_argument("--no-reuse", action="store_true", help="factorize at every Newton step")
    ap.add_argument("--factorization", default="lu", choices=("lu", "cholesky"))
    ap.add_argument(
        "--no-zone",
        action="store_true",
        help="direct solver without the contact-zone condensation (one factorization per κ "
        "reused by CG, the second session's solver)",
    )
    ap.add_argument(
        "--no-zone-newton",
        action="store_true",
        help="contact zone, but full Newton steps (one back-substitution each) instead of steps "
        "on the zone's own problem (the third session's solver)",
    )


def solver_options(args: argparse.Namespace, rec: dict[str, Any]) -> NewtonOptions:
    """The Newton options the arguments ask for; records them (and OMP_NUM_THREADS) in ``rec``."""
    rec["linear_solver"] = args.linear_solver
    rec["reuse_factorization"] = not args.no_reuse
    rec["factorization"] = args.factorization
    rec["contact_zone"] = args.linear_solver == "direct" and not args.no_zone
    rec["zone_newton"] = rec["contact_zone"] and not args.no_zone_newton
    rec["omp_num_threads"] = os.environ.get("OMP_NUM_THREADS", "unset")
    return NewtonOptions(
        linear_solver=args.linear_solver,
        reuse_factorization=not args.no_reuse,
        factorization=args.factorization,
        contact_zone=not args.no_zone,
        zone_newton=not args.no_zone_newton,
    )


def timed_mesh(cfg: Config, rec: dict[str, Any]) -> tuple[dolfinx.mesh.Mesh, float]:
    """The config's mesh and its h; records the seconds of meshing and of the checks."""
    t = time.perf_counter()
    mesh = make_mesh(cfg.domain)
    h = mesh_size(mesh)
    rec["mesh_s"] = time.perf_counter() - t
    t = time.perf_counter()
    check_assumptions(cfg.shell, mesh)
    rec["checks_s"] = time.perf_counter() - t
    return mesh, h
