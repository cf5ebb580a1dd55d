"""The adaptive loop: solve → estimate → mark → refine → transfer → solve again.

Each level compiles the problem on its mesh (the forms' code is cached: only the first
level compiles), solves it warm-started from the previous level's solution interpolated
onto the refined mesh (exact: Plaza's meshes are nested), computes the indicators
(:mod:`~shellobstacle.adapt.estimator`), marks by Dörfler's criterion and the discrete free
boundary (:mod:`~shellobstacle.adapt.marking`) and refines the marked cells
(:func:`~shellobstacle.mesh.refinement.refine_marked`). Everything is collective: on several ranks
the marked set, hence the meshes and the numbers, are those of a serial run up to solver
tolerance.

The penalty parameter follows the mesh as ``AdaptOptions.kappa`` says
(:func:`~shellobstacle.penalty.kappa.kappa_on_mesh`). The first level reaches its κ through
the continuation ladder; the later ones start from the transferred solution at their own κ.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from mpi4py import MPI

import dolfinx
import numpy as np

from shellobstacle.adapt.estimator import ErrorEstimator, Indicators
from shellobstacle.adapt.marking import free_boundary_cells, mark_dorfler, marked_edges
from shellobstacle.adapt.options import AdaptOptions
from shellobstacle.mesh.measures import mesh_size, mesh_size_min, num_cells_global
from shellobstacle.mesh.refinement import refine_marked
from shellobstacle.mesh.transfer import Interpolation
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.penalty.kappa import MeshKappa, kappa_on_mesh
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.solvers.linearization import solve_with
from shellobstacle.solvers.newton.options import NewtonOptions
from shellobstacle.solvers.registry import METHODS, Method, discretization_for, options_for
from shellobstacle.solvers.result import MethodResult, SolveResult, Step
from shellobstacle.spec import Discretization, Shell

__all__ = [
    "AdaptLevel",
    "AdaptiveResult",
    "adaptive_solve",
    "carry_over",
    "solve_adaptively",
]

log = logging.getLogger(__name__)


@dataclass
class AdaptLevel:
    """One mesh of the adaptive sequence: its size, κ, estimate and cost."""

    level: int
    dofs: int
    cells: int
    h_max: float
    h_min: float
    kappa_min: float
    kappa_max: float
    eta: float
    parts: dict[str, float]
    iterations: int
    marked: int = 0
    seconds: dict[str, float] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly record (the parts of ``η`` as ``eta_<part>``)."""
        out = {k: v for k, v in self.__dict__.items() if k not in ("parts", "seconds")}
        out |= {f"eta_{k}": v for k, v in self.parts.items()}
        out |= {f"seconds_{k}": v for k, v in self.seconds.items()}
        return out


@dataclass
class AdaptiveResult:
    """The levels of an adaptive solve and the last level's problem (holding ``ζ``).

    Attributes:
        levels: one record per solved mesh.
        problem: the last level's problem.
        steps: the last level's solver steps.
        reason: why the loop stopped.
        converged: whether every solve converged.
        error: the solver's message when one did not.
        indicators: the last level's indicators.
        extra: the exact solver's contact pressure (a method of κ = 0).
    """

    levels: list[AdaptLevel]
    problem: PenalizedProblem
    steps: list[Step]
    reason: str
    converged: bool = True
    error: str | None = None
    indicators: Indicators | None = None
    extra: dict[str, Any] = field(default_factory=dict)


def adaptive_solve(
    shell: Shell,
    mesh: dolfinx.mesh.Mesh,
    discretization: Discretization | None,
    penalty: PenaltySpec | None,
    adapt: AdaptOptions,
    options: NewtonOptions | None = None,
    method: str = "newton",
    method_options: Any = None,
    on_level: Callable[[AdaptLevel, PenalizedProblem], Any] | None = None,
    start: dolfinx.fem.Function | None = None,
    carry: list[dolfinx.fem.Function] | None = None,
) -> AdaptiveResult:
    """Solve on ``mesh`` and its adaptive refinements until a target of ``adapt`` is met.

    Args:
        shell: the membrane shell (the indicators are the membrane model's).
        mesh: the first mesh; a ghosted one (facet-sharing ghost cells) in parallel, so that
            the jump terms across process boundaries are integrated.
        discretization: degree, boundary condition of ζ_3, penalty quadrature.
        penalty: ``κ`` or ``h^exponent``; None for a method of κ = 0 (``"active-set"``).
        adapt: marking fraction, targets, how κ follows the mesh.
        options: Newton's options.
        method: a key of :data:`~shellobstacle.solvers.registry.METHODS` whose method is
            ``adaptive``: ``"newton"`` (penalized) or ``"active-set"`` (the exact discrete VI).
        method_options: its options (e.g. ``ActiveSetOptions``); None: ``options`` for
            Newton, the defaults otherwise.
        on_level: called with each level's record and problem once it is estimated (e.g. to
            measure errors against a reference).
        start: a solution on ``mesh`` or a coarser mesh it refines: the first level starts
            from it (at its κ, as the later levels do) instead of from ζ = 0.
        carry: Functions on the current mesh (``start``'s, if given), replaced in the list by
            their interpolants on each refined mesh (exact: the meshes are nested), with the
            interpolation data of the warm start; ``on_level`` may append to it.

    Returns:
        The :class:`AdaptiveResult`; a solver failure ends the loop with ``converged =
        False`` and the failed level's iterate in ``problem.zeta``.
    """
    if shell.model != "membrane":
        raise ValueError("adaptive refinement needs model.kind = 'membrane' (its indicators)")
    chosen = METHODS.get(method)
    if chosen is None or not chosen.adaptive:
        adaptive = [m.name for m in METHODS.values() if m.adaptive]
        raise ValueError(f"adaptive refinement solves by one of {adaptive}, not {method!r}")
    disc = discretization_for(chosen, discretization or Discretization())
    opts = options_for(chosen, method_options, options)
    comm: MPI.Comm = mesh.comm
    levels: list[AdaptLevel] = []
    previous: dolfinx.fem.Function | None = start
    k = 0
    while True:
        t0 = time.perf_counter()
        kappa = kappa_on_mesh(penalty if chosen.penalized else None, mesh, adapt.kappa)
        first = kappa.ladder[0] if chosen.penalized else None  # None: the nodal problem
        problem = PenalizedProblem(shell, mesh, disc, first, kappa_scale=kappa.scale)
        if previous is not None:
            moved = carry_over([previous, *(carry or [])], problem.V)
            problem.zeta.x.array[:] = moved[0].x.array
            if carry is not None:
                carry[:] = moved[1:]
        seconds = {"setup": time.perf_counter() - t0}
        t0 = time.perf_counter()
        done = _solve_level(chosen, problem, kappa, previous is not None, opts)
        steps, iterations = done.steps, done.iterations
        if not done.converged:
            return AdaptiveResult(levels, problem, steps, "solver failure", False, done.error)
        force = done.extra.get("contact_pressure")
        force = None if force is None else force.copy()
        seconds["solve"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        estimator = (
            ErrorEstimator(problem)
            if force is None
            else ErrorEstimator.for_exact_solution(problem, force)
        )
        indicators = estimator()
        seconds["estimate"] = time.perf_counter() - t0
        level = AdaptLevel(
            k, problem.num_dofs, num_cells_global(mesh), mesh_size(mesh), mesh_size_min(mesh),
            kappa.kappa_min, kappa.kappa_max, indicators.total, indicators.part_totals(),
            iterations,
            seconds=seconds,
        )  # fmt: skip
        levels.append(level)
        reason = _stop(level, adapt)
        if on_level is not None:
            on_level(level, problem)
        if reason:
            log.info(_line(level, reason))
            extra = {} if force is None else {"contact_pressure": force}
            return AdaptiveResult(levels, problem, steps, reason, True, None, indicators, extra)
        t0 = time.perf_counter()
        cells = mark_dorfler(indicators.eta2, adapt.fraction, comm)
        if adapt.free_boundary:
            constraint = "penalty" if chosen.penalized else "nodes"  # (SolveResult.constraint)
            cells = np.union1d(cells, _free_boundary(problem, constraint)).astype(np.int32)
        level.marked = int(comm.allreduce(cells.size, op=MPI.SUM))
        mesh = refine_marked(mesh, marked_edges(mesh, cells))
        seconds["refine"] = time.perf_counter() - t0
        log.info(_line(level, ""))
        previous = problem.zeta
        k += 1


def carry_over(
    functions: list[dolfinx.fem.Function], V: dolfinx.fem.FunctionSpace
) -> list[dolfinx.fem.Function]:
    """Interpolate ``functions`` into ``V``: exact for Lagrange functions of a mesh that
    ``V``'s refines (nested meshes); one point location per distinct source space."""
    into = Interpolation(V)
    return [into(f) for f in functions]


def _solve_level(
    method: Method,
    problem: PenalizedProblem,
    kappa: MeshKappa,
    warm: bool,
    options: Any,
) -> MethodResult:
    """Solve one level by ``method`` (its :class:`~shellobstacle.solvers.result.MethodResult`):
    the mesh's κ ladder, only its last κ when ``warm`` (κ = 0 for a method of the nodal
    problem)."""
    kappas = [0.0]
    if method.penalized:
        assert kappa.ladder != [0.0], "a penalized method needs a penalty"
        kappas = kappa.ladder[-1:] if warm else kappa.ladder
    return solve_with(method, problem, kappa.h, kappas, options)


def _free_boundary(problem: PenalizedProblem, constraint: str) -> np.ndarray:
    """The owned cells cut by the boundary of the current solution's contact set (its
    indicator's ½ level line, measured where ``constraint`` acts,
    :class:`~shellobstacle.post.contact.Postprocessor`)."""
    from shellobstacle.post.contact import Postprocessor

    contact = Postprocessor(problem, constraint).indicator().x.array > 0.5
    return free_boundary_cells(problem.mesh, contact)


def _stop(level: AdaptLevel, adapt: AdaptOptions) -> str:
    """Why the loop ends after ``level`` (empty: refine on)."""
    if adapt.target_error is not None and level.eta <= adapt.target_error:
        return f"η = {level.eta:.3e} ≤ target_error = {adapt.target_error:g}"
    if adapt.target_dofs is not None and level.dofs >= adapt.target_dofs:
        return f"{level.dofs} dofs ≥ target_dofs = {adapt.target_dofs}"
    if level.level >= adapt.max_levels:
        return f"max_levels = {adapt.max_levels} reached"
    return ""


def _line(level: AdaptLevel, reason: str) -> str:
    """The progress line of a level."""
    text = (
        f"adapt level {level.level}: {level.dofs} dofs, h_min = {level.h_min:.3g}, "
        f"η = {level.eta:.4e}, {level.iterations} solver steps"
    )
    if reason:
        return f"{text}; stop: {reason}"
    return f"{text}; {level.marked} cells marked"


def solve_adaptively(
    mesh: dolfinx.mesh.Mesh,
    shell: Shell,
    discretization: Discretization | None,
    penalty: PenaltySpec | None,
    adapt: AdaptOptions,
    options: NewtonOptions | None,
    method: str,
    method_options: Any,
    checks: list[Any],
    timings: dict[str, float],
) -> SolveResult:
    """:func:`adaptive_solve` as a :class:`~shellobstacle.solvers.result.SolveResult` (what
    :func:`~shellobstacle.api.solve_problem` returns with ``adapt``): the last level's problem
    and steps, the levels in ``extra["adapt"]``."""
    t = time.perf_counter()
    r = adaptive_solve(shell, mesh, discretization, penalty, adapt, options, method, method_options)
    timings["solve"] = time.perf_counter() - t
    problem = r.problem
    kappa = float(problem.kappa.value) if METHODS[method].penalized else 0.0
    result = SolveResult(
        problem, mesh_size(problem.mesh), kappa, r.steps, checks, timings, r.converged,
        r.error, method,
    )  # fmt: skip
    result.extra["adapt"] = {"reason": r.reason, "levels": [lv.as_dict() for lv in r.levels]}
    if "contact_pressure" in r.extra:
        result.extra["contact_pressure"] = r.extra["contact_pressure"]
    return result
