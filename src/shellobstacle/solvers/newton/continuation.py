"""The continuation in κ: each κ warm-started from the previous solution (docs/model.md §6).

A plain Newton from ζ = 0 directly at a small κ can take many damped steps; from the solution
at a larger κ it takes a few. :func:`continuation` solves a ladder of κ on one compiled
problem (κ is a ``dolfinx.fem.Constant``: nothing is recompiled), and :func:`predict` moves
the warm start along the solution path first when the linear strategy keeps a factorization
that makes it cheap (:class:`~shellobstacle.solvers.linear.direct.DirectStrategy`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

from mpi4py import MPI  # noqa: F401  (MPI before dolfinx and PETSc)
from petsc4py import PETSc

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.progress import phase
from shellobstacle.solvers.base import ConvergenceError
from shellobstacle.solvers.newton.solver import NewtonResult, NewtonSolver
from shellobstacle.solvers.result import Step

__all__ = ["KappaStep", "continuation", "log_newton", "predict"]

log = logging.getLogger(__name__)


class KappaStep(Step):
    """One κ of a continuation: a :class:`~shellobstacle.solvers.result.Step` whose
    ``record`` is Newton's :class:`NewtonResult` (also as :attr:`newton`)."""

    def __init__(self, kappa: float, newton: NewtonResult, seconds: float) -> None:
        super().__init__(
            kappa,
            newton.iterations,
            newton.converged,
            newton.reason,
            newton.relative_residual,
            seconds,
            newton.residual_norms,
            {
                "round_off_limited": newton.round_off_limited,
                "line_search_evaluations": newton.line_search_evaluations,
                "linear_iterations": newton.linear_iterations,
                "step_lengths": newton.step_lengths,
                "relaxed_steps": newton.relaxed_steps,
            },
            None,
            newton,
        )

    @property
    def newton(self) -> NewtonResult:
        """Newton's statistics at this κ."""
        return self.record


def predict(solver: NewtonSolver, kappa_new: float) -> bool:
    """Euler predictor along κ: ``ζ ← ζ + (κ_new − κ) dζ/dκ`` with ``J dζ/dκ = −∂R/∂κ``.

    ``∂R/∂κ = −(1/κ²) Mᵀ min(g, 0)``, and ``J`` is the linear strategy's kept factorization
    of the last solve (one back-substitution, or a few preconditioned CG iterations). Returns
    False, and changes nothing, when the strategy keeps none.
    """
    if not solver.linear.predicts:
        return False
    t0 = time.perf_counter()
    system = solver.system
    kappa = system.kappa
    b = system.R.duplicate()
    b.set(0.0)
    system.penalty.add_kappa_derivative(system.g, kappa, b)  # −∂R/∂κ
    ok = solver.linear.tangent(b)
    b.destroy()
    if ok:
        system.dz.ghostUpdate(addv=PETSc.InsertMode.INSERT, mode=PETSc.ScatterMode.FORWARD)
        zeta = solver.problem.zeta
        with system.dz.localForm() as dz_loc:
            zeta.x.array[:] += (kappa_new - kappa) * dz_loc.array_r
        zeta.x.scatter_forward()
    solver.timings["predict"] = solver.timings.get("predict", 0.0) + time.perf_counter() - t0
    return ok


def log_newton(result: NewtonResult) -> None:
    """Log (debug) how a Newton solve went: its steps' lengths (the exact line search's t)
    and why it stopped."""
    if log.isEnabledFor(logging.DEBUG):
        lengths = ", ".join(f"{t:.3g}" for t in result.step_lengths) or "none"
        log.debug(f"    Newton: {result.iterations} steps, step lengths {lengths}; {result.reason}")


def continuation(
    problem: PenalizedProblem,
    solver: NewtonSolver,
    kappas: list[float],
    predictor: bool = True,
    newton_progress: Callable[[int, float], Any] | None = None,
) -> list[KappaStep]:
    """Solve for each κ in turn, warm-starting from the previous solution.

    With ``predictor`` the warm start is the Euler prediction along κ (:func:`predict`, where
    the strategy supports it). ``newton_progress(it, relative_residual)`` is called after
    every Newton iteration; if it has a method ``finished(result)``, that is called with each
    κ's :class:`NewtonResult`. Each κ solved is logged (information), with Newton's step
    lengths (debug).

    Raises:
        ConvergenceError: from the first κ that fails, with the earlier κ's steps in its
            ``steps`` (and Newton's :class:`NewtonResult` of the failed κ in its ``result``).
    """
    steps: list[KappaStep] = []
    for k, kappa in enumerate(kappas):
        t0 = time.perf_counter()
        with phase(f"κ {k + 1}/{len(kappas)} = {kappa:.2e}"):
            if predictor and k > 0:
                predict(solver, kappa)
            problem.set_kappa(kappa)
            try:
                result = solver.solve(newton_progress)
            except ConvergenceError as err:
                raise err.after(steps) from err
        if hasattr(newton_progress, "finished"):
            newton_progress.finished(result)
        log_newton(result)
        steps.append(KappaStep(kappa, result, time.perf_counter() - t0))
        log.info(
            f"κ {k + 1}/{len(kappas)} = {kappa:.3e}: {result.iterations} Newton steps, "
            f"relative residual {result.relative_residual:.1e}"
        )
    return steps
