"""What a solve returns and how it fails: one Newton solve's record, one step record, one
method result, one solve result with its contact figures, and one error, shared by every
method of :mod:`~shellobstacle.solvers.registry`.

Plain data, importable without DOLFINx or PETSc (the registry and the configuration import
it); a result's figures import the post-processing when first read.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import dolfinx

    from shellobstacle.checks.assumptions import Check
    from shellobstacle.models.problem import PenalizedProblem
    from shellobstacle.post.contact import Postprocessor
    from shellobstacle.post.validity import Validity

__all__ = [
    "BELOW_RTOL", "ZERO_LOAD", "Contact", "ConvergenceError", "MethodResult", "NewtonResult",
    "SolveResult", "Step",
]  # fmt: skip


#: the reason of a solve whose load vector and start residual are zero: ``ζ = 0`` solves it
ZERO_LOAD = "zero load: zeta = 0 solves the problem"
#: the reason of a convergence to the tolerance (any other is limited by round-off)
BELOW_RTOL = "relative residual below rtol"


@dataclass
class NewtonResult:
    """What a Newton solve did: iterations, residual history, step lengths, times."""

    converged: bool
    iterations: int
    reason: str
    residual_norms: list[float] = field(default_factory=list)
    step_lengths: list[float] = field(default_factory=list)
    linear_iterations: list[int] = field(default_factory=list)
    line_search_evaluations: int = 0
    factorizations: int = 0
    zone_steps: int = 0  # of the iterations: steps on the contact zone's problem
    relaxed_steps: int = 0  # of the iterations: cut steps replaced by the relaxed full step
    timings: dict[str, float] = field(default_factory=dict)
    reference: float = 0.0  # ‖R(0)‖, the scale of the relative residual

    @property
    def round_off_limited(self) -> bool:
        """Stopped because round-off, not the tolerance, bounds what can be resolved.

        For tiny κ the gap is known only to machine precision and the penalty multiplies that
        error by ``ε/κ``: the residual then cannot reach ``rtol`` and the iterate is the
        solution to working precision only.
        """
        return self.converged and self.reason not in (BELOW_RTOL, ZERO_LOAD)

    @property
    def relative_residual(self) -> float:
        """Final ``‖R(ζ)‖ / ‖R(0)‖`` (``R(0)`` = minus the load vector; 0 for a zero load)."""
        if not self.residual_norms:
            return math.nan
        last = self.residual_norms[-1]
        if self.reference > 0:
            return last / self.reference
        return 0.0 if last == 0 else math.inf


@dataclass
class Step:
    """One solve by a method at one κ (0: the exact nodal problem): a row of
    ``summary.json``'s ``continuation``.

    Attributes:
        kappa: the penalty parameter solved for (0 for the exact nodal problem).
        iterations: the method's iterations (Newton steps, linear solves, steps (38)).
        converged: whether the method's stopping rule was met.
        reason: why it stopped.
        relative_residual: the method's relative residual at the answer.
        seconds: wall time of this step.
        residual_norms: the residual norm after each iteration, if the method records it.
        details: the method's own fields of the row, after the common ones.
        method: the method's name, written in the row (None: Newton's continuation, whose
            rows carry no name).
        record: the method's own result object (``NewtonResult``, ``BrezisSibonyResult``,
            ``ActiveSetResult`` …), for callers that need more than the row.
    """

    kappa: float | None
    iterations: int
    converged: bool
    reason: str
    relative_residual: float
    seconds: float
    residual_norms: list[float] = field(default_factory=list)
    details: dict[str, Any] = field(default_factory=dict)
    method: str | None = None
    record: Any = None

    def as_dict(self) -> dict[str, Any]:
        """JSON-friendly record."""
        head = {} if self.method is None else {"method": self.method}
        return {
            **head,
            "kappa": self.kappa,
            "converged": self.converged,
            "iterations": self.iterations,
            "reason": self.reason,
            "relative_residual": self.relative_residual,
            **self.details,
            "seconds": self.seconds,
        }


@dataclass
class MethodResult:
    """What a method did on one problem (its answer is in ``problem.zeta``).

    Attributes:
        steps: one :class:`Step` per κ solved (the failed one last, when one failed).
        converged: whether every step converged.
        error: the failure's message when one did not.
        extra: results beside ζ, e.g. the exact methods' ``multiplier`` and
            ``contact_pressure`` (Functions).
        timings: seconds of the method's parts (e.g. ``setup``, ``solve.<part>``).
    """

    steps: list[Step] = field(default_factory=list)
    converged: bool = True
    error: str | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)

    @property
    def iterations(self) -> int:
        """Iterations summed over all steps."""
        return sum(s.iterations for s in self.steps)


class ConvergenceError(RuntimeError):
    """A solver did not reach its answer: no convergence, a failed factorization or solve.

    Attributes:
        result: what the failing solver did (its result object with the history, or a
            :class:`MethodResult`; None when it failed before iterating). A solver that
            iterates leaves its last iterate in place.
        steps: the steps completed before the failure (e.g. the κ of a continuation that
            converged before the one that failed).
    """

    def __init__(self, message: str, result: Any = None, steps: Sequence[Step] = ()) -> None:
        super().__init__(message)
        self.result = result
        self.steps: list[Step] = list(steps)

    def after(self, steps: Sequence[Step]) -> ConvergenceError:
        """The same failure, preceded by ``steps`` (raise it ``from`` this one)."""
        return ConvergenceError(str(self), self.result, [*steps, *self.steps])


@dataclass(frozen=True)
class Contact:
    """A solution's contact set ``{g(ζ) ≤ tol}`` and its measures (docs/model.md §7): where
    the constraint acts, and at the nodes (``*_nodal``); the figures of
    :meth:`~shellobstacle.post.contact.Postprocessor.contact`, global values.

    Attributes:
        area: ``Σ w_k √a(x_k)`` over the contact points where the constraint acts.
        area_projected: ``Σ w_k`` over them.
        max_violation: ``max {g}^-`` there.
        min_gap: ``min g`` there.
        count: the number of contact points there.
        points: where the constraint acts: ``"quadrature points"``, ``"vertices"`` or
            ``"nodes"``.
        area_nodal, area_nodal_projected, max_violation_nodal, min_gap_nodal, count_nodal:
            the same at the nodes of ζ's space (P1: the lumped ``∫ φ_i √a dy``).
        nodal_points: ``"vertices"`` or ``"nodes"``.
        tol: the contact threshold.
    """

    area: float
    area_projected: float
    max_violation: float
    min_gap: float
    count: int
    points: str
    area_nodal: float
    area_nodal_projected: float
    max_violation_nodal: float
    min_gap_nodal: float
    count_nodal: int
    nodal_points: str
    tol: float

    @classmethod
    def from_figures(cls, figures: Mapping[str, Any]) -> Contact:
        """From the dictionary of :meth:`~shellobstacle.post.contact.Postprocessor.contact`."""
        return cls(
            figures["contact_area"], figures["contact_area_projected"],
            figures["max_violation"], figures["min_gap"], figures["num_contact_points"],
            figures["contact_points"], figures["contact_area_nodal"],
            figures["contact_area_nodal_projected"], figures["max_violation_nodal"],
            figures["min_gap_nodal"], figures["num_contact_nodes"], figures["nodal_points"],
            figures["tol"],
        )  # fmt: skip


@dataclass
class SolveResult:
    """A finished (or failed) solve: the problem holding ζ, steps, checks and timings, and
    the solution's figures (:attr:`contact`, :attr:`validity`), computed when first read
    from the solution held then. Reading a figure is collective: read it on every rank.

    Attributes:
        problem: the compiled problem; ``problem.zeta`` is the answer (or the last iterate).
        h: the mesh size.
        kappa: the target κ (0 for the exact nodal problem).
        steps: the method's steps.
        checks: the assumptions checked on the mesh.
        timings: seconds per phase (``mesh``, ``checks``, ``compile``, ``solve`` and the
            method's parts).
        converged: whether the method converged.
        error: its message when it did not.
        method: the method's name (a key of :data:`~shellobstacle.solvers.registry.METHODS`).
        extra: the method's results beside ζ, and ``adapt``'s levels.
    """

    problem: PenalizedProblem
    h: float
    kappa: float
    steps: list[Step]
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
        return 0.0 if self.kappa == 0.0 else float(self.problem.kappa.value)

    @property
    def constraint(self) -> str:
        """Where the solution's constraint acts, and so where contact is measured
        (:func:`~shellobstacle.post.points.constraint_points`): ``"penalty"`` for a
        penalized method, ``"nodes"`` for an exact nodal one (κ = 0, as :attr:`solved_kappa`)."""
        return "nodes" if self.kappa == 0.0 else "penalty"

    @property
    def zeta(self) -> dolfinx.fem.Function:
        """The answer ``ζ`` (or the last iterate of a failed solve): ``problem.zeta``."""
        return self.problem.zeta

    @property
    def mesh(self) -> dolfinx.mesh.Mesh:
        """The mesh of ω the answer lives on (the last level's after adaptive refinement)."""
        return self.problem.mesh

    @property
    def dofs(self) -> int:
        """The number of degrees of freedom of ζ (global)."""
        return self.problem.num_dofs

    @cached_property
    def post(self) -> Postprocessor:
        """The :class:`~shellobstacle.post.contact.Postprocessor` of the problem, measuring
        where the solution's constraint acts (:attr:`constraint`). Collective."""
        from shellobstacle.post.contact import Postprocessor

        return Postprocessor(self.problem, self.constraint)

    @cached_property
    def contact(self) -> Contact:
        """The contact set and its measures (:class:`Contact`). Collective."""
        return Contact.from_figures(self.post.contact())

    @cached_property
    def validity(self) -> Validity:
        """The solution's :class:`~shellobstacle.post.validity.Validity` (penetration,
        displacement, orientation against their thresholds). Collective."""
        from shellobstacle.post.validity import assess

        return assess(self.post, self.solved_kappa)
