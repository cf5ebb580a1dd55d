"""How a Newton direction is solved: linear strategies behind one small interface.

A strategy solves the Newton equation ``J δ = −R(ζ)`` of a
:class:`~shellobstacle.solvers.newton.system.PenalizedSystem` into its ``dz``:

* :class:`~.zone.ZoneStrategy` (the default): exact solves condensed onto a contact zone,
  and steps on the zone's own condensed problem while the active points stay inside it;
* :class:`~.direct.DirectStrategy`: one MUMPS factorization per κ, reused by conjugate
  gradients at the κ's later steps (``solver.contact_zone = false``);
* :class:`~.iterative.IterativeStrategy`: inexact Newton with flexible CG and a field split,
  GAMG on ζ_α (``solver.linear_solver = "iterative"``);
* :class:`~.multigrid.MultigridStrategy`: inexact Newton with CG and geometric multigrid on
  the mesh hierarchy (``solver.linear_solver = "multigrid"``).

:func:`make_strategy` picks one from :class:`~shellobstacle.solvers.newton.options.NewtonOptions`;
a strategy built by hand (with its own knobs) can be given to the solver instead.
"""

from __future__ import annotations

from typing import Protocol

from mpi4py import MPI  # noqa: F401  (MPI before dolfinx and PETSc)
from petsc4py import PETSc

import numpy as np

from shellobstacle.solvers.newton.options import NewtonOptions
from shellobstacle.solvers.newton.system import PenalizedSystem

__all__ = ["LinearSolveError", "LinearStrategy", "make_strategy"]


class LinearSolveError(RuntimeError):
    """A linear solve for a Newton direction failed; ``iterations`` it took."""

    def __init__(self, message: str, iterations: int) -> None:
        super().__init__(message)
        self.iterations = iterations


class LinearStrategy(Protocol):
    """What :class:`~shellobstacle.solvers.newton.solver.NewtonSolver` asks of a linear strategy."""

    #: whether the continuation's Euler predictor may use :meth:`tangent`
    predicts: bool
    #: factorizations in the current solve
    factorizations: int

    def attach(self, system: PenalizedSystem, timings: dict[str, float]) -> None:
        """Build the solvers for ``system``; add phase seconds to ``timings``."""

    def begin(self) -> None:
        """A new solve starts (its result must not depend on earlier solves)."""

    def refresh(self) -> None:
        """The penalty's point operators were assembled anew (a curved obstacle's gap
        linearized again; their sparsity unchanged): drop what was built from their values."""

    def direction(self, history: list[float], target: float) -> int:
        """``δ ← J⁻¹(−R)`` for a full Newton step (``system.R`` holds ``−R``); returns the
        linear iterations. ``history``: the residual norms so far, ``target``: Newton's
        stopping threshold. Raises :class:`LinearSolveError`."""

    def reduced(self, floor_factor: float) -> object | None:
        """A smaller model to take the next Newton steps on (the contact zone's), or None."""

    def tangent(self, b: PETSc.Vec) -> bool:
        """``δ ← J⁻¹ b`` with what the last solve kept (the predictor); False if nothing."""


def make_strategy(options: NewtonOptions, comm: object) -> LinearStrategy:
    """The strategy the options ask for (the zone when MUMPS' selected inverse is reachable)."""
    from shellobstacle.solvers.linear.direct import DirectStrategy
    from shellobstacle.solvers.linear.iterative import IterativeStrategy
    from shellobstacle.solvers.linear.multigrid import MultigridStrategy
    from shellobstacle.solvers.linear.zone import ZoneStrategy, zone_available

    if options.linear_solver == "iterative":
        return IterativeStrategy(options.linear_rtol)
    if options.linear_solver == "multigrid":
        return MultigridStrategy(options.linear_rtol)
    if options.contact_zone and zone_available(comm):
        return ZoneStrategy(options.factorization, options.linear_rtol)
    return DirectStrategy(options.factorization, options.linear_rtol)


def active_changes(comm: object, before: np.ndarray, after: np.ndarray) -> int:
    """How many points changed between active and inactive (collective)."""
    return comm.allreduce(int(np.count_nonzero(before != after)))
