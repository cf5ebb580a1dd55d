"""The nodal problem's solvers side by side, in one process: the active-set solver, the
default Newton continuation, PETSc's VI Newton (rsls, ssls) and proximal Galerkin.

For each gmsh target size the mesh is made once; every method then builds its own problem
(the forms compiled before its clock starts) and solver, and is timed from the solver's
set-up (stiffness, ``K' = QᵀKQ``, …) to its answer. The nodal methods solve the exact nodal
problem (κ = 0, the constraint at the vertices); ``newton`` is the package's default path on
the config's own discretization: the continuation over ``penalty.ladder(h)`` (the paper's
config: κ = h^0.5, h, h^1.5, the penalty at Gauss points), so its distance to the nodal
solution is the penalty's and the quadrature's, not a solver error. One JSON line per method
and size on rank 0: iterations (linear solves; Newton: steps over all κ, with its large
factorizations and its steps on the contact zone per κ), seconds, the
method's peak RSS (the kernel's high-water mark reset before it starts, ``VmHWM``; largest
rank and sum) and its rise over the RSS at the start (which holds the heap of the earlier
methods: freed objects stay in the allocator's pools), MUMPS' memory of its last
factorization, dofs, the relative KKT measures and
the distance to the active-set solution (Euclidean norms of the nodal vectors); the load
average of the machine with every line. With ``--repeat N`` every method runs N times per
size, in rounds (all methods, then all again), and ``seconds`` is the median of
``seconds_all`` (the other fields are the last round's). A last line per method: the slope
of iterations against h (``iterations ∝ h^slope``, fitted over the sizes).

    .venv/bin/python benchmarks/peers.py --sizes 0.02,0.014,0.01
    .venv/bin/python benchmarks/peers.py --config examples/paraboloid.toml --sizes 0.04,0.02
    .venv/bin/python benchmarks/peers.py --methods active-set,snes-vi:ssls:l2 --sizes 0.01

An untimed round on a coarse mesh (``--warmup``) comes first, so that no method pays for
loading libraries or compiling forms. Methods: ``active-set``, ``newton``,
``snes-vi:<rsls|ssls>:<l2|bt|basic>``, ``proximal-galerkin[:mixed]``. Results go to
``--out`` (default ``docs/perf/peers/<config>.jsonl``, replaced) and to standard output.
"""

from __future__ import annotations

# isort: split
import record  # the DOLFINx wheel's bootstrap before PETSc and DOLFINx

# isort: split
import argparse
import dataclasses
import gc
import json
import math
import os
import re
import time
from pathlib import Path
from typing import Any

from mpi4py import MPI

import numpy as np

from shellobstacle.api import make_mesh, nodal_solver
from shellobstacle.config.loader import Config, load_config
from shellobstacle.experiments.common import fit_rate
from shellobstacle.mesh.measures import mesh_size
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.base import ConvergenceError
from shellobstacle.solvers.newton.continuation import continuation
from shellobstacle.solvers.newton.solver import NewtonSolver
from shellobstacle.solvers.vi.options import (
    ActiveSetOptions,
    ProximalGalerkinOptions,
    SnesVIOptions,
)

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_METHODS = "active-set,newton,snes-vi:rsls:l2,snes-vi:ssls:l2,proximal-galerkin"


def memory_mb(field: str) -> float:
    """``VmHWM`` (peak) or ``VmRSS`` (now) of this process, MB (0 where /proc lacks it)."""
    try:
        text = Path("/proc/self/status").read_text()
    except OSError:
        return 0.0
    found = re.search(rf"^{field}:\s+(\d+) kB", text, re.M)
    return int(found.group(1)) / 1024 if found else 0.0


def reset_peak() -> bool:
    """Reset the kernel's high-water mark of the resident set (Linux ≥ 4.0)."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def method_options(spec: str, cfg: Config) -> tuple[str, Any]:
    """``(method, options)`` of a method spec such as ``snes-vi:ssls:l2``."""
    name, *rest = spec.split(":")
    factorization = cfg.solver.factorization
    if name == "active-set":
        return name, ActiveSetOptions()
    if name == "snes-vi":
        vi_type, line_search = (rest + ["rsls", "l2"][len(rest) :])[:2]
        return name, SnesVIOptions(
            vi_type=vi_type, line_search=line_search, factorization=factorization
        )
    if name == "proximal-galerkin":
        system = rest[0] if rest else "condensed"
        return name, ProximalGalerkinOptions(linear_system=system, factorization=factorization)
    if name == "newton":
        return name, cfg.solver
    raise SystemExit(f"unknown method {spec!r}")


def owned(problem: PenalizedProblem) -> np.ndarray:
    """The owned dofs of ``ζ`` (the nodal vector the distances are taken of)."""
    V = problem.V
    return problem.zeta.x.array[: V.dofmap.index_map.size_local * V.dofmap.index_map_bs].copy()


def norm(x: np.ndarray, comm: MPI.Comm) -> float:
    return math.sqrt(comm.allreduce(float(np.dot(x, x)), op=MPI.SUM))


def run_method(
    spec: str, cfg: Config, mesh: Any, h: float, reference: np.ndarray | None
) -> tuple[dict[str, Any], np.ndarray]:
    """One method on one mesh: its record and its solution's owned dofs."""
    comm = mesh.comm
    method, options = method_options(spec, cfg)
    rec: dict[str, Any] = {"method": spec}
    disc = cfg.discretization
    if method != "newton" and disc.degree == 1:  # the nodal constraint: P1's vertex penalty
        disc = dataclasses.replace(disc, penalty_quadrature="vertex")
    t = time.perf_counter()
    problem = PenalizedProblem(cfg.shell, mesh, disc)  # forms compiled: outside the clock
    rec["compile_s"] = time.perf_counter() - t
    rec["dofs"] = problem.num_dofs
    gc.collect()
    comm.barrier()
    memory_mb_before = memory_mb("VmRSS")
    rec["rss_before_mb"] = comm.allreduce(memory_mb_before, op=MPI.MAX)
    peak_reset = reset_peak()
    t0 = time.perf_counter()
    try:
        if method == "newton":
            kappas = cfg.penalty.ladder(h)
            solver = NewtonSolver(problem, options)
            rec["setup_s"] = time.perf_counter() - t0
            steps = continuation(problem, solver, kappas)
            rec["iterations"] = sum(s.iterations for s in steps)
            rec["per_kappa"] = [s.iterations for s in steps]
            rec["factorizations"] = [s.newton.factorizations for s in steps]
            rec["zone_steps"] = [s.newton.zone_steps for s in steps]
            rec["kappa"] = kappas[-1]
            rec["converged"] = True
        else:
            solver = nodal_solver(problem, method, options)
            rec["setup_s"] = time.perf_counter() - t0
            try:
                result = solver.solve()
            except ConvergenceError as err:
                result = err.result
            rec |= {
                "iterations": result.iterations,
                "converged": result.converged,
                "reason": result.reason,
                "active_nodes": result.active_nodes,
                "kkt_relative_max": max(result.relative_kkt.values()),
                "factor_mb": result.factor_mb,
            }
            for key in ("proximal_steps", "rejected_steps", "snes_reason"):
                if hasattr(result, key):
                    rec[key] = getattr(result, key)
    except ConvergenceError as err:  # Newton's continuation
        rec["converged"], rec["reason"] = False, str(err)
    rec["seconds"] = time.perf_counter() - t0
    rec["solve_s"] = rec["seconds"] - rec.get("setup_s", 0.0)
    peak = memory_mb("VmHWM") if peak_reset else float("nan")
    rec["peak_rss_mb_per_rank_max"] = comm.allreduce(peak, op=MPI.MAX)
    rec["peak_rss_mb_total"] = comm.allreduce(peak, op=MPI.SUM)
    rec["peak_increase_mb_total"] = comm.allreduce(peak - memory_mb_before, op=MPI.SUM)
    z = owned(problem)
    if reference is not None:
        rec["distance_to_active_set"] = norm(z - reference, comm) / norm(reference, comm)
    del solver, problem
    gc.collect()
    return rec, z


def emit(rec: dict[str, Any], comm: MPI.Comm, out: Any) -> None:
    """Print ``rec`` (6 significant digits, NaN as null) on rank 0 and append it to ``out``."""
    if comm.rank == 0:
        values = {
            k: (None if math.isnan(v) else float(f"{v:.6g}")) if isinstance(v, float) else v
            for k, v in rec.items()
        }
        line = json.dumps(values)
        print(line, flush=True)
        if out is not None:
            out.write(line + "\n")
            out.flush()


def main(argv: list[str] | None = None) -> int:
    """Run every method at every size; JSON lines on rank 0."""
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    ap.add_argument("--config", type=Path, default=record.PAPER)
    ap.add_argument("--sizes", default="0.02,0.014,0.01", help="gmsh targets (domain.h)")
    ap.add_argument("--methods", default=DEFAULT_METHODS)
    ap.add_argument("--out", type=Path, default=None, help="default docs/perf/peers/<config>")
    ap.add_argument("--repeat", type=int, default=1, help="rounds of every method per size")
    ap.add_argument(
        "--warmup",
        type=float,
        default=0.05,
        help="gmsh target of an untimed first round of every method (libraries loaded, forms "
        "compiled); 0: none",
    )
    args = ap.parse_args(argv)
    comm = MPI.COMM_WORLD
    specs = args.methods.split(",")
    if "active-set" in specs:  # the reference runs first
        specs.remove("active-set")
        specs.insert(0, "active-set")
    path = args.out or ROOT / "docs" / "perf" / "peers" / f"{args.config.stem}.jsonl"
    out = None
    if comm.rank == 0:
        path.parent.mkdir(parents=True, exist_ok=True)
        out = path.open("w")
    rows: dict[str, list[tuple[float, int]]] = {s: [] for s in specs}
    if args.warmup > 0:
        cfg = load_config(args.config, [f"domain.h={args.warmup}"])
        mesh = make_mesh(cfg.domain, ghosted=cfg.shell.model == "koiter")
        for spec in specs:
            run_method(spec, cfg, mesh, mesh_size(mesh), None)
    for size in (float(s) for s in args.sizes.split(",")):
        cfg = load_config(args.config, [f"domain.h={size}"])
        t = time.perf_counter()
        mesh = make_mesh(cfg.domain, ghosted=cfg.shell.model == "koiter")
        h = mesh_size(mesh)
        base = {
            "config": args.config.name,
            "target": size,
            "h": h,
            "mesh_s": time.perf_counter() - t,
            "ranks": comm.size,
        }
        reference = None
        records: dict[str, list[dict[str, Any]]] = {spec: [] for spec in specs}
        for _ in range(args.repeat):  # rounds of every method: a load spike hits them alike
            for spec in specs:
                load = os.getloadavg()[0]
                rec, z = run_method(spec, cfg, mesh, h, reference)
                if spec == "active-set" and reference is None and rec.get("converged"):
                    reference = z
                after = os.getloadavg()[0]
                records[spec].append(rec | {"load_average": load, "load_average_after": after})
        for spec in specs:
            rec = base | records[spec][-1]
            seconds = [r["seconds"] for r in records[spec]]
            rec["seconds_all"], rec["seconds"] = seconds, float(np.median(seconds))
            emit(rec, comm, out)
            if rec.get("converged"):
                rows[spec].append((h, rec["iterations"]))
        del mesh
        gc.collect()
    for spec, points in rows.items():
        slope = fit_rate(*zip(*points, strict=True)) if len(points) > 1 else float("nan")
        emit({"method": spec, "iterations_slope_vs_h": slope, "sizes": len(points)}, comm, out)
    if out is not None:
        out.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
