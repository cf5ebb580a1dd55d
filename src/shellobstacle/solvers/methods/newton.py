"""``newton``: the penalized problem by Newton's method, κ reached by continuation."""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import time
from collections.abc import Iterator, Sequence
from typing import TYPE_CHECKING, Any

from shellobstacle.solvers.methods.base import MethodBase
from shellobstacle.solvers.newton.options import NewtonOptions
from shellobstacle.solvers.result import ConvergenceError, MethodResult

if TYPE_CHECKING:
    from shellobstacle.solvers.newton.solver import NewtonSolver

__all__ = ["NewtonContinuation"]

log = logging.getLogger(__name__)


class NewtonContinuation(MethodBase):
    """Newton's method at each κ of the ladder, warm-started from the previous κ
    (:func:`~shellobstacle.solvers.newton.continuation.continuation`).

    Inside :meth:`keeping` its solver of a problem is kept from one solve to the next (a
    curved obstacle's refreshed for the problem's new linearized gap,
    :meth:`~shellobstacle.solvers.newton.solver.NewtonSolver.refresh`) instead of built again.
    Nested iteration (:mod:`~shellobstacle.solvers.newton.nested`), where asked for, runs on the
    first solve only: a curved obstacle's later passes go on from the finest mesh's answer.
    """

    name = "newton"
    penalized = True
    adaptive = True
    options_type = NewtonOptions
    summary = "the penalized problem by Newton's method, κ reached by continuation (default)"

    def __init__(self) -> None:
        # problem → (options, its solver), or None until the first solve: the problems
        # whose solver is kept (inside keeping())
        self._kept: dict[Any, tuple[Any, Any] | None] = {}
        # the kept problems whose solves go on from one another (keeping(go_on=True))
        self._going_on: set[Any] = set()

    @contextlib.contextmanager
    def keeping(self, problem: Any, go_on: bool = False) -> Iterator[None]:
        """Keep the solver of ``problem`` between the solves inside (released at the end).

        With ``go_on`` the solves inside are one continuation: a solve by the kept solver
        starts from the Euler prediction at its first κ
        (:func:`~shellobstacle.solvers.newton.continuation.predict`, where the linear strategy
        kept a factorization of the last κ solved), as a ladder's later κ do. Inside a
        ``keeping`` of the same problem it changes nothing.
        """
        if problem in self._kept:  # inside an enclosing keeping(problem): it keeps the solver
            yield
            return
        self._kept[problem] = None
        if go_on:
            self._going_on.add(problem)
        try:
            yield
        finally:
            self._kept.pop(problem, None)
            self._going_on.discard(problem)

    def kept_solver(self, problem: Any, options: NewtonOptions | None) -> NewtonSolver:
        """Inside :meth:`keeping`: the solver that the solves of ``problem`` with ``options``
        use, set up now if it is not yet (e.g. to restore a checkpoint's state into it before
        the first solve, :meth:`~shellobstacle.io.checkpoint.Checkpoint.restore_solver`).

        Raises:
            ValueError: outside ``keeping(problem)``.
        """
        from shellobstacle.solvers.auto import resolve

        if problem not in self._kept:
            raise ValueError("kept_solver(problem) needs to be called inside keeping(problem)")
        kept = self._kept[problem]
        if kept is not None and kept[0] is options:
            return kept[1]
        asked = options or NewtonOptions()
        if "auto" in (asked.linear_solver, asked.nested_iteration):
            asked = resolve(problem, asked).options
        return self._set_up(problem, options, asked)

    def _set_up(self, problem: Any, options: Any, solve_options: NewtonOptions) -> NewtonSolver:
        """A new solver of ``problem`` with ``solve_options``, kept (inside :meth:`keeping`)
        under the ``options`` asked for, as they came."""
        from shellobstacle.progress import phase
        from shellobstacle.solvers.newton.solver import NewtonSolver

        with phase("setting up Newton's solver"):
            solver = NewtonSolver(problem, solve_options)
        if problem in self._kept:
            self._kept[problem] = (options, solver)
        fallback = getattr(solver.linear, "fallback", "")  # multigrid without levels: GAMG
        if fallback:
            log.warning(fallback)
        return solver

    def solve(
        self,
        problem: Any,
        h: float,
        kappas: Sequence[float],
        options: NewtonOptions | None,
    ) -> MethodResult:
        """The continuation over ``kappas``; a κ that fails ends it, reported in the result
        with the earlier κ's steps and the failed one's."""
        from shellobstacle.progress import phase
        from shellobstacle.solvers.auto import resolve
        from shellobstacle.solvers.newton.continuation import KappaStep, continuation, predict
        from shellobstacle.solvers.newton.nested import nested_start
        from shellobstacle.solvers.newton.solver import NewtonResult

        if problem.shell.kinematics == "nonlinear":  # docs/model.md §11.3
            from shellobstacle.solvers.nonlinear.contact import solve_in_contact

            return solve_in_contact(problem, kappas)
        asked = options or NewtonOptions()
        out = MethodResult()
        if "auto" in (asked.linear_solver, asked.nested_iteration):  # (api.solve resolves it)
            resolution = resolve(problem, asked)
            asked, out.extra["choices"] = resolution.options, resolution.record()
            if resolution.said():
                log.info(resolution.said())
        kept = self._kept.get(problem)  # a later pass inside keeping(): its solver, no nesting
        nested = kept is None and asked.nested_iteration == "on"
        solve_options = asked
        log.info(
            f"h = {h:.4g}, {problem.num_dofs} dofs; solving for {len(kappas)} value(s) of κ"
            + (" on the coarsest mesh, the last on the finer ones" if nested else "")
        )
        t = time.perf_counter()
        if nested:
            try:
                with phase("nested iteration on the coarser meshes"):
                    levels = nested_start(problem, asked, kappas)
            except ConvergenceError as err:  # the continuation on the finest mesh instead
                log.info(f"nested iteration failed ({err}); continuing on the finest mesh alone")
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
            if problem.linearized:  # the gap may have moved since (a plane's does not)
                with phase("refreshing Newton's solver"):
                    solver.refresh()
            if problem in self._going_on:
                predict(solver, kappas[0])
        else:
            solver = self._set_up(problem, options, solve_options)
        out.timings["setup"] = time.perf_counter() - t
        out.extra["linear_solver"] = solver.linear_solver
        fallback = getattr(solver.linear, "fallback", "")  # multigrid without levels: GAMG
        if fallback:
            out.extra["linear_solver_used"] = "gamg"
            out.extra["linear_solver_reason"] = fallback
        try:
            out.steps = list(continuation(problem, solver, list(kappas)))
        except ConvergenceError as err:
            out.steps = list(err.steps)
            if isinstance(err.result, NewtonResult):
                kappa = float(problem.kappa.value)
                out.steps.append(KappaStep(kappa, err.result, math.nan))
            out.converged, out.error = False, str(err)
        for key, value in solver.timings.items():
            out.timings[f"solve.{key}"] = value - before.get(key, 0.0)
        return out
