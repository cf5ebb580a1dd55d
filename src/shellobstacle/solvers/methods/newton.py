"""``newton``: the penalized problem by Newton's method, κ reached by continuation."""

from __future__ import annotations

import contextlib
import dataclasses
import math
import time
from collections.abc import Iterator, Mapping, Sequence
from typing import Any, ClassVar

from shellobstacle.solvers.methods.base import MethodBase
from shellobstacle.solvers.options import NewtonOptions
from shellobstacle.solvers.result import ConvergenceError, MethodResult

__all__ = ["NewtonContinuation"]


class NewtonContinuation(MethodBase):
    """Newton's method at each κ of the ladder, warm-started from the previous κ
    (:func:`~shellobstacle.solvers.newton.continuation.continuation`).

    Inside :meth:`keeping` its solver of a problem is kept from one solve to the next and
    refreshed for the problem's new linearized gap
    (:meth:`~shellobstacle.solvers.newton.solver.NewtonSolver.refresh`) instead of built again.
    Nested iteration (:mod:`~shellobstacle.solvers.newton.nested`), where asked for, runs on the
    first solve only: a curved obstacle's later passes go on from the finest mesh's answer.
    """

    name = "newton"
    penalized = True
    adaptive = True
    options_type = NewtonOptions
    summary = "the penalized problem by Newton's method, κ reached by continuation (default)"
    solver_fields: ClassVar[Mapping[str, str]] = {
        key: key
        for key in (
            "linear_solver", "factorization", "contact_zone", "nested_iteration", "rtol",
            "stol", "max_iterations", "petsc_options",
        )
    }  # fmt: skip

    def __init__(self) -> None:
        # problem → (options, its solver), or None until the first solve: the problems
        # whose solver is kept (inside keeping())
        self._kept: dict[Any, tuple[Any, Any] | None] = {}

    @contextlib.contextmanager
    def keeping(self, problem: Any) -> Iterator[None]:
        """Keep the solver of ``problem`` between the solves inside (released at the end)."""
        self._kept[problem] = None
        try:
            yield
        finally:
            self._kept.pop(problem, None)

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
        from shellobstacle.solvers.newton.continuation import KappaStep, continuation
        from shellobstacle.solvers.newton.nested import nested_start, nested_wanted
        from shellobstacle.solvers.newton.solver import NewtonResult, NewtonSolver

        asked = options or NewtonOptions()  # (None: the defaults, whose "auto" may nest)
        kept = self._kept.get(problem)  # a later pass inside keeping(): its solver, no nesting
        nested = kept is None and nested_wanted(problem, asked)
        solve_options = asked
        say(
            f"h = {h:.4g}, {problem.num_dofs} dofs; solving for {len(kappas)} value(s) of κ"
            + (" on the coarsest mesh, the last on the finer ones" if nested else "")
        )
        out = MethodResult()
        t = time.perf_counter()
        if nested:
            try:
                with phase("nested iteration on the coarser meshes"):
                    levels = nested_start(problem, asked, kappas, say)
            except ConvergenceError as err:  # the continuation on the finest mesh instead
                say(f"nested iteration failed ({err}); continuing on the finest mesh alone")
                out.extra["nested_iteration"] = {"failed": str(err)}
                problem.zeta.x.array[:] = 0.0
            else:
                out.extra["nested_iteration"] = {"levels": levels}
                kappas = list(kappas)[-1:]  # the finest mesh solves the last κ only
                solve_options = dataclasses.replace(asked, normal_relaxation=True)
                problem.linearize()  # a curved obstacle's gap at the start interpolated
            out.timings["nested"] = time.perf_counter() - t
            t = time.perf_counter()
        before: dict[str, float] = {}  # the kept solver's seconds before this solve
        if kept is not None and kept[0] is options:
            solver = kept[1]
            before = dict(solver.timings)
            with phase("refreshing Newton's solver"):
                solver.refresh()
        else:
            with phase("setting up Newton's solver"):
                solver = NewtonSolver(problem, solve_options)
            if problem in self._kept:  # (kept under the options asked for, as they came)
                self._kept[problem] = (options, solver)
        out.timings["setup"] = time.perf_counter() - t
        out.extra["linear_solver"] = solver.linear_solver
        if solver.options.linear_solver == "auto" and solver.linear_solver != "direct":
            say(f'linear solver: {solver.linear_solver} ("auto": {solver.auto_reason})')
        fallback = getattr(solver.linear, "fallback", "")  # multigrid without levels: GAMG
        if fallback:
            out.extra["linear_solver_used"] = "gamg"
            out.extra["linear_solver_reason"] = fallback
            if kept is None or kept[1] is not solver:  # said once, when it is set up
                say(f"warning: {fallback}")
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
            out.timings[f"solve.{key}"] = value - before.get(key, 0.0)
        return out
