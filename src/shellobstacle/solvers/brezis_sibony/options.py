"""The options of the Brezis–Sibony iteration (:class:`BrezisSibonyOptions`), each
``[solver]`` key declared on its field (:func:`~shellobstacle.solvers.options.option`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from shellobstacle.solvers.options import (
    check_choices,
    check_petsc_options,
    option,
    petsc_options_field,
)

__all__ = ["MASSES", "STARTS", "BrezisSibonyOptions"]

MASSES = ("consistent", "lumped")
STARTS = ("zero", "linearized", "current")


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
            solve with the elastic matrix and the load) or ``"current"`` (``problem.zeta``; not
            offered by the config).
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
        petsc_options: PETSc options for the method's solvers
            (:data:`~shellobstacle.solvers.options.PETSC_OPTIONS_HELP`).
    """

    xi: float | None = option(None, help="Ξ of (38); default: from a λ_max estimate")
    safety: float = 0.1
    mass: str = option("consistent", choices=MASSES, help="mass matrix")
    start: str = option("linearized", choices=STARTS, offered=("zero", "linearized"), help="ψ_0")
    rtol: float = option(1e-12, key="bs_rtol", help="relative L² increment tolerance")
    rtol_residual: float = 1e-10
    max_iterations: int = option(200_000, key="bs_max_iterations", help="iteration cap")
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
        check_choices(self)
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
