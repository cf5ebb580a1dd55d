"""A curved obstacle by sequential linearization of its gap (docs/model.md, Curved obstacles).

For a curved obstacle the constraint ``g(ζ) ≥ 0`` is not affine in ``ζ``, and neither the
penalty's piecewise-quadratic structure (Newton's exact line search, the Brezis–Sibony
iteration) nor the exact solvers' nodal bounds hold. Each method therefore solves the problem
whose gap is linearized at ``ζ̄``, ``g(ζ̄) + c(ζ̄)·(ζ − ζ̄)``
(:meth:`~shellobstacle.models.problem.PenalizedProblem.linearize`), with all its machinery
unchanged, and ``ζ̄`` moves to the answer until the linearized gap at the answer is the
curved one (:data:`RTOL`), or to the round-off of evaluating ``g`` (:data:`STALL`). At a
fixed point ``ζ = ζ̄`` the linearized gap, its derivative and hence the penalized equation
(and the exact problem's KKT conditions at the constraint's points) are those of the curved
obstacle.

The first pass goes through the whole κ ladder; the later ones solve at the target κ only,
from the previous answer, with what the method kept from the pass before
(:func:`~shellobstacle.solvers.methods.base.keeping`: Newton's solver, its penalty's point
operators assembled again in place).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from shellobstacle.solvers.methods.base import keeping
from shellobstacle.solvers.result import MethodResult

__all__ = ["MAX_LINEARIZATIONS", "RTOL", "STALL", "solve_with"]

RTOL = 1e-12
"""Stop when the linearization's error at the answer, ``max |g(ζ) − g_ζ̄(ζ)|`` over the
penalty rule's points, is at most ``RTOL · max |g(ζ)|``: the gap is then the curved
obstacle's to about the accuracy the solvers compute it with."""

STALL = 1e-8
"""A linearization error that no longer halves from one pass to the next is the round-off of
evaluating ``g`` (a ball of radius 10⁴ evaluates ``|x − c| − R`` to about 1e-11 of ``max |g|``,
above :data:`RTOL`): the passes stop there if it is at most ``STALL``, and fail otherwise."""

MAX_LINEARIZATIONS = 30


def solve_with(
    method: Any,
    problem: Any,
    h: float,
    kappas: Sequence[float],
    options: Any,
    say: Any,
    newton_progress: Any = None,
) -> MethodResult:
    """``method.solve(problem, …)``, repeated on the linearized gap for a curved obstacle.

    Returns:
        The method's result; for a curved obstacle every pass's steps (each with its
        ``linearization`` number) and, in ``extra``, ``linearizations`` (passes) and
        ``linearization_change`` (each pass's relative linearization error, :data:`RTOL`). Not
        converging in
        :data:`MAX_LINEARIZATIONS` passes is reported as a failure.
    """
    if not problem.linearized:
        return method.solve(problem, h, kappas, options, say, newton_progress)
    total = MethodResult()
    changes: list[float] = []
    ladder = list(kappas)
    problem.linearize()
    error = LinearizationError(problem)
    with keeping(method, problem):  # a method may keep its solver from pass to pass
        for k in range(1, MAX_LINEARIZATIONS + 1):
            done = method.solve(problem, h, ladder, options, say, newton_progress)
            for step in done.steps:
                step.details["linearization"] = k
            total.steps.extend(done.steps)
            total.extra.update(done.extra)
            for key, seconds in done.timings.items():
                total.timings[key] = total.timings.get(key, 0.0) + seconds
            if not done.converged:
                total.converged, total.error = False, done.error
                break
            changes.append(error())
            say(f"linearization {k}: max |g(ζ) − g_ζ̄(ζ)| / max |g(ζ)| = {changes[-1]:.1e}")
            if changes[-1] <= RTOL:
                break
            if len(changes) > 1 and STALL >= changes[-1] > changes[-2] / 2:
                say(f"linearization {k}: settled at the round-off of evaluating g")
                break
            problem.linearize()
            ladder = list(kappas[-1:])
        else:
            total.converged = False
            total.error = (
                f"the curved obstacle's linearization did not settle in {MAX_LINEARIZATIONS} "
                f"passes (last change {changes[-1]:.1e}: above {RTOL:g}, and still falling or "
                f"above {STALL:g})"
            )
    total.extra["linearizations"] = len(changes)
    total.extra["linearization_change"] = changes
    return total


class LinearizationError:
    """``max |g(ζ) − g_ζ̄(ζ)| / max |g(ζ)|`` (global) at the points of the problem's penalty
    rule (Gauss points or vertices), the error of the linearized gap at the current ``ζ``."""

    def __init__(self, problem: Any) -> None:
        import dolfinx.fem

        from shellobstacle.penalty.quadrature import quadrature_space

        self.comm = problem.mesh.comm
        Q = quadrature_space(problem)
        self.n = Q.dofmap.index_map.size_local
        points = Q.element.interpolation_points
        self.values = dolfinx.fem.Function(Q)
        self.exprs = [
            dolfinx.fem.Expression(e, points) for e in (problem.g, problem.g - problem.g_penalty)
        ]

    def __call__(self) -> float:
        from mpi4py import MPI

        largest = []
        for expr in self.exprs:
            self.values.interpolate(expr)
            local = float(np.max(np.abs(self.values.x.array[: self.n]), initial=0.0))
            largest.append(self.comm.allreduce(local, op=MPI.MAX))
        scale, error = largest
        return error / max(scale, 1e-300)
