"""Nested iteration (grid sequencing) on the mesh's refinement levels (docs/model.md §6).

A mesh made by uniform refinement remembers the meshes it came from
(:mod:`~shellobstacle.mesh.hierarchy`). :func:`nested_start` solves the same shell on them,
coarse to fine: the coarsest climbs the whole κ ladder by continuation (a few Newton steps per
κ on a mesh 4^L times smaller), every finer level solves the last κ once, from the coarser
level's solution interpolated, and the finest level's start is the last coarse solution
interpolated. Only the last κ is then solved on the finest mesh. A curved obstacle's gap is
linearized at each level's start; the finest mesh's passes of sequential linearization start
from the interpolated answer, linearized there.

The interpolated start misses the contact zone's outer ring, where a plain Newton step pushes
ζ_3 deep into the obstacle and the line search crawls; every level therefore relaxes ζ_3 after
such a cut step (:mod:`~shellobstacle.solvers.newton.normal_relaxation`). The finest mesh then takes
about half the Newton steps of the whole ladder, and the solve with multigrid is faster
(docs/perf/multigrid.md).
``solver.nested_iteration = "auto"`` uses it with multigrid on one rank
(:func:`~shellobstacle.solvers.auto.resolve`); what it needs is
:func:`~shellobstacle.solvers.auto.check_nested`.
"""

from __future__ import annotations

import dataclasses
import gc
import logging
import time
from collections.abc import Sequence
from typing import Any

from mpi4py import MPI  # noqa: F401  (MPI before dolfinx and PETSc)

from shellobstacle.mesh.hierarchy import coarser_meshes, prolongation
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.solvers.auto import check_nested
from shellobstacle.solvers.newton.continuation import KappaStep, continuation
from shellobstacle.solvers.newton.options import NewtonOptions
from shellobstacle.solvers.newton.solver import NewtonSolver

__all__ = ["interpolate", "nested_start"]

log = logging.getLogger(__name__)


def interpolate(coarse: PenalizedProblem, fine: PenalizedProblem) -> None:
    """``fine.zeta ←`` ``coarse.zeta`` interpolated, zero at the Dirichlet dofs."""
    P = prolongation(coarse.V, fine.V)
    P.mult(coarse.zeta.x.petsc_vec, fine.zeta.x.petsc_vec)
    P.destroy()
    for bc in fine.bcs:
        bc.set(fine.zeta.x.array, alpha=0.0)
    fine.zeta.x.scatter_forward()


def nested_start(
    problem: PenalizedProblem,
    options: NewtonOptions,
    kappas: Sequence[float],
) -> list[dict[str, Any]]:
    """Solve the coarser levels and leave the finest level's start in ``problem.zeta``.

    The coarsest level uses the direct solver, the others geometric multigrid; all of them
    relax ζ_3 after cut steps. Returns one record per coarser level (dofs, the κ solved,
    Newton steps, linear iterations, seconds). Raises ConvergenceError from a level that fails.
    """
    check_nested(problem)
    levels = coarser_meshes(problem.mesh)
    previous: PenalizedProblem | None = None
    records: list[dict[str, Any]] = []
    for k, mesh in enumerate(levels):
        t0 = time.perf_counter()
        level = PenalizedProblem(problem.shell, mesh, problem.disc, kappa=kappas[0])
        for name, value in problem.parameters.items():  # the load's current parameters
            level.parameters[name].value = value.value
        chosen = dataclasses.replace(
            options,
            linear_solver="direct" if k == 0 else "multigrid",
            nested_iteration="off",
            normal_relaxation=True,
            petsc_options={},
        )
        solver = NewtonSolver(level, chosen)
        if previous is not None:
            interpolate(previous, level)
        ladder = list(kappas) if previous is None else [kappas[-1]]
        steps = _solve_level(level, solver, ladder, k)
        results = [step.newton for step in steps]
        records.append(
            {
                "dofs": level.num_dofs,
                "kappas": [step.kappa for step in steps],
                "newton": [r.iterations for r in results],
                "linear_iterations": [sum(r.linear_iterations) for r in results],
                "relaxed_steps": sum(r.relaxed_steps for r in results),
                "seconds": time.perf_counter() - t0,
            }
        )
        log.info(
            f"nested iteration, level {k + 1}/{len(levels)}: {level.num_dofs} dofs, "
            f"{sum(records[-1]['newton'])} Newton steps"
        )
        previous = level
        del solver
        gc.collect()  # the solver and its strategy refer to each other: free the level now
    interpolate(previous, problem)
    return records


def _solve_level(
    level: PenalizedProblem, solver: NewtonSolver, ladder: list[float], k: int
) -> list[KappaStep]:
    """The steps of one level's κ values (the ladder, or the last κ) from its current ζ.

    A curved obstacle's gap is linearized once per level, at its start (ζ = 0 on the
    coarsest, the coarser answer interpolated on the others), and not settled there: a level
    only gives the next its start, and the finest mesh settles the gap by the passes of
    :func:`~shellobstacle.solvers.linearization.solve_with`. Settling every level costs
    more for the same Newton steps on the finest mesh and the same ζ
    (docs/perf/multigrid.md)."""
    if level.linearized and k > 0:
        level.linearize()
        solver.refresh()
    return continuation(level, solver, ladder)
