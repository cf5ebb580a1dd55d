"""One solve of the obstacle problem: mesh → checks → compile → the solver asked for.

This is what ``shellobstacle solve`` runs, and the Python API's entry point: Newton's
continuation in κ (the default), the paper's Brezis–Sibony iteration at the target κ, or the
exact nodal variational inequality (κ = 0, :func:`exact_solution`) by the active-set solver
or by one of its peers (PETSc's VI Newton, proximal Galerkin).
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from mpi4py import MPI  # noqa: F401  (MPI before dolfinx and PETSc)

import dolfinx

from shellobstacle.checks import Check, check_assumptions, require
from shellobstacle.config import NODAL_METHODS, Config, ConfigError
from shellobstacle.domains import DomainSpec
from shellobstacle.measures import mesh_size
from shellobstacle.meshing import create_mesh
from shellobstacle.model import Discretization, PenaltySpec, Shell
from shellobstacle.problem import PenalizedProblem
from shellobstacle.progress import phase
from shellobstacle.solvers.base import ConvergenceError
from shellobstacle.solvers.continuation import KappaStep, continuation
from shellobstacle.solvers.newton import NewtonOptions, NewtonSolver

__all__ = [
    "METHODS",
    "MethodStep",
    "SolveResult",
    "exact_solution",
    "make_mesh",
    "nodal_solver",
    "solve",
    "solve_config",
]

METHODS = ("newton", "brezis-sibony", *NODAL_METHODS)

Progress = Callable[[str], Any]


@dataclass
class MethodStep:
    """One solve by a method other than Newton (Brezis–Sibony, the nodal methods)."""

    method: str
    kappa: float | None
    iterations: int
    converged: bool
    reason: str
    relative_residual: float
    seconds: float
    residual_norms: list[float] = field(default_factory=list)
    details: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly record."""
        return {
            "method": self.method,
            "kappa": self.kappa,
            "converged": self.converged,
            "iterations": self.iterations,
            "reason": self.reason,
            "relative_residual": self.relative_residual,
            "seconds": self.seconds,
            **self.details,
        }


@dataclass
class SolveResult:
    """A finished (or failed) solve: the problem holding ζ, steps, checks and timings."""

    problem: PenalizedProblem
    h: float
    kappa: float
    steps: list[KappaStep | MethodStep]
    checks: list[Check]
    timings: dict[str, float] = field(default_factory=dict)
    converged: bool = True
    error: str | None = None
    method: str = "newton"
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def iterations(self) -> int:
        """Iterations summed over all steps (Newton steps over the continuation)."""
        return sum(s.iterations for s in self.steps)

    @property
    def solved_kappa(self) -> float:
        """The κ of the solution held (0 for the exact nodal problem's solution)."""
        return 0.0 if self.method in NODAL_METHODS else float(self.problem.kappa.value)

    def validity(self, post: Any = None) -> Any:
        """The solution's :class:`~shellobstacle.post.validity.Validity` (penetration,
        displacement, orientation against their thresholds); ``post``: the problem's
        :class:`~shellobstacle.post.contact.Postprocessor` if one exists. Collective."""
        from shellobstacle.post.contact import Postprocessor
        from shellobstacle.post.validity import assess

        constraint = "nodes" if self.method in NODAL_METHODS else "penalty"
        return assess(post or Postprocessor(self.problem, constraint), self.solved_kappa)


def make_mesh(domain: DomainSpec, ghosted: bool = False) -> dolfinx.mesh.Mesh:
    """Mesh ω (``ghosted``: with facet-sharing ghost cells in parallel, which Koiter's facet
    terms read); a bad domain description becomes a :class:`ConfigError` naming it."""
    try:
        size = "" if domain.h is None else f" (h = {domain.h:g})"
        with phase(f"meshing the {domain.kind}{size}"):
            return create_mesh(domain, ghosted=ghosted)
    except (ValueError, FileNotFoundError) as err:
        raise ConfigError(f"[domain]: {err}") from None


def solve(
    shell: Shell,
    domain: DomainSpec | dolfinx.mesh.Mesh,
    penalty: PenaltySpec | None,
    discretization: Discretization | None = None,
    options: NewtonOptions | None = None,
    force: bool = False,
    progress: Progress | None = None,
    method: str = "newton",
    method_options: Any = None,
    newton_progress: Callable[[int, float], Any] | None = None,
    adapt: Any = None,
) -> SolveResult:
    """Solve the obstacle problem for the shell on a domain (or a ready mesh).

    Args:
        shell: surface, material, load and obstacle.
        domain: a :class:`DomainSpec` to mesh, or a DOLFINx mesh.
        penalty: κ (or ``h^exponent``) and whether to continue from larger κ; None (unused)
            for the nodal methods (``"active-set"``, ``"snes-vi"``, ``"proximal-galerkin"``).
        discretization: element degree, boundary condition of ζ_3, penalty quadrature.
        options: Newton tolerances and linear solver.
        force: proceed (with a warning) when the theory's assumptions fail, and mesh even
            when the mesh looks too large for this machine (:mod:`shellobstacle.resources`).
        progress: called with one-line progress messages.
        method: ``"newton"`` (continuation in κ), ``"brezis-sibony"`` (the iteration (38) at
            the target κ), or the exact nodal VI (κ = 0) by ``"active-set"``, ``"snes-vi"``
            (PETSc's VI Newton) or ``"proximal-galerkin"``.
        method_options: the options of those methods (``BrezisSibonyOptions``,
            ``ActiveSetOptions``, ``SnesVIOptions``, ``ProximalGalerkinOptions``).
        newton_progress: called as ``(iteration, relative residual)`` after every Newton
            iteration (see :func:`~shellobstacle.solvers.continuation.continuation`).
        adapt: :class:`~shellobstacle.adapt.options.AdaptOptions`: solve on the mesh and its
            adaptive refinements (:func:`~shellobstacle.adapt.loop.adaptive_solve`); the
            result holds the last mesh's solution and, in ``extra["adapt"]``, every level.

    Raises:
        AssumptionError: the data violate MODEL.md §3 (unless ``force``).
        ResourceError: the mesh would not fit in this machine's memory (unless ``force``).
        ExpressionError: θ, its derivatives or the load are not finite at a point of the mesh
            (whatever ``force``: nothing can be solved there).
    """
    if method not in METHODS:
        raise ConfigError(f"solver.method must be one of {METHODS}, got {method!r}")
    if penalty is None and method not in NODAL_METHODS:
        raise ConfigError(f"solver.method = {method!r} needs a penalty (kappa or exponent)")
    say = progress or (lambda _msg: None)
    timings: dict[str, float] = {}
    t = time.perf_counter()
    if isinstance(domain, DomainSpec):
        if not force:
            from shellobstacle.resources import require_fits

            require_fits(domain, shell.model, (discretization or Discretization()).degree)
        say(f"meshing {domain.kind} (target h = {domain.h})")
        mesh = make_mesh(domain, ghosted=shell.model == "koiter" or adapt is not None)
    else:
        mesh = domain
    h = mesh_size(mesh)
    timings["mesh"] = time.perf_counter() - t

    t = time.perf_counter()
    with phase("checking the assumptions"):
        checks = check_assumptions(shell, mesh)
    timings["checks"] = time.perf_counter() - t
    if force:
        failed = [c.name for c in checks if not c.passed]
        if failed:
            warnings.warn(
                f"proceeding although assumptions fail: {', '.join(failed)}", stacklevel=2
            )
    else:
        require(checks)

    if adapt is not None:
        from shellobstacle.adapt.loop import solve_adaptively

        return solve_adaptively(
            mesh, shell, discretization, penalty, adapt, options, method, method_options,
            say, newton_progress, checks, timings,
        )  # fmt: skip
    t = time.perf_counter()
    kappas = penalty.ladder(h) if penalty is not None else [0.0]
    problem = PenalizedProblem(shell, mesh, discretization, kappa=kappas[0] or 1.0)
    timings["compile"] = time.perf_counter() - t
    result = SolveResult(problem, h, kappas[-1], [], checks, timings, method=method)
    t = time.perf_counter()
    if method == "newton":
        say(f"h = {h:.4g}, {problem.num_dofs} dofs; solving for {len(kappas)} value(s) of κ")
        _newton(result, kappas, options, say, newton_progress)
    elif method == "brezis-sibony":
        say(
            f"h = {h:.4g}, {problem.num_dofs} dofs; solving for 1 value of κ = {kappas[-1]:.3e} "
            "by Brezis–Sibony (no continuation)"
        )
        _brezis_sibony(result, method_options, say)
    else:
        say(f"h = {h:.4g}, {problem.num_dofs} dofs; the exact nodal problem (κ = 0) by {method}")
        _nodal(result, method_options, say)
    timings["solve"] = time.perf_counter() - t
    return result


def _newton(
    result: SolveResult,
    kappas: list[float],
    options: NewtonOptions | None,
    say: Progress,
    newton_progress: Callable[[int, float], Any] | None,
) -> None:
    """The continuation in κ; non-convergence is reported in ``result``, not raised."""
    problem = result.problem
    t = time.perf_counter()
    with phase("setting up Newton's solver"):
        solver = NewtonSolver(problem, options)
    result.timings["setup"] = time.perf_counter() - t
    try:
        result.steps = continuation(problem, solver, kappas, say, newton_progress=newton_progress)
    except ConvergenceError as err:
        result.steps = err.steps  # type: ignore[attr-defined]
        result.steps.append(KappaStep(float(problem.kappa.value), err.result, float("nan")))
        result.converged, result.error = False, str(err)
    for key, value in solver.timings.items():
        result.timings[f"solve.{key}"] = value


def _brezis_sibony(result: SolveResult, options: Any, say: Progress) -> None:
    """The paper's iteration (38) at the target κ; non-convergence is reported, not raised."""
    from shellobstacle.solvers.brezis_sibony import BrezisSibonySolver

    problem = result.problem
    problem.set_kappa(result.kappa)
    solver = BrezisSibonySolver(problem, result.h, options)

    def progress(k: int, increment: float) -> None:
        say(f"Brezis–Sibony step {k}: ‖ψ_k − ψ_(k−1)‖_L² = {increment:.3e}")

    r = solver.solve(progress)
    details = r.as_dict()
    for key in ("converged", "iterations", "reason", "relative_residual"):
        details.pop(key, None)
    result.steps = [
        MethodStep(
            "brezis-sibony",
            result.kappa,
            r.iterations,
            r.converged,
            r.reason,
            r.relative_residual,
            r.seconds,
            [],
            details,
        )
    ]
    say(
        f"Brezis–Sibony: {r.iterations} steps, {r.reason}; contraction observed "
        f"{r.contraction_factor:.6f}, bound {r.contraction_bound:.6f}"
    )
    if not r.converged:
        result.converged, result.error = False, f"Brezis–Sibony did not converge: {r.reason}"


def nodal_solver(problem: PenalizedProblem, method: str, options: Any = None) -> Any:
    """The solver of the nodal problem (κ = 0) that ``method`` names, built on ``problem``."""
    if method == "active-set":
        from shellobstacle.solvers.active_set import ActiveSetSolver

        return ActiveSetSolver(problem, options)
    if method == "snes-vi":
        from shellobstacle.solvers.snes_vi import SnesVISolver

        return SnesVISolver(problem, options)
    if method == "proximal-galerkin":
        from shellobstacle.solvers.proximal_galerkin import ProximalGalerkinSolver

        return ProximalGalerkinSolver(problem, options)
    raise ValueError(f"{method!r} is not one of the nodal methods {NODAL_METHODS}")


def _nodal(result: SolveResult, options: Any, say: Progress) -> None:
    """The exact nodal variational inequality (κ = 0) by ``result.method``."""
    problem = result.problem
    result.kappa = 0.0
    t0 = time.perf_counter()
    try:
        r = nodal_solver(problem, result.method, options).solve()
    except ConvergenceError as err:
        r = err.result  # type: ignore[assignment]
        result.converged, result.error = False, str(err)
    seconds = time.perf_counter() - t0
    rel = r.kkt.get("stationarity", float("nan"))  # ‖Kζ − f − Bᵀλ‖ / ‖f‖
    norms = list(getattr(r, "residual_norms", []))
    result.steps = [
        MethodStep(
            result.method, 0.0, r.iterations, r.converged, r.reason, rel, seconds, norms,
            r.details(),
        )
    ]  # fmt: skip
    result.extra["multiplier"] = r.multiplier
    result.extra["contact_pressure"] = r.contact_pressure
    say(
        f"{result.method}: {r.iterations} linear solves, {r.active_nodes} active nodes, KKT {r.kkt}"
    )


def solve_config(
    config: Config,
    force: bool = False,
    progress: Progress | None = None,
    newton_progress: Callable[[int, float], Any] | None = None,
) -> SolveResult:
    """:func:`solve` with everything taken from a validated :class:`Config`."""
    return solve(
        config.shell,
        config.domain,
        config.penalty,
        config.discretization,
        config.solver,
        force=force,
        progress=progress,
        method=config.method,
        method_options=config.method_options,
        newton_progress=newton_progress,
        adapt=config.adapt,
    )


def exact_solution(
    shell: Shell,
    mesh: dolfinx.mesh.Mesh,
    discretization: Discretization | None = None,
    options: Any = None,
) -> tuple[dolfinx.fem.Function, Any]:
    """The exact solution ``ζ^h`` of the discrete variational inequality (κ = 0) on ``mesh``,
    with the constraint ``g ≥ 0`` at the vertices and P1 elements (MODEL.md §3, §5).

    Args:
        shell: surface, material, load and obstacle.
        mesh: the mesh of ω.
        discretization: its ``transverse`` and ``quadrature_degree`` are used; the degree is
            1 and the constraint nodal whatever it says.
        options: ``ActiveSetOptions`` of the solver.

    Returns:
        ``(zeta, result)``: a Function in the P1 vector space of ``mesh`` and the
        :class:`~shellobstacle.solvers.active_set.ActiveSetResult` (KKT measures, the
        multiplier and the contact pressure).

    Raises:
        ConvergenceError: the active set did not settle or the KKT conditions do not hold.
    """
    from shellobstacle.solvers.active_set import ActiveSetSolver

    disc = dataclasses.replace(
        discretization or Discretization(), penalty_quadrature="vertex", degree=1
    )
    problem = PenalizedProblem(shell, mesh, disc)
    result = ActiveSetSolver(problem, options).solve()
    zeta = dolfinx.fem.Function(problem.V, name="zeta_exact")
    zeta.x.array[:] = problem.zeta.x.array
    return zeta, result
