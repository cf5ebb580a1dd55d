"""Options of the solvers: Newton's method, the exact active-set solver, Brezis–Sibony.

Plain data with their validation, importable without DOLFINx or PETSc (the configuration
builds them).
"""

from __future__ import annotations

from dataclasses import dataclass

from shellobstacle.messages import not_one_of

__all__ = [
    "LINEAR_SOLVERS",
    "ActiveSetOptions",
    "BrezisSibonyOptions",
    "NewtonOptions",
]

LINEAR_SOLVERS = ("direct", "iterative")
FACTORIZATIONS = ("cholesky", "lu")
MASSES = ("consistent", "lumped")
STARTS = ("zero", "linearized", "current")


@dataclass(frozen=True)
class NewtonOptions:
    """Stopping rules and linear strategy of :class:`~shellobstacle.solvers.newton.NewtonSolver`.

    Attributes:
        rtol: stop when ``‖R(ζ)‖ ≤ rtol ‖R(0)‖`` (``R(0) = −`` load vector).
        atol: stop when ``‖R(ζ)‖ ≤ atol``.
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
            :mod:`~shellobstacle.solvers.linear.iterative`).
        factorization: of the direct solver: ``"cholesky"`` (MUMPS' LDLᵀ; the Jacobians are
            symmetric positive definite: half the memory of LU) or ``"lu"``.
        contact_zone: with the direct solver, condense every Newton step onto a contact zone
            (``K`` outside it factorized once per zone, kept across κ); ``False``: one
            factorization per κ, reused by conjugate gradients at its later steps.
        linear_rtol: the smallest relative tolerance of the Krylov solves (the iterative
            solver's forcing terms, and CG preconditioned by a kept factorization).
    """

    rtol: float = 1e-10
    atol: float = 1e-30
    stol: float = 1e-12
    floor_factor: float = 100.0
    max_iterations: int = 100
    linear_solver: str = "direct"
    factorization: str = "cholesky"
    contact_zone: bool = True
    linear_rtol: float = 1e-12

    def __post_init__(self) -> None:
        if self.linear_solver not in LINEAR_SOLVERS:
            raise ValueError(not_one_of("solver.linear_solver", self.linear_solver, LINEAR_SOLVERS))
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
    (:class:`~shellobstacle.solvers.active_set.ActiveSetSolver`).

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
    """

    max_iterations: int = 200
    gamma_initial: float = 1e-4
    gamma_factor: float = 100.0
    gamma_max: float = 1e16
    max_stage_iterations: int = 50
    max_pdas_iterations: int = 6
    kkt_rtol: float = 1e-10
    warm_start: bool = True

    def __post_init__(self) -> None:
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
    (:class:`~shellobstacle.solvers.brezis_sibony.BrezisSibonySolver`).

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
    """

    xi: float | None = None
    safety: float = 0.1
    mass: str = "consistent"
    start: str = "linearized"
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

    def __post_init__(self) -> None:
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
