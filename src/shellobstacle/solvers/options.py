"""Options of the solvers: Newton's method, the exact active-set solver, Brezis–Sibony, and
the peers on the nodal problem (PETSc's VI Newton, proximal Galerkin).

Plain data with their validation, importable without DOLFINx or PETSc (the configuration
builds them).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from shellobstacle.messages import not_one_of

__all__ = [
    "LINEAR_SOLVERS",
    "PETSC_OPTIONS_HELP",
    "ActiveSetOptions",
    "BrezisSibonyOptions",
    "NewtonOptions",
    "ProximalGalerkinOptions",
    "SnesVIOptions",
]

LINEAR_SOLVERS = ("auto", "direct", "iterative", "multigrid")
NESTED = ("auto", "on", "off")
FACTORIZATIONS = ("cholesky", "lu")
MASSES = ("consistent", "lumped")
STARTS = ("zero", "linearized", "current")
VI_TYPES = ("rsls", "ssls")
VI_LINE_SEARCHES = ("bt", "basic", "l2")
LINEAR_SYSTEMS = ("condensed", "mixed")
#: what ``petsc_options`` is, in every options class and in the config reference
PETSC_OPTIONS_HELP = (
    "PETSc options (names without the leading '-', e.g. ksp_type, pc_factor_mat_solver_type, "
    "mat_mumps_icntl_14) set on the main linear solver of the method under its own prefix "
    "shellobstacle_<kind><n>_ (kind: newton and zone for newton, bs_mass and bs_linearized "
    "for brezis-sibony, as for active-set, vi for snes-vi: the SNES, its KSP and PC, pg for "
    "proximal-galerkin); an option no object reads is reported in a warning"
)
_OPTION_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*")


def petsc_options_field() -> Any:
    """The ``petsc_options`` field of an options class: a table of PETSc options."""
    return field(default_factory=dict, hash=False)


def check_petsc_options(values: Mapping[str, Any]) -> None:
    """Raise ValueError for a name that is not a PETSc option name or a value PETSc cannot
    take (a string, a number or a boolean)."""
    if not isinstance(values, Mapping):
        raise ValueError(f"solver.petsc_options must be a table of options, got {values!r}")
    for name, value in values.items():
        if not isinstance(name, str) or not _OPTION_NAME.fullmatch(name):
            raise ValueError(
                f"solver.petsc_options: {name!r} is not a PETSc option name (letters, digits "
                "and _, without the leading '-' and without a prefix, e.g. ksp_type)"
            )
        if not isinstance(value, str | int | float | bool):
            raise ValueError(
                f"solver.petsc_options.{name} must be a string, a number or true/false, "
                f"got {value!r}"
            )


@dataclass(frozen=True)
class NewtonOptions:
    """Stopping rules and linear strategy of
    :class:`~shellobstacle.solvers.newton.solver.NewtonSolver`.

    Attributes:
        rtol: stop when ``‖R(ζ)‖ ≤ rtol ‖R(0)‖`` (``R(0) = −`` load vector).
        atol: stop when ``‖R(ζ)‖ ≤ atol``, an absolute floor, off (0) by default: every other
            test is relative to the problem's scale, while an ``atol`` above the load vector
            (material constants and a load of 1e-40) stops at the start with ``ζ = 0``.
        stol: stop when the Newton correction is smaller than ``stol ‖ζ‖`` (max norms).
        floor_factor: the residual is at its round-off floor when ``‖R‖ ≤ floor_factor · u ·
            (‖L‖ + ‖S‖)``, ``u`` the machine epsilon, ``L`` the load vector and ``S`` the
            penalty residual built from the magnitudes of the terms of the gap; with ``ε/κ``
            large this floor is far above ``rtol ‖L‖``, and iterating further only stirs
            round-off.
        max_iterations: give up (and raise) after this many Newton steps.
        linear_solver: ``"direct"`` (MUMPS; :mod:`~shellobstacle.solvers.linear.zone` or
            :mod:`~shellobstacle.solvers.linear.direct`) or ``"iterative"`` (inexact Newton
            with a Krylov method and a field split, GAMG on ζ_α:
            :mod:`~shellobstacle.solvers.linear.iterative`) or ``"multigrid"`` (inexact Newton
            with CG and geometric multigrid on the mesh's refinement levels:
            :mod:`~shellobstacle.solvers.linear.multigrid`); ``"auto"`` (the default):
            ``"multigrid"`` for the membrane P1 from
            :data:`~shellobstacle.mesh.memory.MULTIGRID_FROM_DOFS` dofs on a mesh with coarser
            levels, and for the membrane P1 and Koiter's model (on a mesh with coarser levels)
            wherever the direct path's memory estimate does not fit this machine, ``"direct"``
            else (:func:`~shellobstacle.mesh.memory.auto_choice`).
        factorization: of the direct solver: ``"cholesky"`` (MUMPS' LDLᵀ; the Jacobians are
            symmetric positive definite: half the memory of LU) or ``"lu"``.
        contact_zone: with the direct solver, condense every Newton step onto a contact zone
            (``K`` outside it factorized once per zone, kept across κ); ``False``: one
            factorization per κ, reused by conjugate gradients at its later steps.
        linear_rtol: the smallest relative tolerance of the Krylov solves (the iterative
            solver's forcing terms, and CG preconditioned by a kept factorization).
        nested_iteration: ``"on"``: solve the κ ladder on the coarsest level of the mesh's
            refinements, then every finer level at the last κ only, each from the coarser
            level's solution (:mod:`~shellobstacle.solvers.newton.nested`; the membrane model on a
            refined mesh; a curved obstacle's gap is linearized at each level's start); the
            finest level's result is that of the last κ.
            ``"auto"`` (the default): on one rank wherever the linear solver is multigrid and
            the problem allows it (:func:`~shellobstacle.solvers.newton.nested.nested_wanted`); with
            the direct path's contact zone, whose steps are not relaxed, it is slower.
        normal_relaxation: after a Newton step that the line search cuts below ``t = 0.5``, try
            the full step with ζ_3 relaxed (:mod:`~shellobstacle.solvers.newton.normal_relaxation`;
            the membrane model only). Nested iteration turns it on; not a config key.
        petsc_options: PETSc options for the method's solvers (:data:`PETSC_OPTIONS_HELP`).
    """

    rtol: float = 1e-10
    atol: float = 0.0
    stol: float = 1e-12
    floor_factor: float = 100.0
    max_iterations: int = 100
    linear_solver: str = field(default="auto", metadata={"choices": LINEAR_SOLVERS})
    factorization: str = field(default="cholesky", metadata={"choices": FACTORIZATIONS})
    contact_zone: bool = True
    linear_rtol: float = 1e-12
    nested_iteration: str = field(default="auto", metadata={"choices": NESTED})
    normal_relaxation: bool = False
    petsc_options: Mapping[str, Any] = petsc_options_field()

    def __post_init__(self) -> None:
        check_petsc_options(self.petsc_options)
        if self.linear_solver not in LINEAR_SOLVERS:
            raise ValueError(not_one_of("solver.linear_solver", self.linear_solver, LINEAR_SOLVERS))
        if self.nested_iteration not in NESTED:
            raise ValueError(not_one_of("solver.nested_iteration", self.nested_iteration, NESTED))
        if self.factorization not in FACTORIZATIONS:
            raise ValueError(not_one_of("solver.factorization", self.factorization, FACTORIZATIONS))
        if self.max_iterations < 1:
            raise ValueError(f"solver.max_iterations must be >= 1, got {self.max_iterations}")
        for name in ("rtol", "atol", "stol", "linear_rtol"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"solver.{name} must be >= 0, got {getattr(self, name)}")
        if not self.floor_factor > 0:
            raise ValueError(f"floor_factor must be > 0, got {self.floor_factor}")


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
        petsc_options: PETSc options for the method's solvers (:data:`PETSC_OPTIONS_HELP`).
    """

    max_iterations: int = 200
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
class BrezisSibonyOptions:
    """Step, mass matrix, start and stopping rules of the Brezis–Sibony iteration
    (:class:`~shellobstacle.solvers.brezis_sibony.iteration.BrezisSibonySolver`).

    Attributes:
        xi: ``Ξ`` of (38), the step being ``τ = Ξ h⁴``; ``None`` chooses
            ``τ = 2 / (λ_max (1 + safety))`` from the estimated spectrum.
        safety: ``s`` in the automatic step (``τ λ_max = 2 / (1 + s) < 2``).
        mass: ``"consistent"`` (the paper's mass matrix) or ``"lumped"`` (row sums, P1 only).
        start: ``"zero"``, ``"linearized"`` (the unconstrained solution ``K ψ_0 = L``: one linear
            solve with the elastic matrix and the load) or ``"current"`` (``problem.zeta``).
        rtol: stop when ``‖ψ_{k+1} − ψ_k‖_{L²} ≤ rtol ‖ψ_k‖_{L²}`` (0 disables). The error
            left is up to ``ρ/(1 − ρ)`` times the last increment, and ``1/(1 − ρ)`` is
            10³–10⁴ on the paper's meshes: hence the small default.
        rtol_residual: stop when ``‖R(ψ)‖ ≤ rtol_residual ‖R(0)‖`` (Euclidean norms of the
            residual vector, as in Newton; 0 disables). Either criterion ends the iteration.
        max_iterations: stop (with ``converged=False``, no exception) after this many steps.
        progress_every: call ``progress(k, ‖ψ_k − ψ_{k−1}‖_{L²})`` every this many steps.
        history_stride: record every this many increments in ``result.increments``.
        tail: the number of final steps over which ``contraction_factor_tail`` is measured.
        estimate_spectrum: estimate ``λ_min``, ``λ_max`` also when ``xi`` is given (for the
            reported bound); always done when ``xi`` is ``None``.
        eigen_tol: relative tolerance of the SLEPc eigensolves.
        eigen_max_iterations: iteration cap of the SLEPc eigensolves.
        divergence_factor: give up when an increment exceeds this times the first one.
        petsc_options: PETSc options for the method's solvers (:data:`PETSC_OPTIONS_HELP`).
    """

    xi: float | None = None
    safety: float = 0.1
    mass: str = field(default="consistent", metadata={"choices": MASSES})
    start: str = field(default="linearized", metadata={"choices": STARTS})
    rtol: float = 1e-12
    rtol_residual: float = 1e-10
    max_iterations: int = 200_000
    progress_every: int = 1000
    history_stride: int = 1
    tail: int = 100
    estimate_spectrum: bool = True
    eigen_tol: float = 1e-8
    eigen_max_iterations: int = 1000
    divergence_factor: float = 1e8
    petsc_options: Mapping[str, Any] = petsc_options_field()

    def __post_init__(self) -> None:
        check_petsc_options(self.petsc_options)
        if self.mass not in MASSES:
            raise ValueError(not_one_of("solver.mass", self.mass, MASSES))
        if self.start not in STARTS:
            raise ValueError(not_one_of("solver.start", self.start, STARTS))
        if self.xi is not None and not self.xi > 0:
            raise ValueError(f"solver.xi must be > 0 (omit it: automatic step), got {self.xi}")
        if not self.safety > 0:
            raise ValueError(f"safety must be > 0, got {self.safety}")
        if self.rtol < 0 or self.rtol_residual < 0:
            raise ValueError("rtol and rtol_residual must be >= 0")
        for name in ("progress_every", "history_stride", "tail"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if self.max_iterations < 0:
            raise ValueError(f"max_iterations must be >= 0, got {self.max_iterations}")


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
        petsc_options: PETSc options for the method's solvers (:data:`PETSC_OPTIONS_HELP`).
    """

    vi_type: str = field(default="rsls", metadata={"choices": VI_TYPES})
    line_search: str = field(default="l2", metadata={"choices": VI_LINE_SEARCHES})
    rtol: float = 1e-10
    atol: float = 1e-50
    stol: float = 1e-12
    max_iterations: int = 100
    factorization: str = field(default="cholesky", metadata={"choices": FACTORIZATIONS})
    kkt_rtol: float = 1e-6
    warm_start: bool = True
    scaling: bool = True
    petsc_options: Mapping[str, Any] = petsc_options_field()

    def __post_init__(self) -> None:
        check_petsc_options(self.petsc_options)
        if self.vi_type not in VI_TYPES:
            raise ValueError(not_one_of("solver.vi_type", self.vi_type, VI_TYPES))
        if self.line_search not in VI_LINE_SEARCHES:
            raise ValueError(
                not_one_of("solver.vi_line_search", self.line_search, VI_LINE_SEARCHES)
            )
        if self.factorization not in FACTORIZATIONS:
            raise ValueError(not_one_of("solver.factorization", self.factorization, FACTORIZATIONS))
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
        petsc_options: PETSc options for the method's solvers (:data:`PETSC_OPTIONS_HELP`).
    """

    tol: float = 1e-9
    alpha_initial: float = 1.0
    alpha_base: float = 1.5
    alpha_exponent: float = 1.5
    alpha_max: float = 1e5
    max_iterations: int = 100
    newton_rtol: float = 1e-10
    max_newton_iterations: int = 50
    max_rejections: int = 5
    regrowth: float = 2.0
    linear_system: str = field(default="condensed", metadata={"choices": LINEAR_SYSTEMS})
    factorization: str = field(default="cholesky", metadata={"choices": FACTORIZATIONS})
    kkt_rtol: float = 1e-6
    warm_start: bool = True
    petsc_options: Mapping[str, Any] = petsc_options_field()

    def __post_init__(self) -> None:
        check_petsc_options(self.petsc_options)
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
        if self.factorization not in FACTORIZATIONS:
            raise ValueError(not_one_of("solver.factorization", self.factorization, FACTORIZATIONS))
        if self.linear_system not in LINEAR_SYSTEMS:
            raise ValueError(not_one_of("linear_system", self.linear_system, LINEAR_SYSTEMS))

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
