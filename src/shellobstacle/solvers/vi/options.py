"""The options of the solvers of the nodal problem: the active-set method
(:class:`ActiveSetOptions`), PETSc's VI Newton (:class:`SnesVIOptions`) and proximal Galerkin
(:class:`ProximalGalerkinOptions`), each ``[solver]`` key declared on its field
(:func:`~shellobstacle.solvers.options.option`)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from shellobstacle.solvers.options import (
    FACTORIZATION_HELP,
    FACTORIZATIONS,
    check_choices,
    check_petsc_options,
    option,
    petsc_options_field,
)

__all__ = [
    "LINEAR_SYSTEMS",
    "VI_LINE_SEARCHES",
    "VI_TYPES",
    "ActiveSetOptions",
    "ProximalGalerkinOptions",
    "SnesVIOptions",
]

VI_TYPES = ("rsls", "ssls")
VI_LINE_SEARCHES = ("bt", "basic", "l2")
LINEAR_SYSTEMS = ("condensed", "mixed")


@dataclass(frozen=True)
class ActiveSetOptions:
    """Path-following schedule, limits and acceptance tolerance of the exact solver
    (:class:`~shellobstacle.solvers.vi.active_set.ActiveSetSolver`).

    Attributes:
        max_iterations: give up (and raise) after this many linear solves in total.
        gamma_initial: first Moreau–Yosida parameter ``γ`` (penalty ``γ K'_bb`` per constraint).
        gamma_factor: ``γ`` is multiplied by this between path-following stages.
        gamma_max: largest ``γ``; beyond it the solver gives up.
        max_stage_iterations: semismooth Newton steps allowed for one ``γ``.
        max_pdas_iterations: primal–dual active-set steps per attempt before ``γ`` grows.
        kkt_rtol: the answer is accepted only if the relative KKT measures
            (``ActiveSetResult.relative_kkt``) are all at most this.
        warm_start: start from the current ``problem.zeta`` (first trying active-set steps
            from it) instead of from zero.
        petsc_options: PETSc options for the method's solvers
            (:data:`~shellobstacle.solvers.options.PETSC_OPTIONS_HELP`).
    """

    max_iterations: int = option(200, help="linear solves")
    gamma_initial: float = 1e-4
    gamma_factor: float = 100.0
    gamma_max: float = 1e16
    max_stage_iterations: int = 50
    max_pdas_iterations: int = 6
    kkt_rtol: float = 1e-10
    warm_start: bool = True
    petsc_options: Mapping[str, Any] = petsc_options_field()

    def __post_init__(self) -> None:
        check_petsc_options(self.petsc_options)
        if self.max_iterations < 1:
            raise ValueError(f"max_iterations must be >= 1, got {self.max_iterations}")
        if self.max_stage_iterations < 1 or self.max_pdas_iterations < 1:
            raise ValueError("max_stage_iterations and max_pdas_iterations must be >= 1")
        if not 0 < self.gamma_initial <= self.gamma_max:
            raise ValueError(
                f"need 0 < gamma_initial <= gamma_max, got {self.gamma_initial}, {self.gamma_max}"
            )
        if not self.gamma_factor > 1:
            raise ValueError(f"gamma_factor must be > 1, got {self.gamma_factor}")
        if not self.kkt_rtol > 0:
            raise ValueError(f"kkt_rtol must be > 0, got {self.kkt_rtol}")


@dataclass(frozen=True)
class SnesVIOptions:
    """PETSc's VI Newton on the nodal problem
    (:class:`~shellobstacle.solvers.vi.snes_vi.SnesVISolver`).

    Attributes:
        vi_type: ``"rsls"`` (reduced space: Newton on the unknowns off their bounds,
            ``SNESVINEWTONRSLS``) or ``"ssls"`` (semismooth Newton on the Fischer–Burmeister
            reformulation, ``SNESVINEWTONSSLS``).
        line_search: PETSc's line search (``SNESLineSearchType``): ``"l2"`` (a secant
            method on ``‖F‖²``), ``"bt"`` (backtracking on ``‖F‖``, PETSc's default for both;
            on ``examples/cylinder_koiter.toml`` rsls with it stops with
            ``DIVERGED_LINE_SEARCH`` or at 100 steps, and on the paper's problem it takes about
            three times l2's steps) or ``"basic"`` (full steps: rsls cycles between active
            sets on the paper's problem).
        rtol, atol, stol: PETSc's tolerances on the VI residual (relative to the first,
            absolute) and on the relative step length.
        max_iterations: PETSc's iteration cap.
        factorization: of the linear solves (MUMPS): ``"cholesky"`` (``LDLᵀ``; ``rsls``'s
            reduced matrices are principal submatrices of ``K'``, symmetric) or ``"lu"``;
            ``ssls``'s matrices are not symmetric and are always factorized by LU.
        kkt_rtol: a solve whose relative KKT measures exceed this is reported as not
            converged, whatever PETSc says.
        warm_start: start from the current ``problem.zeta`` (projected onto the bounds by
            PETSc) instead of from zero.
        scaling: solve for ``v = D^{1/2} u`` (``D = diag K'``), so that ``F`` and the
            distance to a bound have the same units (Fischer–Burmeister compares them);
            ``False``: the rotated unknowns as they are.
        petsc_options: PETSc options for the method's solvers
            (:data:`~shellobstacle.solvers.options.PETSC_OPTIONS_HELP`).
    """

    vi_type: str = option(
        "rsls",
        choices=VI_TYPES,
        help="PETSc's reduced-space (rsls) or semismooth Fischer–Burmeister (ssls) Newton",
    )
    line_search: str = option(
        "l2",
        key="vi_line_search",
        choices=VI_LINE_SEARCHES,
        help="PETSc's line search (l2: secant on ‖F‖²; bt, PETSc's default: backtracking, "
        "which stalls on Koiter's cylinder_koiter.toml; basic: full steps)",
    )
    rtol: float = option(1e-10, help="relative residual tolerance")
    atol: float = 1e-50
    stol: float = option(1e-12, help="relative Newton-correction tolerance")
    max_iterations: int = option(100, help="PETSc's Newton steps")
    factorization: str = option("cholesky", choices=FACTORIZATIONS, help=FACTORIZATION_HELP)
    kkt_rtol: float = 1e-6
    warm_start: bool = True
    scaling: bool = True
    petsc_options: Mapping[str, Any] = petsc_options_field()

    def __post_init__(self) -> None:
        check_petsc_options(self.petsc_options)
        check_choices(self)
        if self.max_iterations < 1:
            raise ValueError(f"solver.max_iterations must be >= 1, got {self.max_iterations}")
        for name in ("rtol", "atol", "stol"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"solver.{name} must be >= 0, got {getattr(self, name)}")
        if not self.kkt_rtol > 0:
            raise ValueError(f"kkt_rtol must be > 0, got {self.kkt_rtol}")


@dataclass(frozen=True)
class ProximalGalerkinOptions:
    """The latent-variable proximal point method on the nodal problem
    (:class:`~shellobstacle.solvers.vi.proximal_galerkin.ProximalGalerkinSolver`).

    The proximal parameter is ``α_k = α̂_k / P`` with ``P`` the largest nodal load pressure
    (``|f_i| / m_i``), so that ``α̂`` is dimensionless (a node pressed by the full load
    moves its latent variable by ``α̂`` per step). ``α̂_k`` follows the authors'
    double-exponential rule ``α̂_k = max(C r^{q^k} − α̂_{k−1}, C)``, capped at ``alpha_max``.
    A step whose Newton iteration fails (``max_newton_iterations`` reached, or a non-finite
    residual) is taken again from its start with ``α̂`` ten times smaller, and from then on
    ``α̂`` grows by at most ``regrowth`` per step. Newton fails where a node leaves contact
    after a step with a large ``α̂`` (its latent variable, driven far below zero, must rise,
    and Newton's linearization of ``e^φ`` from below overshoots) or where ``α̂`` times the
    contact pressure over ``P`` is large; a bounded ``α̂`` would leave the proximal point
    iteration sublinear. On ``examples/cylinder_koiter.toml`` (bending concentrates the contact
    force at the rim of the contact zone) the authors' rule alone fails on the finer meshes,
    and a regrowth of 2 converges where 10 does not (docs/perf/peers.md).

    Attributes:
        tol: stop when ``‖u_k − u_{k−1}‖ ≤ tol ‖u_k‖`` (Euclidean norms of the nodal vectors).
        alpha_initial: ``C``.
        alpha_base, alpha_exponent: ``r`` and ``q``.
        alpha_max: the cap of ``α̂``.
        max_iterations: proximal steps before giving up.
        newton_rtol: each step's Newton iteration stops when both parts of its residual are
            this small relative to their scales (``α ‖f'‖`` and ``‖m ψ‖``).
        max_newton_iterations: Newton steps allowed per proximal step.
        max_rejections: failed steps (each reducing ``α̂``) before giving up.
        regrowth: the largest factor of ``α̂`` from one step to the next after a failure.
        linear_system: ``"condensed"`` (the nodal latent variable eliminated from each Newton
            step: a symmetric positive definite matrix with ``K'``'s sparsity) or
            ``"mixed"`` (the symmetric indefinite matrix in ``(u, φ)``, as the authors'
            examples solve it); the same Newton iterates up to round-off.
        factorization: of the Newton matrix by MUMPS: ``"cholesky"`` (``LDLᵀ``; with
            pivoting for the mixed matrix) or ``"lu"``.
        kkt_rtol: a solve whose relative KKT measures exceed this is reported as not
            converged.
        warm_start: start from the current ``problem.zeta`` instead of from zero.
        petsc_options: PETSc options for the method's solvers
            (:data:`~shellobstacle.solvers.options.PETSC_OPTIONS_HELP`).
    """

    tol: float = option(
        1e-9,
        key="proximal_tol",
        help="stop at a relative increment ‖u_k − u_(k−1)‖/‖u_k‖ below this",
    )
    alpha_initial: float = 1.0
    alpha_base: float = 1.5
    alpha_exponent: float = 1.5
    alpha_max: float = option(
        1e5, key="proximal_alpha_max", help="cap of the (dimensionless) proximal parameter α̂"
    )
    max_iterations: int = option(100, help="proximal steps")
    newton_rtol: float = option(
        1e-10,
        key="rtol",
        help="relative residual tolerance of each proximal step's Newton iteration",
    )
    max_newton_iterations: int = 50
    max_rejections: int = 5
    regrowth: float = 2.0
    linear_system: str = field(default="condensed", metadata={"choices": LINEAR_SYSTEMS})
    factorization: str = option("cholesky", choices=FACTORIZATIONS, help=FACTORIZATION_HELP)
    kkt_rtol: float = 1e-6
    warm_start: bool = True
    petsc_options: Mapping[str, Any] = petsc_options_field()

    def __post_init__(self) -> None:
        check_petsc_options(self.petsc_options)
        check_choices(self)
        if not self.tol > 0:
            raise ValueError(
                f"solver.proximal_tol must be > 0, got {self.tol}: the relative increment "
                "at which the proximal iteration stops, e.g. 1e-9"
            )
        if not 0 < self.alpha_initial <= self.alpha_max:
            raise ValueError(
                f"need 0 < alpha_initial <= solver.proximal_alpha_max, got "
                f"{self.alpha_initial}, {self.alpha_max}"
            )
        if not (self.alpha_base > 1 and self.alpha_exponent >= 1):
            raise ValueError("alpha_base must be > 1 and alpha_exponent >= 1")
        if self.max_iterations < 1 or self.max_newton_iterations < 1:
            raise ValueError("max_iterations and max_newton_iterations must be >= 1")
        if self.max_rejections < 0:
            raise ValueError(f"max_rejections must be >= 0, got {self.max_rejections}")
        if not self.regrowth > 1:
            raise ValueError(f"regrowth must be > 1, got {self.regrowth}")
        if not self.newton_rtol > 0 or not self.kkt_rtol > 0:
            raise ValueError("newton_rtol and kkt_rtol must be > 0")

    def alphas(self) -> list[float]:
        """``α̂_0, α̂_1, …`` for ``max_iterations`` steps."""
        out: list[float] = []
        previous = self.alpha_initial  # the previous α̂ before the cap
        log_r = math.log(self.alpha_base)
        for k in range(self.max_iterations):
            exponent = k * math.log(self.alpha_exponent) + math.log(log_r)  # log(q^k log r)
            if exponent < math.log(700.0):  # beyond, C r^{q^k} overflows: α̂ stays
                grown = self.alpha_initial * math.exp(math.exp(exponent))
                previous = max(grown - previous, self.alpha_initial)
            out.append(min(previous, self.alpha_max))
        return out
