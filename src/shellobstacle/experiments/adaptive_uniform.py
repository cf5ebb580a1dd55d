"""The uniform sequence of the adaptive study (:mod:`shellobstacle.experiments.adaptive`):
red refinements of the first mesh, each solved like ``solve`` solves it, estimated, and
compared with the reference."""

from __future__ import annotations

import logging
import time
from typing import Any

from mpi4py import MPI  # noqa: F401  (MPI before dolfinx)

import dolfinx

from shellobstacle.adapt.estimator import ErrorEstimator
from shellobstacle.config.loader import Config
from shellobstacle.io.checkpoint import Checkpoint
from shellobstacle.mesh.measures import mesh_size, mesh_size_min
from shellobstacle.mesh.refinement import refine_uniformly
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.penalty.kappa import kappa_on_mesh
from shellobstacle.post.nonmatching import SampledNorms
from shellobstacle.solvers.linearization import solve_with
from shellobstacle.solvers.registry import METHODS, options_for
from shellobstacle.solvers.result import ConvergenceError

__all__ = ["uniform_sequence"]

log = logging.getLogger(__name__)


def uniform_sequence(
    cfg: Config,
    base: dolfinx.mesh.Mesh,
    refinements: int,
    norms: SampledNorms,
    checkpoint: Checkpoint,
) -> list[dict[str, Any]]:
    """``base`` and its ``refinements`` uniform refinements: one row per mesh (dofs, h, κ,
    η, the error against ``norms``' reference, solver steps, seconds). Recorded rows are
    not solved again (their meshes are still made, the next one refines them)."""
    rows = []
    mesh = base
    for k in range(refinements + 1):
        t0 = time.perf_counter()
        if k > 0:
            mesh = refine_uniformly(mesh, ghosted=True)
        refine_seconds = time.perf_counter() - t0
        key = f"uniform_level{k}"
        checkpoint.check_mesh(mesh, f"{key}_mesh")
        record = checkpoint.load(key)
        if record is not None:
            rows.append(record["row"])
            log.info(f"adaptive study, uniform level {k}: {record['row']['dofs']} dofs (recorded)")
            continue
        t0 = time.perf_counter()
        problem, iterations, force, kappa = _solve(cfg, mesh)
        seconds = refine_seconds + time.perf_counter() - t0
        estimator = (
            ErrorEstimator(problem)
            if force is None
            else ErrorEstimator.for_exact_solution(problem, force)
        )
        indicators = estimator()
        eta = indicators.total
        error = norms(problem.zeta)["vm"]
        row = {
            "sequence": "uniform", "level": k, "dofs": problem.num_dofs,
            "h_min": mesh_size_min(mesh), "h_max": mesh_size(mesh), "kappa_min": kappa,
            "kappa_max": kappa, "eta": eta, "error_VM": error, "iterations": iterations,
            "seconds": seconds, "efficiency": eta / error if error > 0 else float("nan"),
            **{f"eta_{k}": v for k, v in indicators.part_totals().items()},
        }  # fmt: skip
        rows.append(row)
        checkpoint.save(key, {"row": row})
        log.info(
            f"adaptive study, uniform level {k}: {row['dofs']} dofs, η = {eta:.4e}, "
            f"error {error:.4e}, {seconds:.1f} s"
        )
    return rows


def _solve(cfg: Config, mesh: dolfinx.mesh.Mesh) -> tuple[PenalizedProblem, int, Any, float]:
    """Solve on ``mesh`` by the config's method from ζ = 0: ``(problem, steps, contact
    pressure or None, κ)``."""
    h = mesh_size(mesh)
    method = METHODS[cfg.method]
    assert cfg.penalty is not None or not method.penalized
    kappas = kappa_on_mesh(cfg.penalty if method.penalized else None, mesh).ladder
    kappa = kappas[0] if method.penalized else None
    problem = PenalizedProblem(cfg.shell, mesh, cfg.discretization, kappa=kappa)
    options = options_for(method, cfg.method_options, cfg.solver)
    done = solve_with(method, problem, h, kappas, options)
    if not done.converged:
        raise ConvergenceError(done.error or f"{cfg.method} did not converge", done, done.steps)
    pressure = done.extra.get("contact_pressure")
    pressure = None if pressure is None else pressure.copy()
    return problem, done.iterations, pressure, kappas[-1]
