"""Shared parts of the benchmark scripts: solver arguments, peak memory, one JSON line."""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import resource
import time
from pathlib import Path
from typing import Any

import shellobstacle.compat  # noqa: F401  (must precede dolfinx / petsc4py)

# isort: split
import dolfinx
from mpi4py import MPI

from shellobstacle.blas import gemmt_calls, gemmt_policy
from shellobstacle.checks import check_assumptions
from shellobstacle.config import Config
from shellobstacle.domains import mesh_size
from shellobstacle.memory import malloc_policy
from shellobstacle.pipeline import make_mesh
from shellobstacle.prefault import prefault_policy, prefaulted_gib
from shellobstacle.solvers.newton import NewtonOptions
from shellobstacle.threads import blas_threads


def petsc_blas() -> str:
    """The configuration string of the OpenBLAS that PETSc and MUMPS run on (``unknown``
    if none is loaded): it says whether the BLAS is threaded (``SINGLE_THREADED`` if not)."""
    try:
        lib = ctypes.CDLL("libopenblas.so.0", mode=getattr(os, "RTLD_NOLOAD", 0))
        lib.openblas_get_config.restype = ctypes.c_char_p
        return lib.openblas_get_config().decode()
    except (OSError, AttributeError):
        return "unknown"


# the paper's section 10 problem (MODEL.md §7), the configuration most benchmarks run
PAPER = Path(__file__).parents[1] / "src" / "shellobstacle" / "configs" / "paper.toml"


def emit(rec: dict[str, Any], comm: MPI.Comm) -> None:
    """Add the peak RSS and the CPU seconds (largest rank and sum over ranks), the BLAS of
    PETSc and the threads of NumPy's BLAS, and print ``rec`` on rank 0.

    CPU seconds (user + system, all threads, since the process started: imports included, and
    in a ladder every size so far) against the wall clock show how many cores a run kept busy.
    The system CPU seconds and the memory faulted in (minor page faults times the page size,
    GiB, summed over ranks) show what first touches of memory cost, and ``malloc`` whether
    freed memory was kept in the process (:mod:`shellobstacle.memory`); ``gemmt`` whether
    MUMPS ran on the blocked DGEMMT and ``gemmt_calls`` how many calls it took in blocks or
    passed to OpenBLAS (:mod:`shellobstacle.blas`); ``prefault`` whether a helper thread
    faulted the heap's new pages in and ``prefaulted_gib_total`` how much
    (:mod:`shellobstacle.prefault`).
    Floats keep 6 significant digits.
    """
    usage = resource.getrusage(resource.RUSAGE_SELF)
    rss, cpu = usage.ru_maxrss / 1024, usage.ru_utime + usage.ru_stime
    rec["peak_rss_mb_per_rank_max"] = comm.allreduce(rss, op=MPI.MAX)
    rec["peak_rss_mb_total"] = comm.allreduce(rss, op=MPI.SUM)
    rec["cpu_s_per_rank_max"] = comm.allreduce(cpu, op=MPI.MAX)
    rec["cpu_s_total"] = comm.allreduce(cpu, op=MPI.SUM)
    rec["cpu_sys_s_total"] = comm.allreduce(usage.ru_stime, op=MPI.SUM)
    faulted = usage.ru_minflt * resource.getpagesize() / 2**30
    rec["faulted_gib_total"] = comm.allreduce(faulted, op=MPI.SUM)
    rec["malloc"] = malloc_policy()
    rec["gemmt"] = gemmt_policy()
    rec["gemmt_calls"] = gemmt_calls()
    rec["prefault"] = prefault_policy()
    rec["prefaulted_gib_total"] = comm.allreduce(prefaulted_gib(), op=MPI.SUM)
    rec["petsc_blas"] = petsc_blas()
    rec["numpy_blas_threads"] = blas_threads()
    if comm.rank == 0:
        values = {k: float(f"{v:.6g}") if isinstance(v, float) else v for k, v in rec.items()}
        print(json.dumps(values), flush=True)


def add_solver_arguments(ap: argparse.ArgumentParser) -> None:
    """The linear-solver choices shared by the benchmarks."""
    ap.add_argument("--linear-solver", default="direct", choices=("direct", "iterative"))
    ap.add_argument("--no-reuse", action="store_true", help="factorize at every Newton step")
    ap.add_argument("--factorization", default="cholesky", choices=("cholesky", "lu"))
    ap.add_argument(
        "--forcing",
        default="eisenstat-walker",
        choices=("eisenstat-walker", "fixed"),
        help="iterative solver: CG tolerance per Newton step (inexact Newton, or linear_rtol "
        "at every step, the sixth session's solver)",
    )
    ap.add_argument(
        "--split-sweep",
        default="forward",
        choices=("forward", "symmetric"),
        help="iterative solver: one block Gauss-Seidel sweep with flexible CG, or the "
        "symmetric sweep with CG (the thirteenth session's solver)",
    )
    ap.add_argument(
        "--no-keep-multigrid",
        action="store_true",
        help="iterative solver: build GAMG at every κ's first step (the thirteenth session's "
        "solver) instead of keeping it while the ζ_α diagonal drifts by less than 5 %%",
    )
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
    iterative = args.linear_solver == "iterative"
    rec["forcing"] = args.forcing if iterative else None
    rec["split_sweep"] = args.split_sweep if iterative else None
    rec["keep_multigrid"] = not args.no_keep_multigrid if iterative else None
    rec["contact_zone"] = args.linear_solver == "direct" and not args.no_zone
    rec["zone_newton"] = rec["contact_zone"] and not args.no_zone_newton
    rec["omp_num_threads"] = os.environ.get("OMP_NUM_THREADS", "unset")
    return NewtonOptions(
        linear_solver=args.linear_solver,
        reuse_factorization=not args.no_reuse,
        factorization=args.factorization,
        forcing=args.forcing,
        contact_zone=not args.no_zone,
        zone_newton=not args.no_zone_newton,
        split_sweep=args.split_sweep,
        keep_multigrid=not args.no_keep_multigrid,
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
