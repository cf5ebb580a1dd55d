"""One solve of the obstacle problem: mesh → checks → compile → the solver asked for.

:func:`solve` takes a configuration (a :class:`~shellobstacle.config.loader.Config`, a TOML
file or a mapping shaped like one) and overrides of its sections: it is what ``shellobstacle
solve`` runs, and the Python API's entry point. :func:`solve_problem` is the same solve for
code that holds the objects already (a mesh, a shell, the options). The method is taken by
name from :data:`~shellobstacle.solvers.registry.METHODS`: Newton's continuation in κ (the
default), the paper's Brezis–Sibony iteration at the target κ, or the exact nodal
variational inequality (κ = 0, :func:`exact_solution`) by the active-set solver or by one of
its peers (PETSc's VI Newton, proximal Galerkin).
"""

from __future__ import annotations

import dataclasses
import logging
import time
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from mpi4py import MPI  # noqa: F401  (MPI before dolfinx and PETSc)

import dolfinx

from shellobstacle.checks.assumptions import check_assumptions, require
from shellobstacle.config.loader import Config, ConfigError, as_config
from shellobstacle.config.validated import require_penalty
from shellobstacle.mesh.domains import DomainSpec
from shellobstacle.mesh.measures import mesh_size, num_cells_global
from shellobstacle.mesh.meshing import create_mesh
from shellobstacle.messages import not_one_of
from shellobstacle.models.problem import PenalizedProblem
from shellobstacle.penalty.kappa import kappa_on_mesh
from shellobstacle.penalty.spec import PenaltySpec
from shellobstacle.progress import phase
from shellobstacle.solvers.auto import estimated_linear_solver, resolve, takes_linear_solver
from shellobstacle.solvers.linearization import solve_with
from shellobstacle.solvers.registry import METHODS, options_for
from shellobstacle.solvers.result import SolveResult
from shellobstacle.spec import Discretization, Shell

if TYPE_CHECKING:
    from shellobstacle.adapt.options import AdaptOptions
    from shellobstacle.solvers.vi.active_set import ActiveSetResult
    from shellobstacle.solvers.vi.options import ActiveSetOptions

__all__ = [
    "METHODS",
    "SolveResult",
    "exact_solution",
    "make_mesh",
    "nodal_solver",
    "solve",
    "solve_problem",
]

log = logging.getLogger(__name__)


def make_mesh(domain: DomainSpec, ghosted: bool = False) -> dolfinx.mesh.Mesh:
    """Mesh ω (``ghosted``: with facet-sharing ghost cells in parallel, which Koiter's facet
    terms read); a bad domain description becomes a :class:`ConfigError` naming it.
    Logs the mesh obtained: its h (the largest cell diameter) beside the size asked for
    (gmsh's target is not the largest cell diameter). Collective."""
    try:
        size = "" if domain.h is None else f" (h = {domain.h:g})"
        with phase(f"meshing the {domain.kind}{size}"):
            mesh = create_mesh(domain, ghosted=ghosted)
    except (ValueError, FileNotFoundError) as err:
        raise ConfigError(f"[domain]: {err}") from None
    log.info(_obtained(domain, mesh))  # (computed on every rank: collective)
    return mesh


def _obtained(domain: DomainSpec, mesh: dolfinx.mesh.Mesh) -> str:
    """``meshed the disk: h = 0.0139 (target 0.01), 7362 cells`` (collective)."""
    h, cells = mesh_size(mesh), num_cells_global(mesh)
    if domain.h is None:
        return f"read the mesh {domain.path}: h = {h:.4g}, {cells} cells"
    asked = [f"target {domain.h:g}"]
    if domain.central_h is not None:
        asked.append(f"{domain.central_h:g} in the centre")
    if domain.edge_h is not None:
        asked.append(f"{domain.edge_h:g} along the boundary")
    if domain.refinements:
        asked.append(f"then {domain.refinements} uniform refinement(s)")
    return f"meshed the {domain.kind}: h = {h:.4g} ({', '.join(asked)}), {cells} cells"


def solve(
    spec: Config | str | Path | Mapping[str, Any], *, force: bool = False, **overrides: Any
) -> SolveResult:
    """Solve the obstacle problem a configuration describes.

    Example::

        result = solve("examples/paper.toml", domain={"h": 0.02}, solver={"method": "active-set"})
        result.contact.area, result.validity.warnings()

    Args:
        spec: a validated :class:`~shellobstacle.config.loader.Config` (read by
            :func:`~shellobstacle.config.loader.load_config`, or built in Python:
            ``Config(shell, DomainSpec("disk", h=0.02), penalty=PenaltySpec(exponent=1.5))``),
            the path of a TOML config file, or a mapping shaped like one.
        force: proceed (with a warning) when the theory's assumptions fail, and mesh even
            when the mesh looks too large for this machine.
        overrides: sections of the config, each a mapping of its keys
            (``domain={"h": 0.02}``), applied and validated as ``--set domain.h=0.02`` is
            (the same checks and messages). ``solver`` may instead be an options object,
            an instance of a method's ``options_type`` (``NewtonOptions(rtol=1e-8)``,
            ``ActiveSetOptions(…)``): it chooses that method and is the one set of options
            it solves with.

    Returns:
        The :class:`SolveResult`: ``zeta``, ``contact``, ``validity``, ``timings``, ….

    Raises:
        ConfigError: a spec or an override the configuration refuses, in one line naming it
            and the fix.
        AssumptionError, ResourceError, ExpressionError: as :func:`solve_problem`.
    """
    config = as_config(spec, overrides)
    return solve_problem(
        config.shell,
        config.domain,
        config.penalty,
        config.discretization,
        method=config.method,
        options=config.options,
        force=force,
        adapt=config.adapt,
    )


def solve_problem(
    shell: Shell,
    domain: DomainSpec | dolfinx.mesh.Mesh,
    penalty: PenaltySpec | None,
    discretization: Discretization | None = None,
    *,
    method: str = "newton",
    options: Any = None,
    force: bool = False,
    adapt: AdaptOptions | None = None,
) -> SolveResult:
    """Solve the obstacle problem for the shell on a domain (or a ready mesh): :func:`solve`
    for code that holds the objects (a mesh, the options) rather than a configuration.

    Progress (the mesh obtained, each κ solved) is logged to the ``shellobstacle`` logger.

    Args:
        shell: surface, material, load and obstacle.
        domain: a :class:`DomainSpec` to mesh, or a DOLFINx mesh.
        penalty: κ (or ``h^exponent``) and whether to continue from larger κ; None (unused)
            for the methods of the nodal problem (κ = 0: not ``penalized``).
        discretization: element degree, boundary condition of ζ_3, penalty quadrature.
        method: a key of :data:`~shellobstacle.solvers.registry.METHODS`: ``"newton"``
            (continuation in κ), ``"brezis-sibony"`` (the iteration (38) at the target κ), or
            the exact nodal VI (κ = 0) by ``"active-set"``, ``"snes-vi"`` (PETSc's VI Newton)
            or ``"proximal-galerkin"``.
        options: the options of that method, an instance of its ``options_type``
            (``NewtonOptions``, ``BrezisSibonyOptions``, ``ActiveSetOptions``,
            ``SnesVIOptions``, ``ProximalGalerkinOptions``); None: its defaults.
        force: proceed (with a warning) when the theory's assumptions fail, and mesh even
            when the mesh looks too large for this machine (:mod:`shellobstacle.mesh.resources`).
        adapt: :class:`~shellobstacle.adapt.options.AdaptOptions`: solve on the mesh and its
            adaptive refinements (:func:`~shellobstacle.adapt.loop.adaptive_solve`); the
            result holds the last mesh's solution and, in ``extra["adapt"]``, every level.

    Raises:
        ConfigError: an unknown method, or a penalized one without ``penalty``.
        TypeError: ``options`` are not of the method's ``options_type``.
        AssumptionError: the data violate docs/model.md §3 (unless ``force``).
        ResourceError: the mesh would not fit in this machine's memory (unless ``force``).
        ExpressionError: θ, its derivatives or the load are not finite at a point of the mesh
            (whatever ``force``: nothing can be solved there).
    """
    if method not in METHODS:
        raise ConfigError(not_one_of("solver.method", method, METHODS.keys()))
    chosen = METHODS[method]
    require_penalty(method, penalty)
    opts = options_for(chosen, options)
    if shell.kinematics == "nonlinear":
        _require_nonlinear_choices(method, opts, discretization, adapt)
    timings: dict[str, float] = {}
    t = time.perf_counter()
    if isinstance(domain, DomainSpec):
        if not force:
            from shellobstacle.mesh.resources import require_fits

            degree = (discretization or Discretization()).degree
            linear = estimated_linear_solver(chosen, opts, domain, shell.model, degree)
            require_fits(domain, shell.model, degree, linear_solver=linear)
        mesh = make_mesh(domain, shell.model == "koiter" or adapt is not None)
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
            mesh, shell, discretization, penalty, adapt, None, method, opts, checks, timings
        )
    t = time.perf_counter()
    kappas = kappa_on_mesh(penalty, mesh).ladder
    if shell.kinematics == "nonlinear":
        problem: Any = _nonlinear_problem(shell, mesh, discretization, kappas[0])
    else:
        problem = PenalizedProblem(
            shell, mesh, discretization, kappa=kappas[0] if chosen.penalized else None
        )
    timings["compile"] = time.perf_counter() - t
    target = kappas[-1] if chosen.penalized else 0.0
    result = SolveResult(problem, h, target, [], checks, timings, method=method)
    t = time.perf_counter()
    if takes_linear_solver(chosen) and shell.kinematics == "linear":  # "auto" resolved once
        resolution = resolve(problem, opts or chosen.options_type())
        opts, result.extra["choices"] = resolution.options, resolution.record()
        if resolution.said():
            log.info(resolution.said())
    done = solve_with(chosen, problem, h, kappas, opts)
    result.steps, result.converged, result.error = done.steps, done.converged, done.error
    result.extra.update(done.extra)
    timings.update(done.timings)
    timings["solve"] = time.perf_counter() - t
    return result


def _require_nonlinear_choices(
    method: str, options: Any, discretization: Discretization | None, adapt: Any
) -> None:
    """Refuse, in one line, what the solver of ``kinematics = "nonlinear"`` (load stepping,
    a direct solver, docs/model.md §11.3) cannot take."""
    if method != "newton":
        raise ConfigError(
            f"model.kinematics = 'nonlinear' is solved by load stepping with Newton's method: "
            f"set solver.method = 'newton' (got {method!r})"
        )
    if getattr(options, "linear_solver", "direct") not in ("auto", "direct"):
        raise ConfigError(
            "model.kinematics = 'nonlinear' has the direct linear solver only (its tangent is "
            "indefinite): set solver.linear_solver = 'direct'"
        )
    if (discretization or Discretization()).bending != "c0ip":
        raise ConfigError(
            "model.kinematics = 'nonlinear' has the C⁰ interior-penalty bending form only: "
            "set discretization.bending = 'c0ip'"
        )
    if adapt is not None:
        raise ConfigError(
            "model.kinematics = 'nonlinear' is solved on one mesh: remove the [adapt] section"
        )


def _nonlinear_problem(
    shell: Shell, mesh: dolfinx.mesh.Mesh, discretization: Discretization | None, kappa: float
) -> Any:
    """The nonlinear Koiter problem (docs/model.md §11.3) with the obstacle's penalty at
    ``kappa``, its forms compiled at ``-O0``."""
    from shellobstacle.models.nonlinear_koiter import FAST_COMPILE, NonlinearKoiterProblem

    disc = discretization or Discretization()
    with phase("compiling the nonlinear forms"):
        return NonlinearKoiterProblem(shell, mesh, disc, jit_options=FAST_COMPILE, kappa=kappa)


def nodal_solver(problem: PenalizedProblem, method: str, options: Any = None) -> Any:
    """The solver of the nodal problem (κ = 0) that ``method`` names, built on ``problem``
    (``METHODS[method].solver``)."""
    chosen = METHODS.get(method)
    if chosen is None or chosen.penalized or not hasattr(chosen, "solver"):
        nodal = [m.name for m in METHODS.values() if not m.penalized]
        raise ValueError(f"{method!r} is not one of the nodal methods {tuple(nodal)}")
    return chosen.solver(problem, options)


def exact_solution(
    shell: Shell,
    mesh: dolfinx.mesh.Mesh,
    discretization: Discretization | None = None,
    options: ActiveSetOptions | None = None,
) -> tuple[dolfinx.fem.Function, ActiveSetResult]:
    """The exact solution ``ζ^h`` of the discrete variational inequality (κ = 0) on ``mesh``,
    with the constraint ``g ≥ 0`` at the vertices and P1 elements (docs/model.md §5).

    Args:
        shell: surface, material, load and obstacle.
        mesh: the mesh of ω.
        discretization: its ``transverse`` and ``quadrature_degree`` are used; the degree is
            1 and the constraint nodal whatever it says.
        options: ``ActiveSetOptions`` of the solver.

    Returns:
        ``(zeta, result)``: a Function in the P1 vector space of ``mesh`` and the
        :class:`~shellobstacle.solvers.vi.active_set.ActiveSetResult` (KKT measures, the
        multiplier and the contact pressure).

    Raises:
        ConvergenceError: the active set did not settle or the KKT conditions do not hold.
    """
    from shellobstacle.solvers.vi.active_set import ActiveSetSolver

    disc = dataclasses.replace(
        discretization or Discretization(), penalty_quadrature="vertex", degree=1
    )
    problem = PenalizedProblem(shell, mesh, disc, kappa=None)
    result = ActiveSetSolver(problem, options).solve()
    zeta = dolfinx.fem.Function(problem.V, name="zeta_exact")
    zeta.x.array[:] = problem.zeta.x.array
    return zeta, result
