# ruff: noqa: E402  (the DOLFINx wheel's bootstrap must come before dolfinx and PETSc)
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

from mpi4py import MPI

import blocked_gemmt

from shellobstacle.compat import bootstrap

# the benchmarks run as the ``shellobstacle`` command does (import this module first); the
# process tuning is the environment's (docs/user-guide.md, "Process tuning")
bootstrap()

# isort: split

import dolfinx

from shellobstacle.api import make_mesh
from shellobstacle.checks.assumptions import check_assumptions
from shellobstacle.config.loader import Config
from shellobstacle.io.records import process_environment
from shellobstacle.mesh.measures import mesh_size
from shellobstacle.solvers.linear import LinearStrategy
from shellobstacle.solvers.linear.direct import DirectStrategy
from shellobstacle.solvers.linear.iterative import IterativeStrategy
from shellobstacle.solvers.linear.zone import ZoneStrategy
from shellobstacle.solvers.newton.solver import NewtonOptions


def petsc_blas() -> str:
    """The configuration string of the OpenBLAS that PETSc and MUMPS run on (``unknown``
    if none is loaded): it says whether the BLAS is threaded (``SINGLE_THREADED`` if not)."""
    try:
        lib = ctypes.CDLL("libopenblas.so.0", mode=getattr(os, "RTLD_NOLOAD", 0))
        lib.openblas_get_config.restype = ctypes.c_char_p
        return lib.openblas_get_config().decode()
    except (OSError, AttributeError):
        return "unknown"


def numpy_blas_threads() -> list[int]:
    """The threads of each BLAS NumPy loaded (threadpoolctl)."""
    from threadpoolctl import threadpool_info

    return [p["num_threads"] for p in threadpool_info() if "numpy" in p["filepath"]]


# the paper's section 10 problem (docs/model.md §7), the configuration most benchmarks run
PAPER = Path(__file__).parents[1] / "src" / "shellobstacle" / "configs" / "paper.toml"


def emit(rec: dict[str, Any], comm: MPI.Comm) -> None:
    """Add the peak RSS and the CPU seconds (largest rank and sum over ranks), the BLAS of
    PETSc and the threads of NumPy's BLAS, and print ``rec`` on rank 0.

    CPU seconds (user + system, all threads, since the process started: imports included, and
    in a ladder every size so far) against the wall clock show how many cores a run kept busy.
    The system CPU seconds and the memory faulted in (minor page faults times the page size,
    GiB, summed over ranks) show what first touches of memory cost; ``environment`` the
    variables of the process tuning that were set (``io.records.process_environment``),
    ``blocked_gemmt_calls`` the DGEMMT calls of ``blocked_gemmt.py`` (None: not loaded).
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
    rec["environment"] = process_environment()
    rec["blocked_gemmt_calls"] = blocked_gemmt.calls()
    rec["petsc_blas"] = petsc_blas()
    rec["openblas_num_threads"] = os.environ.get("OPENBLAS_NUM_THREADS", "unset")
    rec["numpy_blas_threads"] = numpy_blas_threads()
    if comm.rank == 0:
        values = {k: float(f"{v:.6g}") if isinstance(v, float) else v for k, v in rec.items()}
        print(json.dumps(values), flush=True)


def add_solver_arguments(ap: argparse.ArgumentParser, strategies: bool = True) -> None:
    """The linear-solver choices shared by the benchmarks (``strategies``: also the knobs of
    the linear strategies, for scripts that build the solver themselves)."""
    ap.add_argument("--linear-solver", default="direct", choices=("direct", "iterative"))
    ap.add_argument("--factorization", default="cholesky", choices=("cholesky", "lu"))
    ap.add_argument(
        "--no-zone",
        action="store_true",
        help="direct solver without the contact-zone condensation (one factorization per κ "
        "reused by CG)",
    )
    if not strategies:
        return
    ap.add_argument("--no-reuse", action="store_true", help="factorize at every Newton step")
    ap.add_argument(
        "--forcing",
        default="eisenstat-walker",
        choices=("eisenstat-walker", "fixed"),
        help="iterative solver: CG tolerance per Newton step (inexact Newton, or linear_rtol "
        "at every step)",
    )
    ap.add_argument(
        "--no-zone-newton",
        action="store_true",
        help="contact zone, but full Newton steps (one back-substitution each) instead of steps "
        "on the zone's own problem",
    )


def solver_options(
    args: argparse.Namespace, rec: dict[str, Any]
) -> tuple[NewtonOptions, LinearStrategy | None]:
    """The Newton options and linear strategy (None: the options' own) the arguments ask for;
    records them (and OMP_NUM_THREADS) in ``rec``."""
    iterative = args.linear_solver == "iterative"
    no_reuse = getattr(args, "no_reuse", False)
    forcing = getattr(args, "forcing", "eisenstat-walker")
    zone_newton = not getattr(args, "no_zone_newton", False)
    rec["linear_solver"] = args.linear_solver
    rec["factorization"] = args.factorization
    rec["contact_zone"] = not iterative and not args.no_zone
    rec["reuse_factorization"] = not no_reuse if not iterative else None
    rec["forcing"] = forcing if iterative else None
    rec["zone_newton"] = rec["contact_zone"] and zone_newton
    rec["omp_num_threads"] = os.environ.get("OMP_NUM_THREADS", "unset")
    options = NewtonOptions(
        linear_solver=args.linear_solver,
        factorization=args.factorization,
        contact_zone=not args.no_zone,
    )
    linear: LinearStrategy | None = None
    if iterative and forcing != "eisenstat-walker":
        linear = IterativeStrategy(options.linear_rtol, forcing=forcing)
    elif rec["contact_zone"] and not zone_newton:
        linear = ZoneStrategy(options.factorization, options.linear_rtol, reduced=False)
    elif not iterative and args.no_zone and no_reuse:
        linear = DirectStrategy(options.factorization, options.linear_rtol, reuse=False)
    return options, linear


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
