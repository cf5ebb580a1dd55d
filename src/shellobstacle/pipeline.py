"""One solve of the penalized obstacle problem: mesh → checks → compile → continuation in κ.

This is what ``shellobstacle solve`` runs, and the Python API's entry point.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import dolfinx

from shellobstacle import compat  # noqa: F401
from shellobstacle.checks import Check, check_assumptions, require
from shellobstacle.config import Config, ConfigError, PenaltySpec
from shellobstacle.domains import DomainSpec, create_mesh, mesh_size
from shellobstacle.model import Shell
from shellobstacle.problem import Discretization, PenalizedProblem
from shellobstacle.solvers.newton import ConvergenceError, NewtonOptions, NewtonResult, NewtonSolver

__all__ = [
    "METHODS",
    "KappaStep",
    "MethodStep",
    "SolveResult",
    "continuation",
    "make_mesh",
    "solve",
    "solve_config",
]

METHODS = ("newton", "brezis-sibony", "active-set")

Progress = Callable[[str], Any]


@dataclass
class KappaStep:
    """One κ of a continuation: its Newton statistics and time."""

    kappa: float
    newton: NewtonResult
    seconds: float

    @property
    def iterations(self) -> int:
        """Newton steps at this κ."""
        return self.newton.iterations

    @property
    def converged(self) -> bool:
        """Whether Newton converged at this κ."""
        return self.newton.converged

    @property
    def residual_norms(self) -> list[float]:
        """Residual norms of the Newton iterates."""
        return self.newton.residual_norms

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly record."""
        r = self.newton
        return {
            "kappa": self.kappa,
            "converged": r.converged,
            "iterations": r.iterations,
            "reason": r.reason,
            "relative_residual": r.relative_residual,
            "round_off_limited": r.round_off_limited,
            "line_search_evaluations": r.line_search_evaluations,
            "linear_iterations": r.linear_iterations,
            "step_lengths": r.step_lengths,
            "seconds": self.seconds,
        }


@dataclass
class MethodStep:
    """One solve by a method other than Newton (Brezis–Sibony, the exact active-set solver)."""

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


def make_mesh(domain: DomainSpec) -> dolfinx.mesh.Mesh:
    """Mesh ω; a bad domain description becomes a :class:`ConfigError` naming it."""
    try:
        return create_mesh(domain)
    except (ValueError, FileNotFoundError) as err:
        raise ConfigError(f"[domain]: {err}") from None


def continuation(
    problem: PenalizedProblem,
    solver: NewtonSolver,
    kappas: list[float],
    progress: Progress | None = None,
    predictor: bool = True,
    newton_progress: Callable[[int, float], Any] | None = None,
) -> list[KappaStep]:
    """Solve for each κ in turn, warm-starting from the previous solution.

    With ``predictor`` the warm start is the Euler prediction along κ
    (:meth:`NewtonSolver.predict`) rather than the previous solution itself.
    ``newton_progress(it, relative_residual)`` is called after every Newton iteration; if it
    has a method ``finished(result)``, that is called with each κ's :class:`NewtonResult`.

    Raises:
        ConvergenceError: from the first κ that fails (earlier steps are in ``err.steps``).
    """
    steps: list[KappaStep] = []
    for k, kappa in enumerate(kappas):
        t0 = time.perf_counter()
        if predictor and k > 0:
            solver.predict(kappa)
        problem.set_kappa(kappa)
        try:
            result = solver.solve(newton_progress)
        except ConvergenceError as err:
            err.steps = steps  # type: ignore[attr-defined]
            raise
        if hasattr(newton_progress, "finished"):
            newton_progress.finished(result)
        steps.append(KappaStep(kappa, result, time.perf_counter() - t0))
        if progress is not None:
            progress(
                f"κ {k + 1}/{len(kappas)} = {kappa:.3e}: {result.iterations} Newton steps, "
                f"relative residual {result.relative_residual:.1e}"
            )
    return steps


def solve(
    shell: Shell,
    domain: DomainSpec | dolfinx.mesh.Mesh,
    penalty: PenaltySpec,
    discretization: Discretization | None = None,
    options: NewtonOptions | None = None,
    force: bool = False,
    progress: Progress | None = None,
    method: str = "newton",
    method_options: Any = None,
    newton_progress: Callable[[int, float], Any] | None = None,
) -> SolveResult:
    """Solve P_{M,κ}^{ε,h} for the shell on a domain (or a ready mesh).

    Args:
        shell: surface, material, load and obstacle.
        domain: a :class:`DomainSpec` to mesh, or a DOLFINx mesh.
        penalty: κ (or ``h^exponent``) and whether to continue from larger κ.
        discretization: element degree, boundary condition of ζ_3, penalty quadrature.
        options: Newton tolerances and linear solver.
        force: proceed (with a warning) when the theory's assumptions fail.
        progress: called with one-line progress messages.
        method: ``"newton"`` (continuation in κ), ``"brezis-sibony"`` (the iteration (38) at
            the target κ) or ``"active-set"`` (the exact nodal VI, κ unused).
        method_options: ``BrezisSibonyOptions`` or ``ActiveSetOptions`` for those methods.
        newton_progress: called as ``(iteration, relative residual)`` after every Newton
            iteration (see :func:`continuation`).

    Raises:
        AssumptionError: the data violate MODEL.md §3 (unless ``force``).
    """
    say = progress or (lambda _msg: None)
    timings: dict[str, float] = {}
    t = time.perf_counter()
    if isinstance(domain, DomainSpec):
        say(f"meshing {domain.kind} (target h = {domain.h})")
        mesh = make_mesh(domain)
    else:
        mesh = domain
    h = mesh_size(mesh)
    timings["mesh"] = time.perf_counter() - t

    t = time.perf_counter()
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

    t = time.perf_counter()
    kappas = penalty.ladder(h)
    problem = PenalizedProblem(shell, mesh, discretization, kappa=kappas[0])
    solver = NewtonSolver(problem, options)
    timings["compile"] = time.perf_counter() - t
    say(f"h = {h:.4g}, {problem.num_dofs} dofs; solving for {len(kappas)} value(s) of κ")

    t = time.perf_counter()
    result = SolveResult(problem, h, kappas[-1], [], checks, timings, method=method)
    if method == "newton":
        try:
            result.steps = continuation(
                problem, solver, kappas, progress, newton_progress=newton_progress
            )
        except ConvergenceError as err:
            result.steps = err.steps  # type: ignore[attr-defined]
            result.steps.append(KappaStep(float(problem.kappa.value), err.result, float("nan")))
            result.converged, result.error = False, str(err)
        for key, value in solver.timings.items():
            timings[f"solve.{key}"] = value
    elif method == "brezis-sibony":
        _brezis_sibony(result, method_options, say)
    elif method == "active-set":
        _active_set(result, method_options, say)
    else:
        raise ConfigError(f"solver.method must be one of {METHODS}, got {method!r}")
    timings["solve"] = time.perf_counter() - t
    return result


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


def _active_set(result: SolveResult, options: Any, say: Progress) -> None:
    """The exact nodal variational inequality (κ = 0)."""
    from shellobstacle.solvers.active_set import ActiveSetSolver

    problem = result.problem
    result.kappa = 0.0
    t0 = time.perf_counter()
    try:
        r = ActiveSetSolver(problem, options).solve()
    except ConvergenceError as err:
        r = err.result  # type: ignore[assignment]
        result.converged, result.error = False, str(err)
    seconds = time.perf_counter() - t0
    rel = r.kkt.get("stationarity", float("nan"))  # ‖Kζ − f − Bᵀλ‖ / ‖f‖
    details = {
        "active_nodes": r.active_nodes,
        "kkt": r.kkt,
        "kkt_relative": r.relative_kkt,
        "kkt_scales": r.scales,
        "newton_steps": r.newton_steps,
        "pdas_steps": r.pdas_steps,
        "active_history": r.active_history,
    }
    result.steps = [
        MethodStep(
            "active-set", 0.0, r.iterations, r.converged, r.reason, rel, seconds, [], details
        )
    ]
    result.extra["multiplier"] = r.multiplier
    result.extra["contact_pressure"] = r.contact_pressure
    say(f"active set: {r.iterations} steps, {r.active_nodes} active vertices, KKT {r.kkt}")


def solve_config(
    config: Config,
    force: bool = False,
    progress: Progress | None = None,
    newton_progress: Callable[[int, float], Any] | None = None,
) -> SolveResult:
    """:func:`solve` with everything taken from a validated :class:`Config`."""
    sv = config.resolved["solver"]
    method_options: Any = None
    if config.method == "brezis-sibony":
        from shellobstacle.solvers.brezis_sibony import BrezisSibonyOptions

        method_options = BrezisSibonyOptions(
            xi=sv.get("xi"),
            mass=sv["mass"],
            start=sv["start"],
            max_iterations=sv["bs_max_iterations"],
            rtol=sv["bs_rtol"],
        )
    elif config.method == "active-set":
        from shellobstacle.solvers.active_set import ActiveSetOptions

        method_options = ActiveSetOptions(max_iterations=sv["max_iterations"])
    return solve(
        config.shell,
        config.domain,
        config.penalty,
        config.discretization,
        config.solver,
        force=force,
        progress=progress,
        method=config.method,
        method_options=method_options,
        newton_progress=newton_progress,
    )
