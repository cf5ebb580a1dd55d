"""Semismooth Newton for the penalized problem with an exact line search (docs/model.md §6).

``J_κ`` is strictly convex, C¹ and piecewise quadratic, so along a Newton direction ``δ`` the
function ``φ(t) = J_κ(ζ + tδ)`` is convex and piecewise quadratic and ``φ'(t) = R(ζ + tδ)·δ``
is monotone and piecewise linear. The step length is the root of ``φ'``
(:mod:`~shellobstacle.solvers.newton.line_search`, exact once the active set along the segment is
fixed), which makes every step decrease the energy and the iteration globally convergent from
any start. With ``normal_relaxation`` (the membrane model) a step cut below ``t = 0.5`` is
replaced by the full step with ζ_3 relaxed when that lowers ``J_κ`` further
(:mod:`~shellobstacle.solvers.newton.normal_relaxation`).

A step is taken on a *model*: the energy at its current iterate, with its residual, round-off
floor, direction and line search. The whole problem
(:class:`~shellobstacle.solvers.newton.system.PenalizedSystem`, its directions from a linear
strategy
of :mod:`~shellobstacle.solvers.linear`) is one; the contact zone's condensed problem
(:class:`~shellobstacle.solvers.zone.reduced.ZoneModel`), on which the default strategy steps
while the active points stay inside the zone, is the other. The stopping rule is the same for
both: the relative residual below ``rtol``, the residual at its round-off floor (with ``ε/κ``
large the gap's rounding, amplified by the penalty, bounds what can be resolved), a Newton
correction below ``stol``, or a Newton decrement below the round-off of the energy's slope.

Every test is relative to the problem's scale (the load vector, the residual's terms), so a
problem and its multiple by any factor take the same steps; ``atol``, an absolute floor, is
off by default. A zero load stops at once with ``ζ = 0`` (:data:`ZERO_LOAD`), and a Newton
direction that overflows (a Jacobian singular at the load's scale: material constants or a load
beyond double precision's range) is a failure, not a step below round-off.
"""

from __future__ import annotations

import functools
import logging
import math
import time
from collections.abc import Callable
from enum import Enum
from typing import Any, Protocol

from mpi4py import MPI  # noqa: F401  (MPI before dolfinx and PETSc)

import dolfinx
import dolfinx.fem.petsc
import numpy as np

from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.progress import note
from shellobstacle.solvers.auto import resolve
from shellobstacle.solvers.base import ConvergenceError, UserOptions, with_user_options
from shellobstacle.solvers.linear import LinearSolveError, LinearStrategy, make_strategy
from shellobstacle.solvers.newton.normal_relaxation import (
    RELAX_BELOW,
    NormalRelaxation,
    require_membrane,
)
from shellobstacle.solvers.newton.options import NewtonOptions
from shellobstacle.solvers.newton.system import PenalizedSystem
from shellobstacle.solvers.result import BELOW_RTOL, ZERO_LOAD, NewtonResult

__all__ = ["ZERO_LOAD", "ConvergenceError", "NewtonOptions", "NewtonResult", "NewtonSolver"]

Progress = Callable[[int, float], Any]
log = logging.getLogger(__name__)
#: the phases of a solve whose seconds :attr:`NewtonSolver.timings` adds up
PHASES = (
    "assemble", "factorize", "solve", "line_search", "zone", "condense", "zone_newton", "relax",
)  # fmt: skip


class Model(Protocol):
    """A penalized energy at its current iterate, as one Newton step needs it."""

    def residual_norm(self) -> float: ...
    def floor(self, load_norm: float) -> float: ...
    def slope(self) -> float: ...
    def small_step(self, stol: float) -> bool: ...
    def direction_norm(self) -> float: ...
    def line_search(self, slope0: float, noise: float) -> tuple[float, int]: ...
    def move(self, t: float, small: bool) -> None: ...


class Outcome(Enum):
    """How a Newton step ended."""

    STEPPED = "stepped"
    SMALL = "Newton correction below stol"
    NOT_DESCENT = "not a descent direction"
    BELOW_NOISE = "Newton decrement below the round-off of the energy slope"
    OVERFLOW = "the Newton direction overflows"


class NewtonSolver:
    """Newton's method for one :class:`PenalizedProblem`, reusable across ``κ`` values.

    Args:
        problem: the compiled problem; ``problem.zeta`` is the iterate.
        options: tolerances and the linear strategy to use.
        linear: a linear strategy built by hand (its own knobs), instead of the one
            ``options`` asks for.
    """

    def __init__(
        self,
        problem: PenalizedProblem,
        options: NewtonOptions | None = None,
        linear: LinearStrategy | None = None,
    ) -> None:
        self.problem = problem
        self.options = opts = options or NewtonOptions()
        if opts.normal_relaxation:
            require_membrane(problem)
        t0 = time.perf_counter()
        self.system = PenalizedSystem(problem, opts.floor_factor)
        #: the linear solver used: ``options.linear_solver`` (``"auto"`` from a direct caller
        #: resolved by :func:`~shellobstacle.solvers.auto.resolve`; a solve passes it
        #: resolved), or the class name of a strategy built by hand
        self.linear_solver: str
        if linear is None:
            chosen = resolve(problem, opts).options if opts.linear_solver == "auto" else opts
            self.linear_solver = chosen.linear_solver
            linear = make_strategy(chosen, problem.mesh.comm)
        else:
            self.linear_solver = type(linear).__name__
        self.linear = linear
        #: the relaxation of ζ_3 after cut steps (``options.normal_relaxation``), once used
        self.relaxation: NormalRelaxation | None = None
        self.timings: dict[str, float] = dict.fromkeys(PHASES, 0.0)
        # the Jacobian's solver and, by default, the zone's factorizations
        self.user_options = UserOptions(
            opts.petsc_options, ("newton", "zone"), "newton", problem.mesh.comm
        )
        with self.user_options.applied():
            self.linear.attach(self.system, self.timings)
        self.timings["setup"] = time.perf_counter() - t0

    def refresh(self) -> None:
        """Follow the problem's gap after it was linearized anew
        (:meth:`~shellobstacle.models.problem.PenalizedProblem.linearize`): the penalty's
        point operators and what the linear strategy built from them are made again in place;
        ``K``, the contact zone and the factorizations' analyses are kept. The next
        :meth:`solve` is then that of a solver built anew, but for those kept parts."""
        t0 = time.perf_counter()
        self.system.refresh()
        self.linear.refresh()
        self.timings["setup"] += time.perf_counter() - t0

    @property
    def kappa(self) -> float:
        """The current penalty parameter."""
        return self.system.kappa

    @property
    def penalty(self) -> Any:
        """The problem's penalty at its quadrature points."""
        return self.system.penalty

    @property
    def zone(self) -> Any:
        """The contact zone of the default strategy (None for the others)."""
        return getattr(self.linear, "zone", None)

    @property
    def active_points(self) -> np.ndarray:
        """The owned penalty points where the last iterate penetrates, ``g_k < 0`` (the
        active set ``A`` of docs/model.md §5), in the quadrature space's local order; none before
        the first solve."""
        return self.system.g < 0

    @property
    def penalty_gaps(self) -> np.ndarray:
        """The gap ``g_k`` of the last iterate at the owned penalty points (a read-only copy:
        the system updates its own in place)."""
        gaps = self.system.g.copy()
        gaps.flags.writeable = False
        return gaps

    def zone_indicator(self) -> dolfinx.fem.Function | None:
        """The contact zone as a 0/1 function (checkpoints), or None."""
        indicator = getattr(self.linear, "zone_indicator", None)
        return None if indicator is None else indicator()

    def set_zone_indicator(self, u: dolfinx.fem.Function) -> None:
        """Restore a zone saved by :meth:`zone_indicator` (collective)."""
        if hasattr(self.linear, "set_zone_indicator"):
            self.linear.set_zone_indicator(u)

    # -- the loop -----------------------------------------------------------------------------
    @with_user_options
    def solve(self, progress: Progress | None = None) -> NewtonResult:
        """Solve the penalized problem for the current ``κ``, starting from ``problem.zeta``.

        Every solve starts with new factorizations, so its result depends only on its start
        (a resumed sweep repeats the uninterrupted one).

        Args:
            progress: called as ``progress(iteration, relative residual)`` after every step.

        Returns:
            The :class:`NewtonResult` (``problem.zeta`` holds the solution).

        Raises:
            ConvergenceError: after ``max_iterations``, on a failed linear solve, a direction
                that does not descend, or NaN; the last iterate is left in ``problem.zeta``
                and the history in ``err.result``.
        """
        opts, problem, system = self.options, self.problem, self.system
        zeta = problem.zeta
        t_start = time.perf_counter()
        dolfinx.fem.petsc.set_bc(zeta.x.petsc_vec, problem.bcs)  # homogeneous bcs on the start
        zeta.x.scatter_forward()
        result = NewtonResult(False, 0, "")
        ta = time.perf_counter()
        ref = system.load()
        self.linear.begin()
        system.residual()
        self.timings["assemble"] += time.perf_counter() - ta
        rnorm = system.residual_norm()
        result.residual_norms.append(rnorm)
        scale = ref if ref > 0.0 else 1.0
        result.reference = ref
        just_reduced = False  # the last iterations were on the zone's problem
        while True:
            stop, converged, floor = self._stop(system, rnorm, scale, ref, result)
            if stop:
                result.converged, result.reason = converged, stop
                break
            if not just_reduced:
                tz, others = time.perf_counter(), self._timed()
                reduced = self.linear.reduced(opts.floor_factor)
                if reduced is not None:
                    rnorm = self._reduced_steps(reduced, result, scale, ref, progress)
                    # (the zone's build, condensation and line searches are timed apart)
                    spent = time.perf_counter() - tz - (self._timed() - others)
                    self.timings["zone_newton"] += spent
                    just_reduced = True
                    continue
            just_reduced = False
            target = max(opts.atol, opts.rtol * scale, floor)
            try:
                outcome = self._step(
                    system,
                    functools.partial(self.linear.direction, result.residual_norms, target),
                    floor,
                    result,
                    scale,
                    progress,
                )
            except LinearSolveError as failure:
                result.linear_iterations.append(failure.iterations)
                result.reason = str(failure)
                break
            rnorm = system.residual_norm()
            if outcome is Outcome.SMALL:
                result.converged, result.reason = True, outcome.value
                break
            if outcome is Outcome.BELOW_NOISE:
                # the decrement δᵀJδ is below the round-off of φ': no step can be verified to
                # decrease J_κ, ζ is the solution to working precision
                result.converged, result.reason = True, outcome.value
                break
            if outcome is Outcome.NOT_DESCENT:
                result.reason = f"not a descent direction (R·δ = {system.slope():.3e})"
                break
            if outcome is Outcome.OVERFLOW:
                result.reason = (
                    f"{outcome.value} (‖δ‖ = {system.direction_norm():.3e}): the Jacobian is "
                    "singular at the scale of the load (material constants or load beyond "
                    "double precision's range)"
                )
                break
        result.factorizations = self.linear.factorizations
        result.timings = {"total": time.perf_counter() - t_start}
        if not result.converged:
            raise ConvergenceError(
                f"Newton did not converge for kappa = {self.kappa:.3e}: {result.reason}; "
                f"relative residual {rnorm / scale:.3e} after {result.iterations} iterations",
                result,
            )
        return result

    def _timed(self) -> float:
        """Seconds of the phases other than the zone's Newton steps so far."""
        return sum(v for k, v in self.timings.items() if k not in ("zone_newton", "setup"))

    def _stop(
        self, model: Model, rnorm: float, scale: float, ref: float, result: NewtonResult
    ) -> tuple[str, bool, float]:
        """The stopping rule: ``(reason, converged, floor)``, the reason empty to go on."""
        opts = self.options
        if not math.isfinite(rnorm):
            return "residual is not finite (NaN/Inf)", False, math.nan
        if ref == 0.0 and rnorm == 0.0:
            return ZERO_LOAD, True, math.nan
        if rnorm <= max(opts.atol, opts.rtol * scale):
            return BELOW_RTOL, True, math.nan
        floor = model.floor(ref)
        if rnorm <= floor:
            return "residual at its round-off floor", True, floor
        if result.iterations >= opts.max_iterations:
            return f"no convergence in {opts.max_iterations} Newton iterations", False, floor
        return "", False, floor

    def _step(
        self,
        model: Model,
        direction: Callable[[], int],
        floor: float,
        result: NewtonResult,
        scale: float,
        progress: Progress | None,
    ) -> Outcome:
        """One Newton step on ``model``: its direction, the exact line search, the move."""
        result.linear_iterations.append(direction())
        tl = time.perf_counter()
        slope0 = model.slope()  # R·δ = −δᵀJδ < 0
        small = model.small_step(self.options.stol)
        if small:  # take the (tiny) full step, then stop: nothing left to gain
            t, evaluations = 1.0, 0
        elif not (slope0 < 0 and math.isfinite(slope0)):
            return Outcome.NOT_DESCENT
        else:
            noise = floor * model.direction_norm()  # |round-off in φ'(t)| ≲ ‖R_floor‖ ‖δ‖
            if not math.isfinite(noise):
                return Outcome.OVERFLOW
            if -slope0 <= noise:
                return Outcome.BELOW_NOISE
            t, evaluations = model.line_search(slope0, noise)
        model.move(t, small)
        self.timings["line_search"] += time.perf_counter() - tl
        if model is self.system and self.options.normal_relaxation and t < RELAX_BELOW:
            tr = time.perf_counter()
            self.relaxation = self.relaxation or NormalRelaxation(self.system)
            result.relaxed_steps += self.relaxation.full_step(t)
            self.timings["relax"] += time.perf_counter() - tr
        result.line_search_evaluations += evaluations
        result.step_lengths.append(t)
        result.iterations += 1
        if getattr(model, "counts_as_zone_step", False):
            result.zone_steps += 1
        rnorm = model.residual_norm()
        result.residual_norms.append(rnorm)
        note(f"Newton step {result.iterations}, relative residual {rnorm / scale:.1e}")
        log.debug("    Newton %d: relative residual %.3e", result.iterations, rnorm / scale)
        if progress is not None:
            progress(result.iterations, rnorm / scale)
        return Outcome.SMALL if small else Outcome.STEPPED

    def _reduced_steps(
        self,
        model: Any,
        result: NewtonResult,
        scale: float,
        ref: float,
        progress: Progress | None,
    ) -> float:
        """Newton steps on a smaller model (the zone's problem) until it stops or cannot step
        further, then the whole iterate completed; returns ``‖R(ζ)‖`` of the whole problem,
        which replaces the last entry of the history (the loop on the whole problem decides
        what happens next)."""
        rnorm = model.residual_norm()
        while True:
            stop, _, floor = self._stop(model, rnorm, scale, ref, result)
            if stop:
                break
            outcome = self._step(
                model, functools.partial(model.direction, floor), floor, result, scale, progress
            )
            if outcome is not Outcome.STEPPED:
                break
            rnorm = model.residual_norm()
        rnorm = model.complete()
        result.residual_norms[-1] = rnorm
        return rnorm
