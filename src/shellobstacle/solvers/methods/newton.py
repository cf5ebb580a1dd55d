"""``newton``: the penalized problem by Newton's method, κ reached by continuation."""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

from shellobstacle.solvers.methods.base import MethodBase
from shellobstacle.solvers.options import NewtonOptions
from shellobstacle.solvers.result import ConvergenceError, MethodResult

__all__ = ["NewtonContinuation"]


class NewtonContinuation(MethodBase):
    """Newton's method at each κ of the ladder, warm-started from the previous κ
    (:func:`~shellobstacle.solvers.continuation.continuation`)."""

    name = "newton"
    penalized = True
    adaptive = True
    options_type = NewtonOptions
    summary = "the penalized problem by Newton's method, κ reached by continuation (default)"
    solver_fields: ClassVar[Mapping[str, str]] = {
        key: key
        for key in (
            "linear_solver", "factorization", "contact_zone", "rtol", "stol", "max_iterations",
            "petsc_options",
        )
    }  # fmt: skip

    def solve(
        self,
        problem: Any,
        h: float,
        kappas: Sequence[float],
        options: NewtonOptions | None,
        say: Any,
        newton_progress: Any = None,
    ) -> MethodResult:
        """The continuation over ``kappas``; a κ that fails ends it, reported in the result
        with the earlier κ's steps and the failed one's."""
        from shellobstacle.progress import phase
        from shellobstacle.solvers.continuation import KappaStep, continuation
        from shellobstacle.solvers.newton import NewtonResult, NewtonSolver

        say(f"h = {h:.4g}, {problem.num_dofs} dofs; solving for {len(kappas)} value(s) of κ")
        out = MethodResult()
        t = time.perf_counter()
        with phase("setting up Newton's solver"):
            solver = NewtonSolver(problem, options)
        out.timings["setup"] = time.perf_counter() - t
        try:
            out.steps = list(
                continuation(problem, solver, list(kappas), say, newton_progress=newton_progress)
            )
        except ConvergenceError as err:
            out.steps = list(err.steps)
            if isinstance(err.result, NewtonResult):
                kappa = float(problem.kappa.value)
                out.steps.append(KappaStep(kappa, err.result, math.nan))
            out.converged, out.error = False, str(err)
        for key, value in solver.timings.items():
            out.timings[f"solve.{key}"] = value
        return out
