"""The options of Newton's method (:class:`NewtonOptions`): stopping rules and the linear
strategy, each ``[solver]`` key declared on its field
(:func:`~shellobstacle.solvers.options.option`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from shellobstacle.solvers.auto import MULTIGRID_FROM_DOFS
from shellobstacle.solvers.options import (
    FACTORIZATION_HELP,
    FACTORIZATIONS,
    check_choices,
    check_petsc_options,
    option,
    petsc_options_field,
)

__all__ = ["LINEAR_SOLVERS", "NESTED", "NewtonOptions"]

LINEAR_SOLVERS = ("auto", "direct", "iterative", "multigrid")
NESTED = ("auto", "on", "off")


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
            :data:`~shellobstacle.solvers.auto.MULTIGRID_FROM_DOFS` dofs on a mesh with coarser
            levels, ``"direct"`` else, whatever the machine
            (:func:`~shellobstacle.solvers.auto.resolve`).
        factorization: of the direct solver: ``"cholesky"`` (MUMPS' LDLᵀ; the Jacobians are
            symmetric positive definite: half the memory of LU) or ``"lu"``.
        contact_zone: with the direct solver, condense every Newton step onto a contact zone
            (``K`` outside it factorized once per zone, kept across κ); ``False``: one
            factorization per κ, reused by conjugate gradients at its later steps.
        linear_rtol: the smallest relative tolerance of the Krylov solves (the iterative
            solver's forcing terms, and CG preconditioned by a kept factorization).
        nested_iteration: ``"on"``: solve the κ ladder on the coarsest level of the mesh's
            refinements, then every finer level at the last κ only, each from the coarser
            level's solution (:mod:`~shellobstacle.solvers.newton.nested`; the membrane model
            on a refined mesh; a curved obstacle's gap is linearized at each level's start);
            the finest level's result is that of the last κ.
            ``"auto"`` (the default): on one rank wherever the linear solver is multigrid and
            the problem allows it (:func:`~shellobstacle.solvers.auto.resolve`);
            with the direct path's contact zone, whose steps are not relaxed, it is slower.
        normal_relaxation: after a Newton step that the line search cuts below ``t = 0.5``, try
            the full step with ζ_3 relaxed
            (:mod:`~shellobstacle.solvers.newton.normal_relaxation`; the membrane model only).
            Nested iteration turns it on; not a config key.
        petsc_options: PETSc options for the method's solvers
            (:data:`~shellobstacle.solvers.options.PETSC_OPTIONS_HELP`).
    """

    rtol: float = option(1e-10, help="relative residual tolerance")
    atol: float = 0.0
    stol: float = option(1e-12, help="relative Newton-correction tolerance")
    floor_factor: float = 100.0
    max_iterations: int = option(100, help="Newton iterations per κ")
    linear_solver: str = option(
        "auto",
        choices=LINEAR_SOLVERS,
        help=f"multigrid (membrane P1) from {MULTIGRID_FROM_DOFS / 1e6:g} M dofs on a refined "
        "mesh, else direct; "
        "MUMPS; inexact Newton with flexible CG and a field split (GAMG on ζ_α): about 70 % "
        "of the memory; or inexact Newton with CG and geometric multigrid on the mesh's "
        "uniform refinements (GAMG on a mesh without them)",
    )
    factorization: str = option("cholesky", choices=FACTORIZATIONS, help=FACTORIZATION_HELP)
    contact_zone: bool = option(
        True,
        help="direct solver: condense each Newton step onto the contact zone (K factorized "
        "once per zone, kept across κ); false: one factorization per κ reused by CG",
    )
    linear_rtol: float = 1e-12
    nested_iteration: str = option(
        "auto",
        choices=NESTED,
        help="on: climb the κ ladder on the coarsest of the mesh's refinement levels, then "
        "solve every finer level at the last κ only, from the coarser solution (membrane; a "
        "curved obstacle's gap linearized at each level's start); auto: on with multigrid "
        "on one rank where the problem allows it",
    )
    normal_relaxation: bool = False
    petsc_options: Mapping[str, Any] = petsc_options_field()

    def __post_init__(self) -> None:
        check_petsc_options(self.petsc_options)
        check_choices(self)
        if self.max_iterations < 1:
            raise ValueError(f"solver.max_iterations must be >= 1, got {self.max_iterations}")
        for name in ("rtol", "atol", "stol", "linear_rtol"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"solver.{name} must be >= 0, got {getattr(self, name)}")
        if not self.floor_factor > 0:
            raise ValueError(f"floor_factor must be > 0, got {self.floor_factor}")
